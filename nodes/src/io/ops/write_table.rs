//! `io.write_table`: a table as CSV and as a Markdown table.

use crate::io::{table_csv, table_markdown};
use fusegraph_engine::path_value;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{PathValue, Table};

/// Write a table as CSV and Markdown under the output folder
#[derive(Op)]
#[op(name = "io.write_table", version = 1, writes_output)]
pub struct WriteTable {
    /// Base name: writes NAME.csv and NAME.md
    #[param(default = "table")]
    pub file: String,
    /// Significant digits in the Markdown
    #[param(default = 4, min = 1, max = 17)]
    pub digits: usize,
}

#[derive(Inputs)]
pub struct WriteTableInputs {
    /// The table
    pub table: Arc<Table>,
}

#[derive(Outputs)]
pub struct WriteTableOutputs {
    /// The CSV file
    pub csv: PathValue,
    /// The Markdown file
    pub markdown: PathValue,
}

impl RunOp for WriteTable {
    type Inputs = WriteTableInputs;
    type Outputs = WriteTableOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let (t, name) = (inputs.table, &self.file);
        let csv = ctx.output_path(&format!("{name}.csv"))?;
        std::fs::write(&csv, table_csv(&t)).map_err(|e| OpError::io(&csv, e))?;
        let md = ctx.output_path(&format!("{name}.md"))?;
        std::fs::write(&md, table_markdown(&t, self.digits)).map_err(|e| OpError::io(&md, e))?;
        Ok(WriteTableOutputs {
            csv: path_value(&csv)?,
            markdown: path_value(&md)?,
        })
    }
}
