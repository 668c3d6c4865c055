//! The nodes crate's integration tests, one module per subject, in one
//! binary: each test binary links the whole crate and compiles its own copies
//! of what it uses from the DICOM, image and linear-algebra crates, and
//! `cargo test` runs binaries one after another: as eight binaries they took
//! longer to build, and a core could idle while one ran its one or two
//! tests. Run one subject with
//! `cargo test -p fusegraph-nodes --test integration phantom::`.
//!
//! `fuzz.rs` stays a binary of its own: it holds its process's peak memory
//! to a bound and runs for a time budget, which other tests in the same
//! process would disturb.

use fusegraph_nodes::phantom::{GroundTruth, PhantomConfig, PhantomSize, generate};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

mod cache_gc;
mod code_fingerprints;
mod dicom_files;
mod dicom_folders;
mod mri_volumes;
mod phantom;
mod registration;
mod stereo_markers;

/// The phantom's size these tests run on: `small` unless
/// FUSEGRAPH_TEST_PHANTOM_SIZE=full asks for the accuracy-grade one.
fn phantom_size() -> PhantomSize {
    let size = std::env::var("FUSEGRAPH_TEST_PHANTOM_SIZE").unwrap_or_else(|_| "small".into());
    PhantomSize::parse(&size).expect("FUSEGRAPH_TEST_PHANTOM_SIZE is small or full")
}

/// The default phantom at [`phantom_size`], generated once per run (the
/// generator's own tests and the marker detector's read it) into a folder
/// of the target's, and its truth.
fn shared_phantom() -> &'static (PathBuf, GroundTruth) {
    static PHANTOM: OnceLock<(PathBuf, GroundTruth)> = OnceLock::new();
    PHANTOM.get_or_init(|| {
        let size = phantom_size();
        let dir =
            Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("phantom-tests-{}", size.name()));
        let _ = std::fs::remove_dir_all(&dir);
        let config = PhantomConfig {
            size,
            ..PhantomConfig::default()
        };
        let g = generate(&config, &dir).unwrap();
        (dir, g.truth)
    })
}
