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
//! slower for 274-282 MB. Below a budget of resident memory, freed memory
//! is kept for reuse ([`KEEP_FREED_BELOW_BYTES`]).

/// Nodes that ran at least this long are followed by a trim (small nodes
/// allocate little, and a trim walks the allocator's free lists).
pub const TRIM_AFTER_MS: f64 = 20.0;

/// Below this much resident memory, what a node freed stays with the
/// allocator for the next nodes to reuse; above it, it is returned after
/// each large node. Returning everything had the main job fault in and zero
/// 1.9 GB of fresh pages (476k faults, a tenth of its CPU, in the kernel);
/// keeping freed memory below 200 MB: 140-157k faults, 6.8-6.9 -> 6.5-6.6 s,
/// peak RSS 249-262 MB (its peak is live data). Measured budgets: 128 MB 299k
/// faults, 160 MB 212k, 224 MB 151k; 256 MB and above never trim (peak 289
/// MB). A job whose live data are larger is trimmed after each large node,
/// as before.
pub const KEEP_FREED_BELOW_BYTES: u64 = 200 << 20;

/// The process's resident memory, bytes (`VmRSS` in Linux's
/// `/proc/self/status`); `None` elsewhere or where it cannot be read.
pub fn resident_bytes() -> Option<u64> {
    vm_rss_bytes(&std::fs::read_to_string("/proc/self/status").ok()?)
}

/// The `VmRSS` line of a `/proc/<pid>/status` text, bytes.
fn vm_rss_bytes(status: &str) -> Option<u64> {
    let line = status.lines().find_map(|l| l.strip_prefix("VmRSS:"))?;
    let kib: u64 = line.trim().strip_suffix("kB")?.trim().parse().ok()?;
    Some(kib << 10)
}

/// [`return_free_memory`] where the process holds more than
/// [`KEEP_FREED_BELOW_BYTES`] resident, or where that cannot be told.
pub fn return_free_memory_if_large() {
    if resident_bytes().is_none_or(|r| r > KEEP_FREED_BELOW_BYTES) {
        return_free_memory();
    }
}

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_resident_size_is_read_from_the_status_text() {
        let status = "Name:\tfusegraph\nVmPeak:\t  300000 kB\nVmRSS:\t   12345 kB\nThreads:\t3\n";
        assert_eq!(vm_rss_bytes(status), Some(12345 * 1024));
        for bad in [
            "",
            "VmRSS:\t12345 MB\n",
            "VmRSS:\tlots kB\n",
            "VmHWM:\t1 kB\n",
        ] {
            assert_eq!(vm_rss_bytes(bad), None, "{bad:?}");
        }
        #[cfg(target_os = "linux")]
        assert!(resident_bytes().is_some_and(|b| b > 0));
    }
}
