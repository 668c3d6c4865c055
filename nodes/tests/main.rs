//! fusegraph-nodes' integration tests, in one binary: one link instead of
//! nine, and the test runner spreads all of them over the cores at once.
//! Run one file's tests with its module name as a filter, e.g.
//! `cargo test -p fusegraph-nodes --test integration phantom::`.

mod cache_gc;
mod code_fingerprints;
mod dicom_files;
mod dicom_folders;
mod fuzz;
mod mri_volumes;
mod phantom;
mod registration;
mod stereo_markers;
