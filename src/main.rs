//! The `fusegraph` binary: the command line of [`fusegraph::cli`], without
//! Python (a graph that names a Python file is refused with what to do).

use std::process::ExitCode;

fn main() -> ExitCode {
    fusegraph::cli::quiet_on_broken_pipe();
    fusegraph_engine::panics::install_hook();
    ExitCode::from(fusegraph::cli::main(std::env::args_os(), None))
}
