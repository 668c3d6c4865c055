//! The shipped Slurm example (`graphs/sweeps/slurm/sweep.sbatch`) on a real
//! single-node Slurm cluster: slurmctld and slurmd started in the foreground
//! under a temporary folder (no munge: `auth/none`, `cred/none`), a sweep
//! sharded over a job array and merged by the dependent job, compared with
//! the same sweep in one process; one task cancelled mid-run and re-run
//! alone; other array numberings. Skipped, saying why, where Slurm is not
//! installed (`.ci/run` installs Debian's slurm-wlm where it can) or the
//! test does not run as root (slurmd must).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_fusegraph")
}

fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

/// A running single-node cluster; its daemons are stopped when dropped.
struct Cluster {
    dir: tempfile::TempDir,
    conf: PathBuf,
    daemons: Vec<Child>,
}

impl Drop for Cluster {
    fn drop(&mut self) {
        for d in &mut self.daemons {
            let _ = d.kill();
            let _ = d.wait();
        }
    }
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free port")
}

fn found(program: &str) -> bool {
    Command::new("sh")
        .args(["-c", &format!("command -v {program}")])
        .stdout(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

impl Cluster {
    fn start() -> Result<Cluster, String> {
        for p in [
            "slurmctld",
            "slurmd",
            "sbatch",
            "squeue",
            "scancel",
            "sinfo",
        ] {
            if !found(p) {
                return Err(format!("`{p}` not found (Debian: apt install slurm-wlm)"));
            }
        }
        // SAFETY: geteuid has no preconditions.
        if unsafe { libc::geteuid() } != 0 {
            return Err("slurmd must run as root".into());
        }
        let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
        let d = dir.path();
        for sub in ["state", "spool", "log"] {
            std::fs::create_dir(d.join(sub)).map_err(|e| e.to_string())?;
        }
        let host = String::from_utf8_lossy(
            &Command::new("hostname")
                .output()
                .map_err(|e| e.to_string())?
                .stdout,
        )
        .trim()
        .to_string();
        let cpus = std::thread::available_parallelism().map_or(1, |n| n.get());
        let conf = d.join("slurm.conf");
        let text = format!(
            "ClusterName=fusegraph-test\nSlurmctldHost={host}\nSlurmctldPort={}\nSlurmdPort={}\n\
             AuthType=auth/none\nCredType=cred/none\nSlurmUser=root\nSlurmdUser=root\n\
             StateSaveLocation={d}/state\nSlurmdSpoolDir={d}/spool\n\
             SlurmctldPidFile={d}/slurmctld.pid\nSlurmdPidFile={d}/slurmd.pid\n\
             SlurmctldLogFile={d}/log/slurmctld.log\nSlurmdLogFile={d}/log/slurmd.log\n\
             SelectType=select/cons_tres\nSelectTypeParameters=CR_Core\n\
             ProctrackType=proctrack/linuxproc\nTaskPlugin=task/none\nMpiDefault=none\n\
             ReturnToService=2\nSchedulerType=sched/backfill\nJobCompType=jobcomp/none\n\
             AccountingStorageType=accounting_storage/none\nMinJobAge=300\n\
             NodeName={host} CPUs={cpus} RealMemory=8000 State=UNKNOWN\n\
             PartitionName=main Nodes={host} Default=YES MaxTime=INFINITE State=UP\n",
            free_port(),
            free_port(),
            d = d.display()
        );
        std::fs::write(&conf, text).map_err(|e| e.to_string())?;
        let mut cluster = Cluster {
            dir,
            conf,
            daemons: Vec::new(),
        };
        for daemon in ["slurmctld", "slurmd"] {
            let log =
                std::fs::File::create(cluster.dir.path().join("log").join(format!("{daemon}.out")))
                    .map_err(|e| e.to_string())?;
            let child = Command::new(daemon)
                .arg("-D")
                .arg("-f")
                .arg(&cluster.conf)
                .stdout(log.try_clone().map_err(|e| e.to_string())?)
                .stderr(log)
                .spawn()
                .map_err(|e| format!("{daemon}: {e}"))?;
            cluster.daemons.push(child);
        }
        let start = Instant::now();
        loop {
            let state = cluster.run("sinfo", &["-h", "-o", "%t"]);
            if state.trim() == "idle" {
                return Ok(cluster);
            }
            if start.elapsed() > Duration::from_secs(60) {
                return Err(format!("the node is not idle after 60 s: {state:?}"));
            }
            std::thread::sleep(Duration::from_millis(300));
        }
    }

    fn command(&self, program: &str) -> Command {
        let mut c = Command::new(program);
        c.env("SLURM_CONF", &self.conf).current_dir(self.dir.path());
        c
    }

    fn run(&self, program: &str, args: &[&str]) -> String {
        let out = self
            .command(program)
            .args(args)
            .output()
            .expect("a Slurm command runs");
        String::from_utf8_lossy(&out.stdout).into_owned()
    }

    /// Submits `sweep.sbatch` as an array over `array` with `env`; the job id.
    fn submit(&self, array: &str, env: &[(&str, &str)], out: &Path, cache: &Path) -> String {
        let mut c = self.command("sbatch");
        c.arg(format!("--array={array}"))
            .arg("--export=ALL")
            .env("FUSEGRAPH", bin())
            .arg(repo("graphs/sweeps/slurm/sweep.sbatch"))
            .arg(repo("tests/data/slurm/sweep.toml"))
            .arg(out)
            .arg(cache);
        for (k, v) in env {
            c.env(k, v);
        }
        let o = c.output().expect("sbatch runs");
        let text = String::from_utf8_lossy(&o.stdout);
        assert!(
            o.status.success(),
            "sbatch: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        text.trim()
            .rsplit(' ')
            .next()
            .expect("Submitted batch job N")
            .to_string()
    }

    /// Waits until no job is queued or running (the merge included).
    fn wait_idle(&self, within: Duration) {
        let start = Instant::now();
        while !self.run("squeue", &["-h"]).trim().is_empty() {
            assert!(
                start.elapsed() < within,
                "jobs still queued after {within:?}:\n{}",
                self.run("squeue", &["-o", "%i %T %r"])
            );
            std::thread::sleep(Duration::from_millis(300));
        }
    }

    fn state_of(&self, job: &str) -> String {
        self.run("squeue", &["-h", "-j", job, "-o", "%T"])
            .trim()
            .to_string()
    }

    fn logs(&self) -> String {
        let mut all = String::new();
        for e in std::fs::read_dir(self.dir.path()).unwrap().flatten() {
            if e.path().extension().is_some_and(|x| x == "log") {
                all += &std::fs::read_to_string(e.path()).unwrap_or_default();
            }
        }
        all
    }
}

/// comparison.csv's rows by variant: status and the metric (no timings).
fn comparison(dir: &Path) -> BTreeMap<String, (String, String)> {
    let text = std::fs::read_to_string(dir.join("comparison.csv"))
        .unwrap_or_else(|e| panic!("{}/comparison.csv: {e}", dir.display()));
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let (v, s, m) = (col("variant"), col("status"), col("square.value"));
    lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (f[v].to_string(), (f[s].to_string(), f[m].to_string()))
        })
        .collect()
}

pub fn a_sweep_sharded_over_a_real_slurm_array_matches_one_process() {
    let cluster = match Cluster::start() {
        Ok(c) => c,
        Err(why) => {
            eprintln!("skipped: no Slurm cluster here: {why}");
            return;
        }
    };
    let work = cluster.dir.path();
    let (cache, out) = (work.join("cache"), work.join("out"));

    let single = work.join("single");
    let status = Command::new(bin())
        .args(["sweep"])
        .arg(repo("tests/data/slurm/sweep.toml"))
        .arg("--out")
        .arg(&single)
        .arg("--no-cache")
        .stderr(Stdio::null())
        .status()
        .unwrap();
    assert!(status.success());
    let expected = comparison(&single);
    assert!(expected.values().all(|(s, _)| s == "done"), "{expected:?}");

    // Two tasks of one CPU each (the node's size, whatever it is, fits them);
    // task 2 (shard 2: the second and fourth variants, the slow ones) is
    // cancelled while it runs.
    let job = cluster.submit("1-2", &[], &out, &cache);
    let task2 = format!("{job}_2");
    let start = Instant::now();
    while cluster.state_of(&task2) != "RUNNING" {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "task 2 never ran: {}",
            cluster.logs()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    std::thread::sleep(Duration::from_millis(1500));
    cluster.run("scancel", &[&task2]);
    cluster.wait_idle(Duration::from_secs(120));
    let partial = comparison(&out);
    assert_eq!(partial.len(), 4, "{partial:?}");
    for (variant, (status, _)) in &partial {
        let shard2 = variant.starts_with("02_") || variant.starts_with("04_");
        if shard2 {
            assert_eq!(status, "missing", "{variant}: cancelled, so missing");
        } else {
            assert_eq!(partial[variant], expected[variant], "{variant}");
        }
    }

    // Re-run only the cancelled shard into the same folder: the merge then
    // completes the comparison, equal to the one process's.
    cluster.submit("2", &[("FUSEGRAPH_SHARDS", "2")], &out, &cache);
    cluster.wait_idle(Duration::from_secs(180));
    assert_eq!(comparison(&out), expected, "{}", cluster.logs());
    // What task 2 finished before it was cancelled (the variant's quick
    // nodes) was reused, not computed again.
    let report: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(
            out.join(expected.keys().nth(1).unwrap())
                .join("report.json"),
        )
        .unwrap(),
    )
    .unwrap();
    assert_eq!(report["nodes"]["k"]["status"], "cached", "{report}");

    // Numbered from 0, into a new folder: the same comparison, all from the cache.
    let zero = work.join("zero");
    cluster.submit("0-1", &[], &zero, &cache);
    cluster.wait_idle(Duration::from_secs(120));
    assert_eq!(comparison(&zero), expected);

    // A non-contiguous array without the shard count is refused, saying how.
    let odd = work.join("odd");
    cluster.submit("1,3", &[], &odd, &cache);
    cluster.wait_idle(Duration::from_secs(60));
    assert!(
        cluster.logs().contains("is not contiguous"),
        "{}",
        cluster.logs()
    );
}
