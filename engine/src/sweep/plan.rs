//! Sweep files: a base graph and what varies in it.
//!
//! ```toml
//! [sweep]
//! graph = "../fusion.toml"            # the base graph, relative to this file
//! rank_by = "evaluate.tre_mm"         # the metric that picks the best variant
//! better = "lower"                    # or "higher"
//! metrics = ["evaluate.tre_mm", "evaluate.rmse_mm"]   # the table's columns
//! mode = "grid"                       # every combination; "zip": the lists in step
//! set = { "phantom.size" = "small" }  # overrides common to every variant
//! plugins = ["libs/libmine.so"]       # loaded once for every variant
//!
//! [sweep.vary]                        # lists of values per NODE.KEY
//! "icp.method" = ["point_to_point", "point_to_plane"]
//! "match.op" = ["stereo.sgm", "stereo.block_match"]   # op swaps too
//!
//! [variant.baseline]                  # named variants: tables of overrides
//! "icp.trim_ratio" = 0.95
//! ```
//!
//! A graph file may hold the `[sweep]` table itself (and `[variant.NAME]`
//! tables); its base graph is then the file. Keys are `NODE.KEY` as in
//! `--set`: a parameter, `op`, or `in.PORT`.

use crate::error::{ErrorKind, GraphError, GraphErrors};
use std::path::{Path, PathBuf};

/// Which way the rank metric is better.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Better {
    /// Smaller is better (errors, times).
    Lower,
    /// Larger is better (coverage, inliers).
    Higher,
}

impl Better {
    /// `lower` or `higher`.
    pub fn name(self) -> &'static str {
        match self {
            Better::Lower => "lower",
            Better::Higher => "higher",
        }
    }
}

/// One variant: a name (a folder name) and its overrides, common ones first.
#[derive(Debug, Clone, PartialEq)]
pub struct Variant {
    /// Letters, digits, `.`, `_`, `-`, `=`: the name of its report folder.
    pub name: String,
    /// `(NODE.KEY, value)` in the order they apply.
    pub overrides: Vec<(String, toml::Value)>,
}

/// A sweep as planned: every variant spelled out.
#[derive(Debug, Clone, PartialEq)]
pub struct SweepPlan {
    /// `[sweep] name`, or the file stem.
    pub name: String,
    /// The sweep file.
    pub file: PathBuf,
    /// The base graph file.
    pub graph: PathBuf,
    /// The metric that ranks the variants (`node.metric`).
    pub rank_by: Option<String>,
    /// Which way it is better.
    pub better: Better,
    /// The comparison's metric columns (`rank_by` first when given).
    pub metrics: Vec<String>,
    /// The keys `[sweep.vary]` varies, in file order.
    pub varied: Vec<String>,
    /// Overrides of `[sweep] set`, applied to every variant (not shown per row).
    pub common: Vec<(String, toml::Value)>,
    /// The variants, grid or zipped ones first, then the named ones.
    pub variants: Vec<Variant>,
    /// Plugin libraries named by `[sweep] plugins`, resolved against the file.
    pub plugins: Vec<PathBuf>,
    /// Python files declaring ops, named by `[sweep] python`, resolved
    /// against the file (see [`crate::script`]).
    pub python: Vec<PathBuf>,
}

const SWEEP_KEYS: &[&str] = &[
    "graph",
    "name",
    "description",
    "rank_by",
    "better",
    "metrics",
    "mode",
    "set",
    "vary",
    "plugins",
    "python",
];

/// The longest a sweep may be.
const MAX_VARIANTS: usize = 10_000;

/// A value as a short label for a variant's name.
fn label(v: &toml::Value) -> String {
    let text = match v {
        toml::Value::String(s) => s.rsplit('.').next().unwrap_or(s).to_string(),
        toml::Value::Array(a) => a.iter().map(label).collect::<Vec<_>>().join("x"),
        other => other.to_string(),
    };
    text.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '.' || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// Reads and expands the sweep at `file`.
pub fn load_sweep(file: &Path) -> Result<SweepPlan, GraphErrors> {
    let err = |msg: String| GraphError::file(ErrorKind::Structure, file, msg);
    let meta = std::fs::metadata(file).map_err(|e| {
        GraphError::file(
            ErrorKind::Unreadable,
            file,
            format!("cannot read the sweep file: {e}"),
        )
    })?;
    if !meta.is_file() || meta.len() > 16 << 20 {
        return Err(GraphError::file(
            ErrorKind::Unreadable,
            file,
            "not a regular file of at most 16 MiB: give a sweep's .toml file",
        )
        .into());
    }
    let text = std::fs::read_to_string(file).map_err(|e| {
        GraphError::file(
            ErrorKind::Unreadable,
            file,
            format!("cannot read the sweep file: {e}"),
        )
    })?;
    let table: toml::Table = toml::from_str(&text)
        .map_err(|e| GraphError::file(ErrorKind::Syntax, file, e.message().to_string()))?;
    let base = file
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let Some(sweep) = table.get("sweep").and_then(|v| v.as_table()) else {
        return Err(err("no [sweep] table: a sweep names its graph and what varies".into()).into());
    };
    let mut errors = Vec::new();
    for k in sweep.keys() {
        if !SWEEP_KEYS.contains(&k.as_str()) {
            errors.push(
                err(format!(
                    "unknown key in [sweep]; valid keys: {}",
                    SWEEP_KEYS.join(", ")
                ))
                .at_key(k),
            );
        }
    }
    let string = |k: &str| sweep.get(k).and_then(|v| v.as_str()).map(str::to_string);
    let strings = |k: &str, errors: &mut Vec<GraphError>| -> Vec<String> {
        match sweep.get(k) {
            None => Vec::new(),
            Some(v) => match v
                .as_array()
                .and_then(|a| a.iter().map(|x| x.as_str().map(String::from)).collect())
            {
                Some(list) => list,
                None => {
                    errors.push(err(format!("[sweep] {k} must be a list of strings")).at_key(k));
                    Vec::new()
                }
            },
        }
    };
    let graph = match (string("graph"), table.contains_key("node")) {
        (Some(g), _) => base.join(g),
        (None, true) => file.to_path_buf(),
        (None, false) => {
            errors.push(
                err("[sweep] graph: name the base graph (relative to this file)".into())
                    .at_key("graph"),
            );
            PathBuf::new()
        }
    };
    let rank_by = string("rank_by");
    let better = match string("better").as_deref() {
        None | Some("lower") => Better::Lower,
        Some("higher") => Better::Higher,
        Some(other) => {
            errors.push(
                err(format!(
                    "[sweep] better = {other:?}: \"lower\" or \"higher\""
                ))
                .at_key("better"),
            );
            Better::Lower
        }
    };
    let mut metrics = strings("metrics", &mut errors);
    if let Some(r) = &rank_by {
        metrics.retain(|m| m != r);
        metrics.insert(0, r.clone());
    }
    for m in metrics.iter().filter(|m| !m.contains('.')) {
        errors.push(err(format!("metric {m:?}: metrics are named NODE.METRIC")).at_key("metrics"));
    }
    let plugins = strings("plugins", &mut errors)
        .iter()
        .map(|p| base.join(p))
        .collect();
    let python = strings("python", &mut errors)
        .iter()
        .map(|p| base.join(p))
        .collect();
    let key_ok = |k: &str| {
        k.split_once('.')
            .is_some_and(|(n, key)| !n.is_empty() && !key.is_empty())
    };
    let overrides =
        |t: &toml::Table, what: &str, errors: &mut Vec<GraphError>| -> Vec<(String, toml::Value)> {
            let mut out = Vec::new();
            for (k, v) in t {
                if key_ok(k) {
                    out.push((k.clone(), v.clone()));
                } else {
                    errors.push(err(format!("{what}: {k:?} is not NODE.KEY")).at_key(k));
                }
            }
            out
        };
    let common = match sweep.get("set") {
        None => Vec::new(),
        Some(toml::Value::Table(t)) => overrides(t, "[sweep] set", &mut errors),
        Some(_) => {
            errors
                .push(err("[sweep] set must be a table of NODE.KEY = value".into()).at_key("set"));
            Vec::new()
        }
    };
    let mut varied = Vec::new();
    let mut lists: Vec<Vec<toml::Value>> = Vec::new();
    match sweep.get("vary") {
        None => {}
        Some(toml::Value::Table(t)) => {
            for (k, v) in t {
                match v.as_array() {
                    Some(a) if !a.is_empty() && key_ok(k) => {
                        varied.push(k.clone());
                        lists.push(a.clone());
                    }
                    _ => errors.push(
                        err(format!(
                            "[sweep.vary] {k:?}: NODE.KEY = a non-empty list of values"
                        ))
                        .at_key(k),
                    ),
                }
            }
        }
        Some(_) => errors
            .push(err("[sweep] vary must be a table of NODE.KEY = [values]".into()).at_key("vary")),
    }
    let zip = match string("mode").as_deref() {
        None | Some("grid") => false,
        Some("zip") => true,
        Some(other) => {
            errors
                .push(err(format!("[sweep] mode = {other:?}: \"grid\" or \"zip\"")).at_key("mode"));
            false
        }
    };
    let combos: Vec<Vec<usize>> = if lists.is_empty() {
        Vec::new()
    } else if zip {
        let n = lists[0].len();
        if let Some((k, l)) = varied.iter().zip(&lists).find(|(_, l)| l.len() != n) {
            errors.push(
                err(format!(
                    "mode = \"zip\": {k:?} has {} values, the first list {n}",
                    l.len()
                ))
                .at_key(k),
            );
        }
        let shortest = lists.iter().map(Vec::len).min().unwrap_or(0);
        if shortest > MAX_VARIANTS {
            errors.push(
                err(format!(
                    "mode = \"zip\": {shortest} variants, more than {MAX_VARIANTS}"
                ))
                .at_key("vary"),
            );
            Vec::new()
        } else {
            (0..shortest).map(|i| vec![i; lists.len()]).collect()
        }
    } else {
        let total = lists
            .iter()
            .try_fold(1usize, |acc, l| acc.checked_mul(l.len()));
        match total {
            Some(t) if t <= MAX_VARIANTS => (0..t)
                .map(|mut i| {
                    let mut pick = vec![0; lists.len()];
                    for (d, l) in lists.iter().enumerate().rev() {
                        pick[d] = i % l.len();
                        i /= l.len();
                    }
                    pick
                })
                .collect(),
            _ => {
                errors.push(
                    err(format!("the grid has more than {MAX_VARIANTS} variants")).at_key("vary"),
                );
                Vec::new()
            }
        }
    };
    let width = combos.len().to_string().len().max(2);
    let mut variants: Vec<Variant> = combos
        .iter()
        .enumerate()
        .map(|(i, pick)| {
            let values: Vec<&toml::Value> = pick.iter().zip(&lists).map(|(&j, l)| &l[j]).collect();
            let labels: Vec<String> = values.iter().map(|v| label(v)).collect();
            Variant {
                name: format!("{:0width$}_{}", i + 1, labels.join("_")),
                overrides: varied
                    .iter()
                    .cloned()
                    .zip(values.into_iter().cloned())
                    .collect(),
            }
        })
        .collect();
    match table.get("variant") {
        None => {}
        Some(toml::Value::Table(named)) if combos.len() + named.len() > MAX_VARIANTS => {
            errors.push(err(format!(
                "{} named variants{}: more than {MAX_VARIANTS} in all",
                named.len(),
                if combos.is_empty() {
                    String::new()
                } else {
                    format!(" and {} from [sweep.vary]", combos.len())
                }
            )));
        }
        Some(toml::Value::Table(named)) => {
            for (name, body) in named {
                // A variant's name is a folder under --out: no `.`, `..` or
                // hidden names.
                let ok = !name.is_empty()
                    && !name.starts_with('.')
                    && name
                        .chars()
                        .all(|c| c.is_ascii_alphanumeric() || "._-".contains(c));
                match body.as_table() {
                    Some(t) if ok => variants.push(Variant {
                        name: name.clone(),
                        overrides: overrides(t, &format!("[variant.{name}]"), &mut errors),
                    }),
                    _ => errors.push(
                        err(format!("[variant.{name}]: a table of NODE.KEY = value, named with letters, digits, '.', '_', '-' (not starting with '.': the name is a folder under --out)"))
                            .at_node(name),
                    ),
                }
            }
        }
        Some(_) => errors.push(err("variant must be tables [variant.NAME]".into())),
    }
    if variants.is_empty() {
        variants.push(Variant {
            name: "base".into(),
            overrides: Vec::new(),
        });
    }
    let mut seen = std::collections::BTreeSet::new();
    for v in &variants {
        if !seen.insert(v.name.clone()) {
            errors.push(err(format!("two variants are named {:?}", v.name)).at_node(&v.name));
        }
    }
    if !errors.is_empty() {
        return Err(GraphErrors(errors));
    }
    let name = string("name").unwrap_or_else(|| {
        file.file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "sweep".into())
    });
    Ok(SweepPlan {
        name,
        file: file.to_path_buf(),
        graph,
        rank_by,
        better,
        metrics,
        varied,
        common,
        variants,
        plugins,
        python,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plan(text: &str) -> Result<SweepPlan, GraphErrors> {
        let t = tempfile::tempdir().unwrap();
        let f = t.path().join("s.toml");
        std::fs::write(&f, text).unwrap();
        load_sweep(&f)
    }

    #[test]
    fn a_grid_spells_out_every_combination_in_order() {
        let p = plan(
            "[sweep]\ngraph = \"g.toml\"\nrank_by = \"e.tre_mm\"\nmetrics = [\"icp.rmse_mm\", \"e.tre_mm\"]\n\
             [sweep.vary]\n\"icp.method\" = [\"point_to_point\", \"point_to_plane\"]\n\"icp.trim_ratio\" = [0.8, 0.9, 1.0]\n\
             [variant.base]\n\"icp.kernel\" = \"none\"\n",
        )
        .unwrap();
        assert_eq!(p.variants.len(), 7);
        assert_eq!(p.variants[0].name, "01_point_to_point_0.8");
        assert_eq!(p.variants[5].name, "06_point_to_plane_1.0");
        assert_eq!(p.variants[6].name, "base");
        assert_eq!(
            p.metrics,
            ["e.tre_mm", "icp.rmse_mm"],
            "rank_by first, once"
        );
        assert_eq!(p.varied, ["icp.method", "icp.trim_ratio"]);
        assert_eq!(
            p.variants[4].overrides[1],
            ("icp.trim_ratio".into(), toml::Value::Float(0.9))
        );
    }

    #[test]
    fn zip_steps_the_lists_together_and_op_swaps_are_named_by_their_action() {
        let p = plan(
            "[sweep]\ngraph = \"g.toml\"\nmode = \"zip\"\n[sweep.vary]\n\"match.op\" = [\"stereo.sgm\", \"stereo.block_match\"]\n\"match.cost\" = [\"census\", \"zncc\"]\n",
        )
        .unwrap();
        let names: Vec<&str> = p.variants.iter().map(|v| v.name.as_str()).collect();
        assert_eq!(names, ["01_sgm_census", "02_block_match_zncc"]);
        let p = plan("[sweep]\ngraph = \"g.toml\"\n[sweep.vary]\n\"match.census_window\" = [[5, 5], [9, 7]]\n").unwrap();
        assert_eq!(p.variants[1].name, "02_9x7");
    }

    #[test]
    fn a_graph_may_hold_its_own_sweep() {
        let t = tempfile::tempdir().unwrap();
        let f = t.path().join("g.toml");
        let text = "[sweep]\nrank_by = \"a.value\"\n[sweep.vary]\n\"a.value\" = [1.0, 2.0]\n\
                    [node.a]\nop = \"math.constant\"\nvalue = 0.0\n";
        std::fs::write(&f, text).unwrap();
        let p = load_sweep(&f).unwrap();
        assert_eq!(p.graph, f);
        assert_eq!(p.variants.len(), 2);
        // The graph loads with its sweep tables in it.
        let doc = crate::graph::GraphDoc::load(&f).unwrap();
        assert_eq!(doc.nodes.len(), 1);
    }

    #[test]
    fn mistakes_are_named_with_their_keys() {
        let e = plan("[sweep]\ngraph = \"g.toml\"\nrank = \"x\"\nmode = \"zip\"\n[sweep.vary]\n\"a.b\" = [1, 2]\n\"c.d\" = [1]\nbad = [1]\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("unknown key in [sweep]"), "{e}");
        assert!(e.contains("\"c.d\" has 1 values, the first list 2"), "{e}");
        assert!(e.contains("\"bad\": NODE.KEY"), "{e}");
        let e = plan("[sweep]\n").unwrap_err().to_string();
        assert!(e.contains("name the base graph"), "{e}");
        let e = plan("[sweep]\ngraph = \"g\"\n[sweep.vary]\n\"a.b\" = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]\n\"c.d\" = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]\n\"e.f\" = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]\n\"g.h\" = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]\n\"i.j\" = [1, 2]\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("more than 10000 variants"), "{e}");
    }

    #[test]
    fn variant_names_stay_inside_the_output_folder() {
        for name in ["..", ".", ".hidden", "a/b", "..%2f"] {
            let e = plan(&format!(
                "[sweep]\ngraph = \"g\"\n[variant.\"{name}\"]\n\"a.b\" = 1\n"
            ))
            .unwrap_err()
            .to_string();
            assert!(e.contains("folder under --out"), "{name}: {e}");
            assert!(e.contains(&format!("[variant.{name}]")), "{name}: {e}");
        }
        assert!(plan("[sweep]\ngraph = \"g\"\n[variant.\"v1.2\"]\n\"a.b\" = 1\n").is_ok());
    }

    #[test]
    fn zipped_and_named_variants_have_the_grids_cap() {
        let many: Vec<String> = (0..=MAX_VARIANTS).map(|i| i.to_string()).collect();
        let e = plan(&format!(
            "[sweep]\ngraph = \"g\"\nmode = \"zip\"\n[sweep.vary]\n\"a.b\" = [{}]\n",
            many.join(", ")
        ))
        .unwrap_err()
        .to_string();
        assert!(e.contains("10001 variants, more than 10000"), "{e}");
        let named: String = (0..=MAX_VARIANTS)
            .map(|i| format!("[variant.v{i}]\n\"a.b\" = {i}\n"))
            .collect();
        let e = plan(&format!("[sweep]\ngraph = \"g\"\n{named}"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("10001 named variants: more than 10000"), "{e}");
    }
}
