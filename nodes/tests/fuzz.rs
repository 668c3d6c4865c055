//! Mutation fuzzing of the two loaders users feed by hand: graph files and
//! DICOM folders. Each mutated input must give `Ok` or a clear error, never a
//! panic, a hang or a blow-up of memory. Deterministic (a fixed seed per
//! round); the time per target is `FUSEGRAPH_FUZZ_SECONDS` (default 3 s, so
//! the suite stays fast; the closing notes give long runs).
//!
//! Written here rather than with cargo-fuzz: it needs a nightly toolchain,
//! and this one runs in the ordinary test suite.

use fusegraph_engine::graph::GraphDoc;
use fusegraph_engine::validate::validate;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// A small deterministic generator (xorshift64*).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

fn budget() -> Duration {
    let seconds = std::env::var("FUSEGRAPH_FUZZ_SECONDS")
        .ok()
        .and_then(|s| s.parse::<f64>().ok())
        .unwrap_or(3.0);
    Duration::from_secs_f64(seconds)
}

/// Peak resident memory of this process so far, MB (Linux).
fn peak_rss_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

const GRAPH_TOKENS: &[&str] = &[
    "[node.x]\n",
    "op = \"math.constant\"\n",
    "op = \"calib.find_chessboard\"\n",
    "in.a = \"x.value\"\n",
    "in.volume = \"nowhere.port\"\n",
    "value = 1e308\n",
    "value = nan\n",
    "pattern = [9, 6, 10]\n",
    "range_mm = [700, 400]\n",
    "[each.v]\nvalues = [1, 1]\n",
    "[each.v.node.y]\nop = \"math.constant\"\nvalue = {v}\n",
    "file = \"{v:099}\"\n",
    "[graph.references]\n\"a.b\" = 3\n",
    "\"",
    "[[",
    "= [",
    "]]\n",
    "\u{0}",
    "é",
];

fn mutate_text(rng: &mut Rng, text: &str) -> String {
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    for _ in 0..1 + rng.below(4) {
        let n = lines.len().max(1);
        match rng.below(6) {
            0 if !lines.is_empty() => {
                lines.remove(rng.below(n));
            }
            1 if !lines.is_empty() => {
                let l = lines[rng.below(n)].clone();
                lines.insert(rng.below(n), l);
            }
            2 if lines.len() > 1 => {
                let (a, b) = (rng.below(n), rng.below(n));
                lines.swap(a, b);
            }
            3 => {
                let t = GRAPH_TOKENS[rng.below(GRAPH_TOKENS.len())];
                lines.insert(rng.below(n), t.trim_end_matches('\n').to_string());
            }
            _ if !lines.is_empty() => {
                // A character of a line replaced by a printable one.
                let i = rng.below(n);
                let mut chars: Vec<char> = lines[i].chars().collect();
                if !chars.is_empty() {
                    let k = rng.below(chars.len());
                    chars[k] = (b' ' + rng.below(95) as u8) as char;
                }
                lines[i] = chars.into_iter().collect();
            }
            _ => {}
        }
    }
    lines.join("\n")
}

#[test]
fn mutated_graphs_give_errors_not_panics() {
    let registry = fusegraph_nodes::builtin_registry();
    let mut bases: Vec<(PathBuf, String)> = std::fs::read_dir(repo().join("graphs"))
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .map(|p| {
            let text = std::fs::read_to_string(&p).unwrap();
            (p, text)
        })
        .collect();
    bases.sort();
    let (start, budget) = (Instant::now(), budget());
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    let (mut inputs, mut valid) = (0usize, 0usize);
    while start.elapsed() < budget {
        let (file, base) = &bases[rng.below(bases.len())];
        let text = mutate_text(&mut rng, base);
        let outcome = catch_unwind(AssertUnwindSafe(|| {
            let mut doc = GraphDoc::parse(&text, file)?;
            // An override too, as `--set` gives them.
            let id = doc.nodes.first().map(|n| n.id.clone()).unwrap_or_default();
            let set = format!("{id}.{}", GRAPH_TOKENS[inputs % GRAPH_TOKENS.len()].trim());
            let _ = doc.apply_set(&set);
            validate(&doc, &registry).map(|_| ())
        }));
        match outcome {
            Ok(r) => valid += r.is_ok() as usize,
            Err(_) => panic!("the graph loader panicked on this input:\n{text}"),
        }
        inputs += 1;
    }
    eprintln!(
        "graph fuzz: {inputs} mutated graphs in {:.1} s, {valid} still valid, no panic",
        start.elapsed().as_secs_f64()
    );
    assert!(inputs > 100, "only {inputs} inputs in the budget");
}

fn mutate_bytes(rng: &mut Rng, bytes: &[u8]) -> Vec<u8> {
    let mut b = bytes.to_vec();
    for _ in 0..1 + rng.below(4) {
        if b.is_empty() {
            break;
        }
        // Mostly in the header, where lengths and tags live.
        let at = if rng.below(4) > 0 {
            rng.below(b.len().min(1500))
        } else {
            rng.below(b.len())
        };
        match rng.below(5) {
            0 => b[at] ^= 1 << rng.below(8),
            1 => b[at] = rng.next() as u8,
            2 => b.truncate(at.max(1)),
            3 if at + 4 <= b.len() => b[at..at + 4].copy_from_slice(&0xFFFF_FFF0u32.to_le_bytes()),
            _ => {
                let v = (rng.next() as u32).to_le_bytes();
                b.splice(at..at, v);
            }
        }
    }
    b
}

#[test]
fn mutated_dicom_files_give_errors_not_panics_or_huge_allocations() {
    let data = repo().join("tests/data/dicom");
    let mut bases: Vec<Vec<u8>> = std::fs::read_dir(&data)
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "dcm"))
        .map(|p| std::fs::read(p).unwrap())
        .collect();
    // And the slices of a small series, loaded as a folder with one mutated.
    let series = data.join("series_CT5N_98892001");
    let slices: Vec<PathBuf> = {
        let mut s: Vec<PathBuf> = std::fs::read_dir(&series)
            .unwrap()
            .filter_map(|e| e.ok().map(|e| e.path()))
            .collect();
        s.sort();
        s
    };
    bases.sort();
    let t = tempfile::tempdir().unwrap();
    let (start, budget) = (Instant::now(), budget());
    let mut rng = Rng(0xD1C0_5EED_0000_0001);
    let (mut inputs, mut loaded) = (0usize, 0usize);
    while start.elapsed() < budget {
        let dir = t.path().join(format!("case{}", inputs % 4));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        if rng.below(3) == 0 {
            // One slice of a real series mutated among the intact others.
            let k = rng.below(slices.len());
            for (i, s) in slices.iter().enumerate() {
                let bytes = std::fs::read(s).unwrap();
                let bytes = if i == k {
                    mutate_bytes(&mut rng, &bytes)
                } else {
                    bytes
                };
                std::fs::write(dir.join(format!("s{i}.dcm")), bytes).unwrap();
            }
        } else {
            let base = &bases[rng.below(bases.len())];
            std::fs::write(dir.join("f.dcm"), mutate_bytes(&mut rng, base)).unwrap();
        }
        let outcome = catch_unwind(AssertUnwindSafe(|| {
            fusegraph_nodes::dicom::load_series(&dir, None).map(|_| ())
        }));
        let keep = |why: &str| {
            let keep = std::env::temp_dir().join("fusegraph-fuzz-dicom");
            let _ = std::fs::remove_dir_all(&keep);
            let _ = std::fs::rename(&dir, &keep);
            panic!("the DICOM loader {why}; the input is in {}", keep.display());
        };
        match outcome {
            Ok(r) => loaded += r.is_ok() as usize,
            Err(_) => keep("panicked"),
        }
        if peak_rss_mb().is_some_and(|mb| mb > MAX_RSS_MB) {
            keep(&format!("took the process above {MAX_RSS_MB} MB"));
        }
        inputs += 1;
    }
    let peak = peak_rss_mb();
    eprintln!(
        "dicom fuzz: {inputs} mutated folders in {:.1} s, {loaded} still loaded, no panic; peak RSS {peak:?} MB",
        start.elapsed().as_secs_f64()
    );
    assert!(inputs > 50, "only {inputs} inputs in the budget");
}

/// The most memory a mutated small file may cost the process, MB.
const MAX_RSS_MB: f64 = 512.0;
