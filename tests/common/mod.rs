//! Helpers shared by the CLI's end-to-end tests.

use std::path::Path;
use std::process::{Command, Output};

/// Runs the `fusegraph` binary with `args` in `cwd`.
pub fn fusegraph(args: &[&str], cwd: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_fusegraph"))
        .args(args)
        .current_dir(cwd)
        .output()
        .expect("fusegraph runs")
}

/// What a run printed on stderr.
pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}
