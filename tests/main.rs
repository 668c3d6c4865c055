//! The root crate's integration tests, in one binary: one link instead of
//! nine, and the test runner spreads all of them over the cores at once (the
//! Slurm test, which mostly waits, runs beside the graphs that compute).
//! Run one file's tests with its module name as a filter, e.g.
//! `cargo test --test integration cli::`.

mod common;

mod bad_input_corpus;
mod bad_inputs;
mod cli;
mod op_declarations;
mod plugins;
mod real_inputs;
mod report;
mod slurm;
mod sweeps;
