//! The `fusegraph` binary: the command line of [`fusegraph::cli`], without
//! Python (a graph that names a Python file is refused with what to do).

use std::process::ExitCode;

fn main() -> ExitCode {
    reuse_large_buffers();
    fusegraph::cli::quiet_on_broken_pipe();
    fusegraph_engine::panics::install_hook();
    ExitCode::from(fusegraph::cli::main(std::env::args_os(), None))
}

/// Keeps freed buffers of up to 32 MB in the heap for the next stage to
/// reuse. Stages allocate and free such buffers by the dozen (an 800 x 600
/// image's f32 planes and per-pixel records, a disparity volume's rows);
/// glibc maps each afresh by default, and the page faults and zeroing
/// took 14 % of the phantom's CPU. Measured (2 cores): `fusegraph phantom`
/// 3.1 -> 2.7-2.9 s (system time 0.9 -> 0.15 s), the main job's peak RSS
/// 254 -> 259 MB. (mimalloc was tried too: no faster, peak RSS 320-350 MB.)
/// Only the binary: the Python module leaves its host's allocator alone.
fn reuse_large_buffers() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets two of glibc's allocator thresholds, and
    // runs before any thread is started.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 64 << 20);
    }
}
