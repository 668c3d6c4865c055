//! The `dicom.*` ops: one file per op, each its declaration and thin adapter.

mod load_series;

pub use load_series::{LoadSeries, LoadSeriesInputs, LoadSeriesOutputs};
