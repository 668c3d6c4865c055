//! `plot.lines`: a line plot of table columns, written as PNG.

use crate::plot::{LinePlot, draw_lines};
use fusegraph_engine::path_value;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{PathValue, Table};

/// Line plot (PNG) of table columns against one column
#[derive(Op)]
#[op(name = "plot.lines", version = 1, writes_output)]
pub struct Lines {
    /// Column on the x axis (default: the first)
    #[param(default = "")]
    pub x: String,
    /// Columns drawn as lines (default: all others)
    #[param(default = [])]
    pub y: Vec<String>,
    /// Title
    #[param(default = "")]
    pub title: String,
    /// x axis label (default: the column name)
    #[param(default = "")]
    pub x_label: String,
    /// y axis label
    #[param(default = "")]
    pub y_label: String,
    /// Logarithmic x axis
    #[param(default = false)]
    pub log_x: bool,
    /// Logarithmic y axis
    #[param(default = false)]
    pub log_y: bool,
    /// Width and height
    #[param(default = [800, 560], unit = "px", min = 100, max = 8000)]
    pub size_px: [u32; 2],
    /// PNG file, relative to the output folder
    #[param(default = "plot.png")]
    pub file: String,
}

#[derive(Inputs)]
pub struct LinesInputs {
    /// The table
    pub table: Arc<Table>,
}

#[derive(Debug, Outputs)]
pub struct LinesOutputs {
    /// The PNG
    pub file: PathValue,
}

impl RunOp for Lines {
    type Inputs = LinesInputs;
    type Outputs = LinesOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let t = inputs.table;
        let x = match &self.x {
            x if x.is_empty() => t.columns[0].clone(),
            x => x.clone(),
        };
        let y = match &self.y {
            y if y.is_empty() => t.columns.iter().filter(|c| **c != x).cloned().collect(),
            y => y.clone(),
        };
        let [w, h] = self.size_px;
        let plot = LinePlot {
            x_label: match &self.x_label {
                l if l.is_empty() => x.clone(),
                l => l.clone(),
            },
            x,
            y,
            title: self.title.clone(),
            y_label: self.y_label.clone(),
            log_x: self.log_x,
            log_y: self.log_y,
            size_px: (w, h),
        };
        let path = ctx.output_path(&self.file)?;
        draw_lines(&t, &plot, &path)
            .map_err(|e| OpError::invalid(format!("{}: {e}", path.display())))?;
        Ok(LinesOutputs {
            file: path_value(&path)?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plots_every_other_column_against_the_first_by_default() {
        let table = Table::new(
            vec!["b".into(), "v".into(), "w".into()],
            vec![5.0, 11.9, 1.0, 10.0, 2.8, 2.0, 25.0, 0.38, 3.0],
        )
        .unwrap();
        let dir = tempfile::tempdir().unwrap();
        let mut ctx = RunCtx::new("plot", dir.path());
        let op = Lines {
            x: String::new(),
            y: Vec::new(),
            title: "t".into(),
            x_label: String::new(),
            y_label: String::new(),
            log_x: false,
            log_y: false,
            size_px: [200, 150],
            file: "sub/p.png".into(),
        };
        let out = op
            .run(
                LinesInputs {
                    table: Arc::new(table),
                },
                &mut ctx,
            )
            .unwrap();
        assert_eq!(out.file.path, dir.path().join("sub/p.png"));
        let img = image::open(&out.file.path).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (200, 150));
    }
}
