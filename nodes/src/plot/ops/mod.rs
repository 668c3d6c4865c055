//! The `plot.*` ops: one file per op, each its declaration and thin adapter.

mod lines;

pub use lines::{Lines, LinesInputs, LinesOutputs};
