//! `fusegraph bench`: measurements of the engine itself, in release builds.

use clap::Subcommand;
use fusegraph_engine::Registry;
use fusegraph_engine::cache::{DiskCache, MemoryCache};
use fusegraph_engine::schedule::RunOptions;
use fusegraph_engine::session::{load_graph, run};
use std::fmt::Write;
use std::time::Instant;

#[derive(Subcommand)]
pub enum BenchCommand {
    /// Scheduler overhead per node on a graph of trivial arithmetic nodes: cold
    /// (empty disk cache), fully cached, and without a disk cache.
    Scheduler {
        /// Number of nodes.
        #[arg(long, default_value_t = 1000)]
        nodes: usize,
        /// Worker threads (0 = one per core).
        #[arg(long, short = 'j', default_value_t = 0)]
        jobs: usize,
        /// Repetitions; the best time of each phase is reported.
        #[arg(long, default_value_t = 5)]
        repeat: usize,
    },
    /// Marching cubes throughput on an N^3 volume holding a wavy sphere, or on a
    /// DICOM series at its mean value (as ../shared/bench/peers.py mc does).
    MarchingCubes {
        /// Voxels along each axis.
        #[arg(long, default_value_t = 256)]
        size: usize,
        /// A DICOM series (folder) to contour instead.
        #[arg(long)]
        dicom: Option<std::path::PathBuf>,
        /// Repetitions; the best time is reported.
        #[arg(long, default_value_t = 3)]
        repeat: usize,
    },
}

/// A graph of `n` trivial nodes: 10 constants, then binary nodes each reading two
/// earlier nodes chosen by a fixed pseudo-random sequence (wide and deep).
pub fn trivial_graph(n: usize) -> String {
    let mut s = String::from("[graph]\nname = \"bench\"\n");
    let constants = n.min(10);
    for i in 0..constants {
        let _ = write!(s, "\n[node.n{i}]\nop = \"math.constant\"\nvalue = {i}.5\n");
    }
    let mut state: u64 = 0x9E37_79B9_7F4A_7C15;
    let mut pick = |below: usize| {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((state >> 33) as usize) % below
    };
    for i in constants..n {
        let (a, b) = (pick(i), pick(i));
        let op = ["add", "sub", "max", "min"][i % 4];
        let _ = write!(
            s,
            "\n[node.n{i}]\nop = \"math.binary\"\nin.a = \"n{a}.value\"\nin.b = \"n{b}.value\"\noperation = \"{op}\"\n"
        );
    }
    s
}

pub fn run_bench(what: BenchCommand, registry: &Registry) -> anyhow::Result<()> {
    match what {
        BenchCommand::Scheduler {
            nodes,
            jobs,
            repeat,
        } => scheduler(nodes, jobs, repeat, registry),
        BenchCommand::MarchingCubes {
            size,
            dicom,
            repeat,
        } => marching_cubes(size, dicom.as_deref(), repeat),
    }
}

fn marching_cubes(n: usize, dicom: Option<&std::path::Path>, repeat: usize) -> anyhow::Result<()> {
    use fusegraph_engine::value::Grid;
    let (values, grid, level) = match dicom {
        Some(dir) => {
            let s = fusegraph_nodes::dicom::load_series(dir, None)?;
            let mean = s.voxels.iter().map(|&v| v as f64).sum::<f64>() / s.voxels.len() as f64;
            (s.voxels, s.grid, mean as f32)
        }
        None => {
            let c = (n as f64 - 1.0) / 2.0;
            let values: Vec<f32> = (0..n * n * n)
                .map(|idx| {
                    let (i, j, k) = (
                        (idx % n) as f64 - c,
                        ((idx / n) % n) as f64 - c,
                        (idx / (n * n)) as f64 - c,
                    );
                    let r = (i * i + j * j + k * k).sqrt();
                    (0.4 * n as f64 + 0.03 * n as f64 * (0.2 * i).sin() * (0.2 * j).cos() - r)
                        as f32
                })
                .collect();
            (values, Grid::axis_aligned([n; 3], [0.5; 3], [0.0; 3]), 0.0)
        }
    };
    let mut best = f64::MAX;
    let mut triangles = 0;
    for _ in 0..repeat.max(1) {
        let t = Instant::now();
        let mesh = fusegraph_nodes::mri::marching_cubes(&values, &grid, level);
        best = best.min(t.elapsed().as_secs_f64());
        triangles = mesh.triangles.len();
    }
    println!(
        "marching cubes: {:?} voxels, level {level:.3}, {triangles} triangles, best of {repeat}: {:.1} ms, {:.1} Mvoxel/s",
        grid.dims,
        best * 1e3,
        values.len() as f64 / best / 1e6
    );
    Ok(())
}

fn scheduler(nodes: usize, jobs: usize, repeat: usize, registry: &Registry) -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let file = dir.path().join("bench.toml");
    std::fs::write(&file, trivial_graph(nodes))?;
    let (mut load, mut cold, mut cached, mut nocache) = (f64::MAX, f64::MAX, f64::MAX, f64::MAX);
    for r in 0..repeat.max(1) {
        let t = Instant::now();
        let graph = load_graph(&file, &[], registry)?;
        load = load.min(t.elapsed().as_secs_f64());
        let cache_dir = dir.path().join(format!("cache{r}"));
        let options = |cache: Option<DiskCache>| RunOptions {
            out_dir: dir.path().join("out"),
            cache,
            jobs,
            progress: false,
        };
        let t = Instant::now();
        let first = run(
            &graph,
            &options(Some(DiskCache::open(&cache_dir)?)),
            &MemoryCache::new(),
        )?;
        cold = cold.min(t.elapsed().as_secs_f64());
        let t = Instant::now();
        let second = run(
            &graph,
            &options(Some(DiskCache::open(&cache_dir)?)),
            &MemoryCache::new(),
        )?;
        cached = cached.min(t.elapsed().as_secs_f64());
        let t = Instant::now();
        run(&graph, &options(None), &MemoryCache::new())?;
        nocache = nocache.min(t.elapsed().as_secs_f64());
        anyhow::ensure!(
            first.report.succeeded() && second.report.succeeded(),
            "bench graph failed"
        );
        anyhow::ensure!(
            second
                .report
                .nodes
                .iter()
                .all(|(_, n)| n.status == fusegraph_engine::NodeStatus::Cached),
            "second run was not fully cached"
        );
    }
    let per_node = |s: f64| s * 1e6 / nodes as f64;
    println!("scheduler bench: {nodes} trivial nodes, jobs {jobs}, best of {repeat}");
    println!(
        "  load + validate      {:>8.1} ms  {:>6.1} us/node",
        load * 1e3,
        per_node(load)
    );
    println!(
        "  run, cold disk cache {:>8.1} ms  {:>6.1} us/node",
        cold * 1e3,
        per_node(cold)
    );
    println!(
        "  run, fully cached    {:>8.1} ms  {:>6.1} us/node",
        cached * 1e3,
        per_node(cached)
    );
    println!(
        "  run, no disk cache   {:>8.1} ms  {:>6.1} us/node",
        nocache * 1e3,
        per_node(nocache)
    );
    Ok(())
}
