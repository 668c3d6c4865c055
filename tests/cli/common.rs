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

/// Runs the `fusegraph` binary with `args` in `cwd` under an address-space
/// limit of `memory_bytes` (so a run that would allocate beyond it fails, as
/// under a cluster's memory limit), killing it if it runs longer than `time`:
/// a hang fails the test instead of stalling the suite.
#[cfg(target_os = "linux")]
pub fn limited(args: &[&str], cwd: &Path, memory_bytes: u64, time: std::time::Duration) -> Output {
    use std::os::unix::process::CommandExt;
    use std::process::Stdio;
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_fusegraph"));
    cmd.args(args)
        .current_dir(cwd)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    // SAFETY: setrlimit is async-signal-safe; the child only calls it
    // between fork and exec.
    unsafe {
        cmd.pre_exec(move || {
            let limit = libc::rlimit {
                rlim_cur: memory_bytes,
                rlim_max: memory_bytes,
            };
            if libc::setrlimit(libc::RLIMIT_AS, &limit) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    let mut child = cmd.spawn().expect("fusegraph starts");
    // Drain the pipes while waiting, so a chatty child cannot block on them.
    let drain = |pipe: Option<Box<dyn std::io::Read + Send>>| {
        std::thread::spawn(move || {
            let mut bytes = Vec::new();
            if let Some(mut p) = pipe {
                let _ = p.read_to_end(&mut bytes);
            }
            bytes
        })
    };
    let out = drain(child.stdout.take().map(|p| Box::new(p) as _));
    let err = drain(child.stderr.take().map(|p| Box::new(p) as _));
    let start = std::time::Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().expect("wait") {
            break status;
        }
        if start.elapsed() > time {
            let _ = child.kill();
            panic!("fusegraph {args:?} still running after {time:?}: a hang");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    };
    Output {
        status,
        stdout: out.join().expect("stdout read"),
        stderr: err.join().expect("stderr read"),
    }
}

/// The browser's command, if one is installed (Debian's chromium; tests that
/// need it skip with a message otherwise).
pub fn chromium() -> Option<&'static str> {
    ["chromium", "chromium-browser", "google-chrome"]
        .into_iter()
        .find(|c| {
            Command::new(c)
                .arg("--version")
                .output()
                .is_ok_and(|o| o.status.success())
        })
}
