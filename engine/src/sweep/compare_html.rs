//! `comparison.html`: the sweep's table (click a column head to sort by it)
//! and, for every chosen metric and every varied key, the metric of each
//! finished variant against the key's value (an SVG strip plot: the values
//! in the order the sweep lists them, one dot per variant). One
//! self-contained file: no server, no network. The plots are also written
//! alone, `plots/METRIC_against_KEY.svg`, for papers and READMEs.
//!
//! The keys plotted are those of `[sweep.vary]` and, for named variants,
//! every key that at least two finished variants set to different values
//! (a sweep of conditions one at a time: each condition's levels).

use super::compare::{Comparison, Status, shown};
use std::fmt::Write;

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// The keys to plot against: the varied ones, then those that named
/// variants set to at least two values, in the order the rows first set
/// them.
pub fn plot_keys(c: &Comparison) -> Vec<String> {
    let mut keys: Vec<String> = c.varied.clone();
    let done = || c.rows.iter().filter(|r| r.status == Status::Done);
    for r in done() {
        for (k, _) in &r.overrides {
            if keys.contains(k) {
                continue;
            }
            let mut values: Vec<&str> = done()
                .filter_map(|r| r.overrides.iter().find(|(kk, _)| kk == k))
                .map(|(_, v)| v.as_str())
                .collect();
            values.sort_unstable();
            values.dedup();
            if values.len() >= 2 {
                keys.push(k.clone());
            }
        }
    }
    keys
}

/// Every plot as a standalone SVG: (file name, SVG text).
pub fn plot_files(c: &Comparison) -> Vec<(String, String)> {
    let keys = plot_keys(c);
    let safe = |s: &str| -> String {
        s.chars()
            .map(|ch| {
                if ch.is_ascii_alphanumeric() || ch == '.' {
                    ch
                } else {
                    '_'
                }
            })
            .collect()
    };
    (0..c.metrics.len())
        .flat_map(|col| {
            keys.iter().filter_map(move |k| {
                let svg = plot_svg(c, col, k)?;
                let name = format!("{}_against_{}.svg", safe(&c.metrics[col]), safe(k));
                Some((name, svg))
            })
        })
        .collect()
}

/// One strip plot of `metric` (column `col`) against the values of `key`,
/// in a figure with its caption.
fn plot(c: &Comparison, col: usize, key: &str) -> Option<String> {
    let svg = plot_svg(c, col, key)?;
    Some(format!(
        "<figure>{svg}<figcaption><code>{}</code> against <code>{}</code></figcaption></figure>",
        esc(&c.metrics[col]),
        esc(key)
    ))
}

/// The SVG of [`plot`].
fn plot_svg(c: &Comparison, col: usize, key: &str) -> Option<String> {
    let points: Vec<(&str, &str, f64)> = c
        .rows
        .iter()
        .filter(|r| r.status == Status::Done)
        .filter_map(|r| {
            let value = r.overrides.iter().find(|(k, _)| k == key)?.1.as_str();
            let y = r.metrics[col].filter(|v| v.is_finite())?;
            Some((r.variant.as_str(), value, y))
        })
        .collect();
    if points.is_empty() {
        return None;
    }
    let mut categories: Vec<&str> = Vec::new();
    for (_, v, _) in &points {
        if !categories.contains(v) {
            categories.push(v);
        }
    }
    let (lo, hi) = points
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(p.2), b.max(p.2))
        });
    let span = if hi > lo { hi - lo } else { 1.0 };
    let (w, h, left, bottom) = (360.0, 220.0, 70.0, 40.0);
    let x = |i: usize| left + (i as f64 + 0.5) * (w - left - 10.0) / categories.len() as f64;
    let y = |v: f64| 10.0 + (h - bottom - 10.0) * (1.0 - (v - lo) / span);
    let mut s = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" viewBox=\"0 0 {w} {h}\" width=\"{w}\" height=\"{h}\" role=\"img\"><title>{} against {}</title>",
        esc(&c.metrics[col]),
        esc(key)
    );
    let _ = write!(
        s,
        "<line x1=\"{left}\" y1=\"10\" x2=\"{left}\" y2=\"{}\" stroke=\"#888\"/><line x1=\"{left}\" y1=\"{0}\" x2=\"{}\" y2=\"{0}\" stroke=\"#888\"/>",
        h - bottom,
        w - 10.0
    );
    for (v, anchor) in [(hi, "hi"), (lo, "lo")] {
        let _ = write!(
            s,
            "<text class=\"{anchor}\" x=\"{}\" y=\"{}\" text-anchor=\"end\" font-size=\"11\">{}</text>",
            left - 4.0,
            y(v) + 4.0,
            esc(&shown(v))
        );
    }
    for (i, cat) in categories.iter().enumerate() {
        let _ = write!(
            s,
            "<text x=\"{}\" y=\"{}\" text-anchor=\"middle\" font-size=\"11\">{}</text>",
            x(i),
            h - bottom + 16.0,
            esc(cat)
        );
    }
    for (variant, value, v) in &points {
        let i = categories.iter().position(|c| c == value).expect("listed");
        let _ = write!(
            s,
            "<circle cx=\"{:.1}\" cy=\"{:.1}\" r=\"4\" fill=\"#2a6fb0\" fill-opacity=\"0.7\"><title>{}: {v}</title></circle>",
            x(i),
            y(*v),
            esc(variant)
        );
    }
    s.push_str("</svg>");
    Some(s)
}

/// The page.
pub fn to_html(c: &Comparison, best: &str) -> String {
    let mut s = format!(
        "<!doctype html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>Sweep {0}</title><style>\
         body{{font-family:sans-serif;margin:2em;max-width:80em}}table{{border-collapse:collapse}}\
         th,td{{border:1px solid #ccc;padding:3px 8px;text-align:left}}th{{cursor:pointer;background:#f4f4f4}}\
         tr.failed td,tr.missing td{{color:#a00}}tr.best td{{background:#eef8ee}}figure{{display:inline-block;margin:1em}}\
         </style></head><body><h1>Sweep <code>{0}</code></h1><p id=\"best\">{1}</p>",
        esc(&c.name),
        esc(best)
    );
    let best_variant = c.best().map(|r| r.variant.clone());
    s.push_str(
        "<table id=\"comparison\"><thead><tr><th>variant</th><th>overrides</th><th>status</th>",
    );
    for m in &c.metrics {
        let _ = write!(s, "<th>{}</th>", esc(m));
    }
    s.push_str(
        "<th>total ms</th><th>computed ms</th><th>computed</th><th>reused</th></tr></thead><tbody>",
    );
    for r in &c.rows {
        let class = if best_variant.as_deref() == Some(r.variant.as_str()) {
            "best"
        } else {
            r.status.name()
        };
        let status = match &r.status {
            Status::Failed(why) => format!("failed: {why}"),
            other => other.name().to_string(),
        };
        let overrides: Vec<String> = r
            .overrides
            .iter()
            .map(|(k, v)| format!("{k}={v}"))
            .collect();
        let _ = write!(
            s,
            "<tr class=\"{class}\"><td>{}</td><td>{}</td><td>{}</td>",
            esc(&r.variant),
            esc(&overrides.join("; ")),
            esc(&status)
        );
        for m in &r.metrics {
            let _ = write!(
                s,
                "<td data-v=\"{}\">{}</td>",
                m.map(|v| v.to_string()).unwrap_or_default(),
                m.map(shown).unwrap_or_else(|| "-".into())
            );
        }
        let num = |v: Option<f64>| v.map(|x| format!("{x:.0}")).unwrap_or_else(|| "-".into());
        let _ = write!(
            s,
            "<td data-v=\"{}\">{}</td><td data-v=\"{}\">{}</td><td>{}</td><td>{}</td></tr>",
            r.total_ms.unwrap_or(f64::NAN),
            num(r.total_ms),
            r.computed_ms.unwrap_or(f64::NAN),
            num(r.computed_ms),
            r.computed,
            r.reused
        );
    }
    s.push_str("</tbody></table>");
    let keys = plot_keys(c);
    let plots: Vec<String> = (0..c.metrics.len())
        .flat_map(|col| keys.iter().filter_map(move |k| plot(c, col, k)))
        .collect();
    if !plots.is_empty() {
        s.push_str("<h2>Metrics against the varied values</h2>");
        s.push_str(&plots.concat());
    }
    // Sorting: numbers by data-v (empty last), text otherwise; a second click
    // reverses. `comparison.html#sort=COLUMN` (or `#sort=-COLUMN`, descending)
    // opens the page sorted, so a sorted view can be linked.
    s.push_str(
        "<script>const heads=[...document.querySelectorAll('#comparison th')];\
         function sortBy(i,dir){const body=document.querySelector('#comparison').tBodies[0];const rows=[...body.rows];\
         const key=r=>{const c=r.cells[i];const v=c.dataset.v;if(v!==undefined){const x=parseFloat(v);return isNaN(x)?null:x;}return c.textContent;};\
         rows.sort((a,b)=>{const x=key(a),y=key(b);if(x===null&&y===null)return 0;if(x===null)return 1;if(y===null)return -1;return (x<y?-1:x>y?1:0)*dir;});\
         rows.forEach(r=>body.appendChild(r));heads[i].dataset.dir=dir===1?'1':'-1';}\
         heads.forEach((th,i)=>th.addEventListener('click',()=>sortBy(i,th.dataset.dir==='1'?-1:1)));\
         const m=decodeURIComponent(location.hash).match(/^#sort=(-?)(.+)$/);\
         if(m){const i=heads.findIndex(h=>h.textContent===m[2]);if(i>=0)sortBy(i,m[1]?-1:1);}</script></body></html>\n",
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sweep::compare::Row;

    fn row(name: &str, overrides: &[(&str, &str)], status: Status, tre: f64) -> Row {
        Row {
            variant: name.into(),
            overrides: overrides
                .iter()
                .map(|(k, v)| (k.to_string(), v.to_string()))
                .collect(),
            status,
            metrics: vec![Some(tre)],
            total_ms: Some(1.0),
            computed_ms: Some(1.0),
            computed: 1,
            reused: 0,
            nodes: vec![],
        }
    }

    #[test]
    fn named_variants_are_plotted_against_each_key_they_vary() {
        // Conditions one at a time: JPEG at two levels, the lamp at one, a
        // preset at two, one of them failed.
        let c = Comparison {
            name: "conditions".into(),
            metrics: vec!["evaluate.tre_mm".into()],
            varied: vec![],
            rank_by: None,
            rows: vec![
                row(
                    "ideal",
                    &[("phantom.conditions", "\"ideal\"")],
                    Status::Done,
                    0.2,
                ),
                row(
                    "lab",
                    &[("phantom.conditions", "\"lab\"")],
                    Status::Done,
                    0.5,
                ),
                row(
                    "jpeg_90",
                    &[("phantom.jpeg_quality", "90")],
                    Status::Done,
                    0.3,
                ),
                row(
                    "jpeg_50",
                    &[("phantom.jpeg_quality", "50")],
                    Status::Done,
                    0.9,
                ),
                row(
                    "warm",
                    &[("phantom.lamp_kelvin", "[2700.0]")],
                    Status::Done,
                    0.2,
                ),
                row(
                    "jpeg_10",
                    &[("phantom.jpeg_quality", "10")],
                    Status::Failed("merge".into()),
                    f64::NAN,
                ),
            ],
        };
        assert_eq!(
            plot_keys(&c),
            ["phantom.conditions", "phantom.jpeg_quality"]
        );
        let files = plot_files(&c);
        let names: Vec<&str> = files.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(
            names,
            [
                "evaluate.tre_mm_against_phantom.conditions.svg",
                "evaluate.tre_mm_against_phantom.jpeg_quality.svg"
            ]
        );
        let (_, jpeg) = &files[1];
        assert!(jpeg.starts_with("<svg xmlns=\"http://www.w3.org/2000/svg\""));
        // Two dots, the failed variant left out, each titled by its variant.
        assert_eq!(jpeg.matches("<circle").count(), 2);
        assert!(jpeg.contains("jpeg_90: 0.3") && jpeg.contains("jpeg_50: 0.9"));
        assert!(to_html(&c, "").contains("against <code>phantom.jpeg_quality</code>"));
    }
}
