//! Records what the `fusegraph` build was made from, for every report's
//! provenance (see `src/cli.rs`): the git commit and whether the tree had
//! uncommitted changes, rustc's version and the target. Without git (a
//! source archive) the commit is "unknown".

use std::process::Command;

fn output(cmd: &mut Command) -> Option<String> {
    let out = cmd.output().ok().filter(|o| o.status.success())?;
    Some(String::from_utf8_lossy(&out.stdout).trim().to_string())
}

fn main() {
    let commit = output(Command::new("git").args(["rev-parse", "HEAD"]));
    let dirty = output(Command::new("git").args(["status", "--porcelain", "--untracked-files=no"]))
        .map(|s| !s.is_empty());
    let rustc = std::env::var("RUSTC").unwrap_or_else(|_| "rustc".into());
    let rustc_version = output(Command::new(rustc).arg("--version"));
    let target = std::env::var("TARGET").unwrap_or_default();
    println!(
        "cargo:rustc-env=FUSEGRAPH_GIT_COMMIT={}",
        commit.as_deref().unwrap_or("unknown")
    );
    println!(
        "cargo:rustc-env=FUSEGRAPH_GIT_DIRTY={}",
        dirty.map_or("unknown", |d| if d { "true" } else { "false" })
    );
    println!(
        "cargo:rustc-env=FUSEGRAPH_RUSTC={}",
        rustc_version.as_deref().unwrap_or("unknown")
    );
    println!("cargo:rustc-env=FUSEGRAPH_TARGET={target}");
    // A new commit (HEAD's branch moves), a staged change or an edited
    // source runs this again.
    for path in [
        ".git/HEAD",
        ".git/index",
        ".git/packed-refs",
        "src",
        "engine/src",
        "nodes/src",
        "python/src",
    ] {
        println!("cargo:rerun-if-changed={path}");
    }
    if let Some(branch) = std::fs::read_to_string(".git/HEAD")
        .ok()
        .and_then(|h| h.strip_prefix("ref: ").map(|r| r.trim().to_string()))
    {
        println!("cargo:rerun-if-changed=.git/{branch}");
    }
}
