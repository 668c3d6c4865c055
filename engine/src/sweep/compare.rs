//! The comparison of a sweep's variants, built from its folder alone (the
//! plan in `sweep.json` and each variant's `report.json`), so that shards'
//! folders merge the same as one process's: `comparison.csv`, `.md` and
//! `.html` (one row per variant: overrides, chosen metrics, status, times),
//! `comparison_nodes.csv` (every node's status and time per variant), and the
//! best variant by the rank metric.

use super::plan::{Better, SweepPlan};
use serde_json::{Value as Json, json};
use std::fmt::Write;
use std::path::Path;

/// The plan as `sweep.json` holds it.
pub fn plan_json(plan: &SweepPlan) -> Json {
    let text = |v: &toml::Value| match v {
        toml::Value::String(s) => s.clone(),
        other => other.to_string(),
    };
    json!({
        "name": plan.name,
        "file": plan.file.display().to_string(),
        "graph": plan.graph.display().to_string(),
        "rank_by": plan.rank_by,
        "better": plan.better.name(),
        "metrics": plan.metrics,
        "varied": plan.varied,
        "variants": plan.variants.iter().map(|v| json!({
            "name": v.name,
            "overrides": v.overrides.iter().map(|(k, x)| json!([k, text(x)])).collect::<Vec<_>>(),
        })).collect::<Vec<_>>(),
    })
}

/// How a variant ended.
#[derive(Debug, Clone, PartialEq)]
pub enum Status {
    /// Every node ran or was cached.
    Done,
    /// A node failed (its id and error).
    Failed(String),
    /// No report: the variant has not run (a shard missing, or still running).
    Missing,
}

impl Status {
    /// `done`, `failed` or `missing`.
    pub fn name(&self) -> &'static str {
        match self {
            Status::Done => "done",
            Status::Failed(_) => "failed",
            Status::Missing => "missing",
        }
    }
}

/// One variant's row.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    /// The variant's name.
    pub variant: String,
    /// Its overrides, `(NODE.KEY, value)`.
    pub overrides: Vec<(String, String)>,
    /// How it ended.
    pub status: Status,
    /// The chosen metrics, in the plan's order (`None`: not in its report).
    pub metrics: Vec<Option<f64>>,
    /// Wall time of its run, ms.
    pub total_ms: Option<f64>,
    /// Time of the nodes it computed (not reused), ms.
    pub computed_ms: Option<f64>,
    /// Nodes it computed and nodes it reused.
    pub computed: usize,
    /// Nodes it reused from the cache.
    pub reused: usize,
    /// (node, status, ms) of every node.
    pub nodes: Vec<(String, String, f64)>,
}

/// A sweep's comparison.
#[derive(Debug, Clone, PartialEq)]
pub struct Comparison {
    /// The sweep's name.
    pub name: String,
    /// The metric columns.
    pub metrics: Vec<String>,
    /// The keys `[sweep.vary]` varies.
    pub varied: Vec<String>,
    /// The rank metric and its direction.
    pub rank_by: Option<(String, Better)>,
    /// One row per variant, in the plan's order.
    pub rows: Vec<Row>,
}

impl Comparison {
    /// The best row by the rank metric (done rows that have it), if any.
    pub fn best(&self) -> Option<&Row> {
        let (metric, better) = self.rank_by.as_ref()?;
        let col = self.metrics.iter().position(|m| m == metric)?;
        self.rows
            .iter()
            .filter(|r| r.status == Status::Done)
            .filter_map(|r| r.metrics[col].filter(|v| v.is_finite()).map(|v| (r, v)))
            .min_by(|a, b| {
                let o = a.1.total_cmp(&b.1);
                if *better == Better::Lower {
                    o
                } else {
                    o.reverse()
                }
            })
            .map(|(r, _)| r)
    }
}

fn read_json(path: &Path) -> Result<Json, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))
}

/// The comparison of the sweep in folder `dir`.
pub fn comparison(dir: &Path) -> Result<Comparison, String> {
    let plan = read_json(&dir.join("sweep.json"))
        .map_err(|e| format!("{e} (not a sweep's folder? `fusegraph sweep` writes sweep.json)"))?;
    let strings = |v: &Json| -> Vec<String> {
        v.as_array()
            .map(|a| {
                a.iter()
                    .filter_map(|x| x.as_str().map(String::from))
                    .collect()
            })
            .unwrap_or_default()
    };
    let metrics = strings(&plan["metrics"]);
    let rank_by = plan["rank_by"].as_str().map(|m| {
        let better = if plan["better"] == "higher" {
            Better::Higher
        } else {
            Better::Lower
        };
        (m.to_string(), better)
    });
    let mut rows = Vec::new();
    for v in plan["variants"]
        .as_array()
        .ok_or("sweep.json: no variants")?
    {
        let name = v["name"]
            .as_str()
            .ok_or("sweep.json: a variant without a name")?
            .to_string();
        let overrides = v["overrides"]
            .as_array()
            .map(|a| {
                a.iter()
                    .map(|kv| {
                        (
                            kv[0].as_str().unwrap_or("").to_string(),
                            kv[1].as_str().unwrap_or("").to_string(),
                        )
                    })
                    .collect()
            })
            .unwrap_or_default();
        let report_file = dir.join(&name).join("report.json");
        let mut row = Row {
            variant: name,
            overrides,
            status: Status::Missing,
            metrics: vec![None; metrics.len()],
            total_ms: None,
            computed_ms: None,
            computed: 0,
            reused: 0,
            nodes: Vec::new(),
        };
        if report_file.is_file() {
            let r = read_json(&report_file)?;
            row.metrics = metrics.iter().map(|m| r["metrics"][m].as_f64()).collect();
            row.total_ms = r["total_ms"].as_f64();
            let mut failed = None;
            let mut computed_ms = 0.0;
            for (id, n) in r["nodes"].as_object().into_iter().flatten() {
                let status = n["status"].as_str().unwrap_or("").to_string();
                let ms = n["ms"].as_f64().unwrap_or(0.0);
                match status.as_str() {
                    "ran" => {
                        row.computed += 1;
                        computed_ms += ms;
                    }
                    "cached" => row.reused += 1,
                    "failed" if failed.is_none() => {
                        failed = Some(format!("{id}: {}", n["error"].as_str().unwrap_or("failed")));
                    }
                    _ => {}
                }
                row.nodes.push((id.clone(), status, ms));
            }
            row.computed_ms = Some(computed_ms);
            row.status = match failed {
                Some(why) => Status::Failed(why),
                None if r["succeeded"] == true => Status::Done,
                None => Status::Failed("a node did not finish".into()),
            };
        }
        rows.push(row);
    }
    Ok(Comparison {
        name: plan["name"].as_str().unwrap_or("sweep").to_string(),
        metrics,
        varied: strings(&plan["varied"]),
        rank_by,
        rows,
    })
}

fn number(v: Option<f64>) -> String {
    v.map(|x| format!("{x}")).unwrap_or_default()
}

/// A value for people: whole numbers without decimals, others to 4 places.
pub fn shown(v: f64) -> String {
    if v.fract() == 0.0 && v.abs() < 1e15 {
        format!("{v:.0}")
    } else {
        format!("{v:.4}")
    }
}

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

fn overrides_text(row: &Row) -> String {
    let parts: Vec<String> = row
        .overrides
        .iter()
        .map(|(k, v)| format!("{k}={v}"))
        .collect();
    parts.join("; ")
}

fn error_text(row: &Row) -> String {
    match &row.status {
        Status::Failed(why) => why.clone(),
        Status::Missing => "no report.json".into(),
        Status::Done => String::new(),
    }
}

/// `comparison.csv`.
pub fn to_csv(c: &Comparison) -> String {
    let mut s = String::from("variant,overrides,status");
    for m in &c.metrics {
        let _ = write!(s, ",{}", csv_field(m));
    }
    s.push_str(",total_ms,computed_ms,computed_nodes,reused_nodes,error\n");
    for r in &c.rows {
        let _ = write!(
            s,
            "{},{},{}",
            csv_field(&r.variant),
            csv_field(&overrides_text(r)),
            r.status.name()
        );
        for m in &r.metrics {
            let _ = write!(s, ",{}", number(*m));
        }
        let _ = writeln!(
            s,
            ",{},{},{},{},{}",
            number(r.total_ms),
            number(r.computed_ms),
            r.computed,
            r.reused,
            csv_field(&error_text(r))
        );
    }
    s
}

/// `comparison_nodes.csv`: every node's status and time, per variant.
pub fn nodes_csv(c: &Comparison) -> String {
    let mut s = String::from("variant,node,status,ms\n");
    for r in &c.rows {
        for (id, status, ms) in &r.nodes {
            let _ = writeln!(
                s,
                "{},{},{status},{ms}",
                csv_field(&r.variant),
                csv_field(id)
            );
        }
    }
    s
}

pub(super) fn best_line(c: &Comparison) -> String {
    match (&c.rank_by, c.best()) {
        (Some((m, b)), Some(row)) => {
            let col = c
                .metrics
                .iter()
                .position(|x| x == m)
                .expect("rank metric is a column");
            format!(
                "Best by `{m}` ({} is better): **{}** ({})",
                b.name(),
                row.variant,
                row.metrics[col].map(shown).unwrap_or_default()
            )
        }
        (Some((m, _)), None) => format!("No variant finished with `{m}`."),
        (None, _) => "No rank metric (`[sweep] rank_by`).".into(),
    }
}

/// `comparison.md`.
pub fn to_markdown(c: &Comparison) -> String {
    let mut s = format!("# Sweep `{}`\n\n{}\n\n", c.name, best_line(c));
    let mut head = vec!["variant".to_string(), "overrides".into(), "status".into()];
    head.extend(c.metrics.iter().cloned());
    head.extend(["total ms".into(), "computed / reused".into()]);
    let _ = writeln!(s, "| {} |", head.join(" | "));
    let _ = writeln!(s, "|{}", " --- |".repeat(head.len()));
    for r in &c.rows {
        let status = match &r.status {
            Status::Done => "done".to_string(),
            other => format!("{}: {}", other.name(), error_text(r).replace('|', "\\|")),
        };
        let mut cells = vec![
            r.variant.clone(),
            overrides_text(r).replace('|', "\\|"),
            status,
        ];
        cells.extend(
            r.metrics
                .iter()
                .map(|m| m.map(shown).unwrap_or_else(|| "-".into())),
        );
        cells.push(
            r.total_ms
                .map(|v| format!("{v:.0}"))
                .unwrap_or_else(|| "-".into()),
        );
        cells.push(format!("{} / {}", r.computed, r.reused));
        let _ = writeln!(s, "| {} |", cells.join(" | "));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(name: &str, status: Status, tre: Option<f64>) -> Row {
        Row {
            variant: name.into(),
            overrides: vec![("icp.kernel".into(), name.into())],
            status,
            metrics: vec![tre, Some(1.0)],
            total_ms: Some(10.0),
            computed_ms: Some(4.0),
            computed: 2,
            reused: 3,
            nodes: vec![],
        }
    }

    fn comparison(better: Better) -> Comparison {
        Comparison {
            name: "t".into(),
            metrics: vec!["e.tre_mm".into(), "e.rmse_mm".into()],
            varied: vec!["icp.kernel".into()],
            rank_by: Some(("e.tre_mm".into(), better)),
            rows: vec![
                row("huber", Status::Done, Some(0.3)),
                row("tukey", Status::Failed("icp: diverged".into()), Some(0.1)),
                row("none", Status::Done, None),
                row("cauchy", Status::Done, Some(0.2)),
                row("late", Status::Missing, None),
            ],
        }
    }

    #[test]
    fn a_folder_with_a_failed_a_metricless_and_a_missing_variant_reads_right() {
        let t = tempfile::tempdir().unwrap();
        let d = t.path();
        let plan = json!({
            "name": "s", "rank_by": "e.tre_mm", "better": "lower", "metrics": ["e.tre_mm"],
            "varied": ["icp.kernel"],
            "variants": [
                {"name": "a", "overrides": [["icp.kernel", "huber"]]},
                {"name": "b", "overrides": [["icp.kernel", "tukey"]]},
                {"name": "c", "overrides": [["icp.kernel", "none"]]},
                {"name": "d", "overrides": [["icp.kernel", "cauchy"]]},
            ],
        });
        std::fs::write(d.join("sweep.json"), plan.to_string()).unwrap();
        let report = |v: &str, r: Json| {
            std::fs::create_dir_all(d.join(v)).unwrap();
            std::fs::write(d.join(v).join("report.json"), r.to_string()).unwrap();
        };
        let node = |status: &str, ms: f64| json!({"status": status, "ms": ms});
        report(
            "a",
            json!({"succeeded": true, "total_ms": 9.0, "metrics": {"e.tre_mm": 0.4},
            "nodes": {"icp": node("ran", 5.0), "up": node("cached", 0.0)}}),
        );
        report(
            "b",
            json!({"succeeded": false, "total_ms": 3.0, "metrics": {},
            "nodes": {"up": node("cached", 0.0), "icp": {"status": "failed", "ms": 1.0, "error": "diverged"}, "e": node("skipped", 0.0)}}),
        );
        report(
            "c",
            json!({"succeeded": true, "total_ms": 2.0, "metrics": {"e.other": 1.0},
            "nodes": {"icp": node("ran", 2.0)}}),
        );
        let c = super::comparison(d).unwrap();
        let status: Vec<&Status> = c.rows.iter().map(|r| &r.status).collect();
        assert_eq!(
            status,
            [
                &Status::Done,
                &Status::Failed("icp: diverged".into()),
                &Status::Done,
                &Status::Missing
            ]
        );
        assert_eq!(c.rows[0].metrics, [Some(0.4)]);
        assert_eq!(c.rows[2].metrics, [None], "metric not in its report");
        assert_eq!(
            (c.rows[0].computed, c.rows[0].reused, c.rows[0].computed_ms),
            (1, 1, Some(5.0))
        );
        assert_eq!(
            c.best().unwrap().variant,
            "a",
            "the only finished variant with the metric"
        );
        assert!(
            super::comparison(&d.join("a"))
                .unwrap_err()
                .contains("sweep.json")
        );
    }

    #[test]
    fn the_best_is_a_finished_variant_with_the_metric() {
        assert_eq!(comparison(Better::Lower).best().unwrap().variant, "cauchy");
        assert_eq!(comparison(Better::Higher).best().unwrap().variant, "huber");
    }

    #[test]
    fn failed_and_missing_rows_keep_their_columns() {
        let csv = to_csv(&comparison(Better::Lower));
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(
            lines[0],
            "variant,overrides,status,e.tre_mm,e.rmse_mm,total_ms,computed_ms,computed_nodes,reused_nodes,error"
        );
        assert_eq!(
            lines[2],
            "tukey,icp.kernel=tukey,failed,0.1,1,10,4,2,3,icp: diverged"
        );
        assert_eq!(
            lines[3], "none,icp.kernel=none,done,,1,10,4,2,3,",
            "a missing metric is an empty cell"
        );
        assert_eq!(
            lines[5],
            "late,icp.kernel=late,missing,,1,10,4,2,3,no report.json"
        );
        let md = to_markdown(&comparison(Better::Lower));
        assert!(
            md.contains("Best by `e.tre_mm` (lower is better): **cauchy** (0.2000)"),
            "{md}"
        );
        assert!(
            md.contains("| none | icp.kernel=none | done | - | 1 |"),
            "{md}"
        );
        assert!(
            md.contains("| tukey | icp.kernel=tukey | failed: icp: diverged |"),
            "{md}"
        );
    }
}
