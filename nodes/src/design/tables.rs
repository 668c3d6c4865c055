//! Tables of the design ops' results.

use fusegraph_engine::OpError;
use fusegraph_engine::value::Table;

/// A table of `columns` from rows of numbers (each as long as `columns`).
pub(crate) fn table(columns: &[&str], rows: Vec<Vec<f64>>) -> Result<Table, OpError> {
    Table::new(
        columns.iter().map(|c| c.to_string()).collect(),
        rows.concat(),
    )
    .map_err(|e| OpError::invalid(e.0))
}
