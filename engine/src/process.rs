//! This process and this machine as other processes sharing a cache see them:
//! the host name written into leases and private folder names, and whether a
//! process of this host is still alive.

use std::path::Path;

/// This machine's name as it appears in temporary folder names (letters,
/// digits, `.` and `_` only), so that on a shared cache a process cleans only
/// what its own machine's dead processes left.
pub fn host_name() -> &'static str {
    static NAME: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    NAME.get_or_init(|| {
        let raw = std::fs::read_to_string("/proc/sys/kernel/hostname")
            .or_else(|_| std::fs::read_to_string("/etc/hostname"))
            .unwrap_or_else(|_| "localhost".into());
        let name: String = raw
            .trim()
            .chars()
            .map(|c| {
                if c.is_ascii_alphanumeric() || c == '.' {
                    c
                } else {
                    '_'
                }
            })
            .collect();
        if name.is_empty() {
            "localhost".into()
        } else {
            name
        }
    })
}

/// Whether process `pid` of this machine is alive; `true` where that cannot
/// be told (so nothing of a live process is ever removed).
pub fn process_alive(pid: u32) -> bool {
    if cfg!(target_os = "linux") {
        Path::new("/proc").join(pid.to_string()).exists()
    } else {
        true
    }
}
