//! Giving freed memory back to the system between nodes.
//!
//! glibc's allocator keeps what a node freed for the next allocation rather
//! than returning it: a node's large buffers (cost volumes, scale spaces)
//! stay in the process's resident memory after it finished, and two such
//! nodes in turn add up in the job's peak. Trimming after each large node
//! returns them (free pages inside the heap too, by `madvise`): the main
//! job's peak 314 -> 274 MB, its CPU time unchanged within the machine's
//! noise (user + system 26.0 s against 26.8 s). A lower `mmap` threshold
//! returns them too, but maps and faults every large buffer anew: 7-20 %
//! slower for 274-282 MB.

/// Nodes that ran at least this long are followed by a trim (small nodes
/// allocate little, and a trim walks the allocator's free lists).
pub const TRIM_AFTER_MS: f64 = 20.0;

/// Returns the allocator's free memory to the system (glibc's
/// `malloc_trim`); nothing elsewhere.
pub fn return_free_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        unsafe extern "C" {
            fn malloc_trim(pad: usize) -> std::ffi::c_int;
        }
        // SAFETY: malloc_trim takes no pointers and is thread-safe (it
        // locks each arena it trims).
        unsafe {
            malloc_trim(0);
        }
    }
}
