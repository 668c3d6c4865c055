//! [`Table`]: rows of named numbers.

use super::{ValueError, check_len};
use serde::Serialize;
use std::sync::Arc;

/// A table of f64 numbers: named columns (put units in the names, e.g.
/// `"baseline_mm"`), rows stored row-major in one buffer.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Table {
    /// Column names.
    pub columns: Vec<String>,
    /// `rows * columns.len()` numbers, row-major.
    pub data: Arc<[f64]>,
}

impl Table {
    /// Checks that the data fills whole rows.
    pub fn new(columns: Vec<String>, data: impl Into<Arc<[f64]>>) -> Result<Self, ValueError> {
        let data = data.into();
        if columns.is_empty() {
            return Err(ValueError("Table: no columns".into()));
        }
        let rows = data.len() / columns.len();
        check_len("Table", data.len(), rows * columns.len())?;
        Ok(Table { columns, data })
    }

    /// Number of rows.
    pub fn row_count(&self) -> usize {
        self.data.len() / self.columns.len()
    }

    /// Row `r` as a slice, one number per column.
    pub fn row(&self, r: usize) -> &[f64] {
        let n = self.columns.len();
        &self.data[r * n..(r + 1) * n]
    }

    /// The values of the column called `name`, if there is one.
    pub fn column(&self, name: &str) -> Option<Vec<f64>> {
        let c = self.columns.iter().position(|n| n == name)?;
        Some((0..self.row_count()).map(|r| self.row(r)[c]).collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_and_columns() {
        let t = Table::new(vec!["a".into(), "b".into()], vec![1.0, 2.0, 3.0, 4.0]).unwrap();
        assert_eq!(t.row_count(), 2);
        assert_eq!(t.row(1), &[3.0, 4.0]);
        assert_eq!(t.column("b"), Some(vec![2.0, 4.0]));
        assert!(Table::new(vec!["a".into(), "b".into()], vec![1.0, 2.0, 3.0]).is_err());
    }
}
