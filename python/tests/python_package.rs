//! Runs the Python package's tests (`python/tests/test_*.py`, unittest)
//! against the module cargo just built, so `cargo test --workspace` tests
//! the package without maturin: the module and the package's Python files
//! are laid out in a temporary folder put on PYTHONPATH. Needs python3 with
//! numpy; where numpy is missing, a venv under the target folder gets it
//! from PyPI; where neither works, the test says so and passes (the Rust
//! suite must run with only the Rust toolchain).

use std::path::{Path, PathBuf};
use std::process::Command;

/// target/debug (or the profile's folder) of this test binary.
fn profile_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("the test binary's path");
    exe.parent()
        .and_then(Path::parent)
        .expect("target/<profile>/deps")
        .to_path_buf()
}

fn python_with_numpy(profile: &Path) -> Result<PathBuf, String> {
    let python = std::env::var_os("PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(|| "python3".into());
    let has_numpy = |py: &Path| {
        Command::new(py)
            .args(["-c", "import numpy"])
            .output()
            .is_ok_and(|o| o.status.success())
    };
    match Command::new(&python).arg("--version").output() {
        Ok(o) if o.status.success() => {}
        _ => return Err(format!("{} not found", python.display())),
    }
    if has_numpy(&python) {
        return Ok(python);
    }
    let venv = profile.join("python-venv");
    let venv_python = venv.join("bin").join("python");
    if !has_numpy(&venv_python) {
        let made = Command::new(&python)
            .args(["-m", "venv"])
            .arg(&venv)
            .status();
        let installed = made.is_ok_and(|s| s.success())
            && Command::new(&venv_python)
                .args(["-m", "pip", "install", "-q", "numpy"])
                .status()
                .is_ok_and(|s| s.success());
        if !installed {
            return Err("numpy is not installed and could not be installed into a venv".into());
        }
    }
    Ok(venv_python)
}

#[test]
fn the_python_package_passes_its_tests() {
    if std::env::var("FUSEGRAPH_PYTHON_TESTS").is_ok_and(|v| v == "pytest") {
        eprintln!(
            "skipped: .ci/run runs the Python tests with pytest on the package maturin builds"
        );
        return;
    }
    let profile = profile_dir();
    let python = match python_with_numpy(&profile) {
        Ok(p) => p,
        Err(why) => {
            eprintln!("skipped: the Python package's tests need python3 with numpy: {why}");
            return;
        }
    };
    // cargo builds the module for this test into deps/ (the rlib lets it);
    // `cargo build` puts it beside deps/: the newer one is this source's.
    let name = format!("lib_native{}", std::env::consts::DLL_SUFFIX);
    let module = [profile.join("deps").join(&name), profile.join(&name)]
        .into_iter()
        .filter_map(|p| Some((std::fs::metadata(&p).ok()?.modified().ok()?, p)))
        .max()
        .map(|(_, p)| p)
        .expect("cargo built the module (python/src) for this test");
    let source = Path::new(env!("CARGO_MANIFEST_DIR"));
    let stage = tempfile::tempdir().expect("a temporary folder");
    let package = stage.path().join("fusegraph");
    std::fs::create_dir(&package).unwrap();
    for entry in std::fs::read_dir(source.join("fusegraph")).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "py") {
            std::fs::copy(&path, package.join(path.file_name().unwrap())).unwrap();
        }
    }
    std::fs::copy(&module, package.join("_native.abi3.so")).unwrap();
    let mut cmd = Command::new(&python);
    cmd.args(["-m", "unittest", "discover", "-v", "-s"])
        .arg(source.join("tests"))
        .env("PYTHONPATH", stage.path())
        .current_dir(stage.path());
    let binary = profile.join("fusegraph");
    if binary.is_file() {
        cmd.env("FUSEGRAPH_BIN", &binary);
    }
    let out = cmd.output().expect("python runs");
    let log = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "the Python tests failed:\n{log}");
    eprintln!("{log}");
}
