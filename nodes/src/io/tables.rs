//! Tables as text: CSV and Markdown (what `io.write_table` writes).

use fusegraph_engine::value::Table;

/// CSV with a header row; numbers in full precision.
pub fn table_csv(t: &Table) -> String {
    let mut s = t.columns.join(",") + "\n";
    for r in 0..t.row_count() {
        s += &t
            .row(r)
            .iter()
            .map(|v| v.to_string())
            .collect::<Vec<_>>()
            .join(",");
        s.push('\n');
    }
    s
}

/// A Markdown table with `digits` significant digits.
pub fn table_markdown(t: &Table, digits: usize) -> String {
    let fmt = |v: f64| {
        if v == 0.0 || !v.is_finite() {
            return format!("{v}");
        }
        let magnitude = v.abs().log10().floor() as i32;
        let decimals = (digits as i32 - 1 - magnitude).max(0) as usize;
        format!("{v:.decimals$}")
    };
    let mut s = format!(
        "| {} |\n|{}|\n",
        t.columns.join(" | "),
        vec![" ---: "; t.columns.len()].join("|")
    );
    for r in 0..t.row_count() {
        s += &format!(
            "| {} |\n",
            t.row(r)
                .iter()
                .map(|&v| fmt(v))
                .collect::<Vec<_>>()
                .join(" | ")
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_and_markdown() {
        let t = Table::new(
            vec!["b_mm".into(), "var_mm2".into()],
            vec![50.0, 11.8612, 100.0, 0.004567],
        )
        .unwrap();
        assert_eq!(table_csv(&t), "b_mm,var_mm2\n50,11.8612\n100,0.004567\n");
        let md = table_markdown(&t, 3);
        assert!(md.starts_with("| b_mm | var_mm2 |\n"), "{md}");
        assert!(
            md.contains("| 50.0 | 11.9 |") && md.contains("| 100 | 0.00457 |"),
            "{md}"
        );
    }
}
