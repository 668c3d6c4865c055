//! The `fusegraph` command line as a library ([`cli::main`]), so that the
//! Python package's entry point runs the very same commands with its Python
//! ops (see `python/`). The binary (`src/main.rs`) only calls it.

mod bench;
mod bench_calibration;
mod bench_chessboard;
mod bench_deformable;
mod bench_phantom;
mod bench_refine;
mod bench_sgm;
pub mod cli;
mod list;
