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
        #[arg(long, default_value_t = 1000, value_parser = count::<1_000_000>)]
        nodes: usize,
        /// Worker threads (0 = one per core).
        #[arg(long, short = 'j', default_value_t = 0)]
        jobs: usize,
        /// Repetitions; the best time of each phase is reported. No repeat starts
        /// after 30 s (a 100,000-node graph takes about 10 s a repeat).
        #[arg(long, default_value_t = 5, value_parser = count::<1000>)]
        repeat: usize,
    },
    /// ICP time per iteration, point-to-point, point-to-plane and GICP, on two
    /// clouds of a bumpy ellipsoid (target offset by 3 deg and 4 mm): over the
    /// later two thirds of the iterations (a run of a third as many taken from
    /// the whole, as peers.py times small_gicp) and over all of them (as it
    /// times Open3D); also writes the clouds as PLY for ../shared/bench/peers.py.
    Icp {
        /// Points per cloud (up to 5 million, about 2 GB with the k-d tree).
        #[arg(long, default_value_t = 100_000, value_parser = count::<5_000_000>)]
        points: usize,
        /// Iterations.
        #[arg(long, default_value_t = 30, value_parser = count::<10_000>)]
        iterations: usize,
        /// Folder for source.ply and target.ply [default: a temporary one].
        #[arg(long)]
        out: Option<std::path::PathBuf>,
    },
    /// Marching cubes throughput on an N^3 volume holding a wavy sphere, or on a
    /// DICOM series at its mean value (as ../shared/bench/peers.py mc does).
    MarchingCubes {
        /// Voxels along each axis (up to 800: 800^3 f32 voxels are 2 GB).
        #[arg(long, default_value_t = 256, value_parser = count::<800>)]
        size: usize,
        /// A DICOM series (folder) to contour instead.
        #[arg(long)]
        dicom: Option<std::path::PathBuf>,
        /// Repetitions; the best time is reported.
        #[arg(long, default_value_t = 3, value_parser = count::<1000>)]
        repeat: usize,
        /// Also time the node with this many Taubin smoothing iterations.
        #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u32).range(0..=1000))]
        smooth: u32,
    },
    /// The phantom generator under each acquisition condition (one at a
    /// time, then the lab and hard presets) against the ideal phantom: best
    /// wall time of each, its MRI, calibration and view stages, and ratios.
    Phantom {
        /// Resolution preset: full or small.
        #[arg(long, default_value = "full", value_parser = ["full", "small"])]
        size: String,
        /// Repetitions; the best time of each is reported.
        #[arg(long, default_value_t = 2, value_parser = count::<100>)]
        repeat: usize,
    },
    /// `mri.otsu` with its defaults (256 bins) on a DICOM series, as
    /// `../shared/bench/peers.py otsu DIR` times SimpleITK's
    /// OtsuThresholdImageFilter on the same series.
    Otsu {
        /// The series (folder).
        dicom: std::path::PathBuf,
        /// Repetitions; the best time is reported.
        #[arg(long, default_value_t = 5, value_parser = count::<1000>)]
        repeat: usize,
    },
    /// `mri.components` (26 neighbours) and `mri.select_markers` with their
    /// defaults on a mask (NIfTI, e.g. graphs/mri.toml's otsu_mask.nii.gz), as
    /// bench/sitk_components.py times SimpleITK's ConnectedComponent and
    /// LabelShapeStatistics on the same file.
    Components {
        /// The mask.
        mask: std::path::PathBuf,
        /// Repetitions; the best time of each is reported.
        #[arg(long, default_value_t = 5, value_parser = count::<1000>)]
        repeat: usize,
    },
    /// Semi-global matching with stereo.sgm's defaults on rectified pairs:
    /// time (best of --repeat) and, with a truth, bad-1 / bad-2 (invalid counted
    /// as bad), MAE and coverage. Without --left: a phantom view pair rectified
    /// with the true rig (800 x 600, 128 disparities) and the Middlebury pairs
    /// in tests/data/stereo (450 x 375, 64 disparities). Writes each pair (and
    /// truth as PFM) under --out for `../shared/bench/peers.py sgbm`.
    Sgm {
        /// Left rectified image.
        #[arg(long, requires = "right")]
        left: Option<std::path::PathBuf>,
        /// Right rectified image.
        #[arg(long)]
        right: Option<std::path::PathBuf>,
        /// Ground-truth disparity of the left image (PFM, PNG or PGM).
        #[arg(long)]
        truth: Option<std::path::PathBuf>,
        /// Divide the truth file's values by this (4 for Middlebury 2003).
        #[arg(long, default_value_t = 1.0)]
        truth_scale: f64,
        /// Smallest disparity, px.
        #[arg(long, default_value_t = 0)]
        min_disparity: i32,
        /// Number of disparities.
        #[arg(long, default_value_t = 64)]
        disparities: usize,
        /// Repetitions; the best time is reported.
        #[arg(long, default_value_t = 5, value_parser = count::<1000>)]
        repeat: usize,
        /// Folder for the pairs given to the peers [default: a temporary one].
        #[arg(long)]
        out: Option<std::path::PathBuf>,
        /// Aggregation paths (4, 5 or 8) instead of stereo.sgm's default.
        #[arg(long)]
        paths: Option<i64>,
    },
    /// `stereo.refine_slanted` with its defaults on the maps the main job
    /// gives it (stereo.sgm, then stereo.fill_disparity): time (best of
    /// --repeat), share refined, and bad-1 / bad-2 / MAE before and after,
    /// on the pairs `bench sgm` uses (a phantom view and the Middlebury
    /// pairs in tests/data/stereo).
    Refine {
        /// Repetitions; the best time is reported.
        #[arg(long, default_value_t = 3, value_parser = count::<1000>)]
        repeat: usize,
        /// Gauss-Newton iterations instead of the default.
        #[arg(long)]
        iterations: Option<usize>,
        /// Largest window side instead of the default, px.
        #[arg(long)]
        max_window_px: Option<usize>,
    },
    /// The deformable fit (register.deformable's solver with its defaults)
    /// on a synthetic breast: a dome's skin scanned, seen from above sagged
    /// by --sag-mm at the apex, 12 markers on both; time (best of
    /// --repeat), the solver's work and the field's error inside against
    /// the sag.
    Deformable {
        /// Scanned skin points (and about as many seen).
        #[arg(long, default_value_t = 20_000, value_parser = count::<2_000_000>)]
        points: usize,
        /// The sag at the apex, mm (0 to 30).
        #[arg(long, default_value_t = 8.0)]
        sag_mm: f64,
        /// Repetitions; the best time is reported.
        #[arg(long, default_value_t = 5, value_parser = count::<1000>)]
        repeat: usize,
    },
    /// Chessboard detection (calib.find_chessboard) on every image of a
    /// folder, on one thread, decoding included: each image's outcome and the
    /// time per image (best of --repeat); --out writes corners.csv.
    Chessboard {
        /// Folder of photos.
        dir: std::path::PathBuf,
        /// File names to use.
        #[arg(long, default_value = "*.jpg")]
        glob: String,
        /// Inner corners per row and per column, e.g. 9x6.
        #[arg(long, default_value = "9x6")]
        pattern: String,
        /// Repetitions; the best time is reported.
        #[arg(long, default_value_t = 3, value_parser = count::<1000>)]
        repeat: usize,
        /// Folder for corners.csv.
        #[arg(long)]
        out: Option<std::path::PathBuf>,
    },
    /// One camera's calibration (calib.calibrate_camera's solver with its
    /// defaults) on the boards found in its photos, e.g.
    /// ../shared/data/chessboard_mono; best of --repeat. --out writes
    /// views.csv for bench/opencv_calibrate.py.
    CameraCalibration {
        /// Folder of the photos.
        dir: std::path::PathBuf,
        /// File names of the photos.
        #[arg(long, default_value = "*.jpg")]
        glob: String,
        #[command(flatten)]
        board: BoardArgs,
        /// Repetitions; the best time is reported.
        #[arg(long, default_value_t = 5, value_parser = count::<1000>)]
        repeat: usize,
        /// Folder for views.csv.
        #[arg(long)]
        out: Option<std::path::PathBuf>,
    },
    /// Stereo calibration (calib.stereo_calibrate's solver with its defaults:
    /// both cameras alone, then together) on the boards found in a folder of
    /// chessboard pairs, e.g. `fusegraph phantom`'s calib folder; best of
    /// --repeat. --out writes pairs.csv for bench/opencv_calibrate.py;
    /// --pairs times a given corner set instead.
    StereoCalibration {
        /// Folder of the photos.
        #[arg(required_unless_present = "pairs", conflicts_with = "pairs")]
        dir: Option<std::path::PathBuf>,
        /// A corner set (the CSV --out writes) to calibrate instead of photos.
        #[arg(long)]
        pairs: Option<std::path::PathBuf>,
        /// File names of the left photos.
        #[arg(long, default_value = "left_*.png")]
        left: String,
        /// File names of the right photos.
        #[arg(long, default_value = "right_*.png")]
        right: String,
        #[command(flatten)]
        board: BoardArgs,
        /// Repetitions; the best time is reported.
        #[arg(long, default_value_t = 5, value_parser = count::<1000>)]
        repeat: usize,
        /// Folder for pairs.csv.
        #[arg(long)]
        out: Option<std::path::PathBuf>,
    },
}

/// The calibration board, as the calibration benches take it.
#[derive(clap::Args)]
pub struct BoardArgs {
    /// Inner corners per row and per column, e.g. 9x6.
    #[arg(long, default_value = "9x6")]
    pattern: String,
    /// Side of a square, mm.
    #[arg(long, default_value_t = 25.0)]
    square_mm: f64,
}

impl BoardArgs {
    /// The bench's setup for the photos in `dir`.
    fn setup<'a>(
        &self,
        dir: &'a std::path::Path,
    ) -> anyhow::Result<crate::bench_calibration::Setup<'a>> {
        let square_mm = self.square_mm;
        anyhow::ensure!(
            square_mm.is_finite() && square_mm > 0.0,
            "--square-mm {square_mm}: give a positive size"
        );
        Ok(crate::bench_calibration::Setup {
            dir,
            pattern: board_pattern(&self.pattern)?,
            square_mm,
        })
    }
}

/// A board pattern given as COLSxROWS (inner corners), e.g. 9x6.
fn board_pattern(pattern: &str) -> anyhow::Result<(usize, usize)> {
    pattern
        .to_lowercase()
        .split_once('x')
        .and_then(|(c, r)| Some((c.trim().parse().ok()?, r.trim().parse().ok()?)))
        .filter(|&(c, r): &(usize, usize)| c >= 2 && r >= 2)
        .ok_or_else(|| anyhow::anyhow!("--pattern {pattern:?}: give COLSxROWS, e.g. 9x6"))
}

/// A count from 1 to `MAX`: a value that sizes an allocation or a loop, kept
/// within what a run on this kind of machine can hold.
fn count<const MAX: usize>(s: &str) -> Result<usize, String> {
    let n: usize = s.trim().parse().map_err(|e| format!("{s:?}: {e}"))?;
    if (1..=MAX).contains(&n) {
        Ok(n)
    } else {
        Err(format!("{n} is not within 1 to {MAX}"))
    }
}

/// A graph of `n` trivial nodes: 10 constants, then binary nodes each reading
/// an earlier node chosen by a fixed pseudo-random sequence (wide and deep),
/// and either n0 (every other node: a hub) or another such node.
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
        // Every other node also reads n0: a hub feeding half the graph, the
        // shape that made validation quadratic once.
        let a = pick(i);
        let b = if i % 2 == 0 { 0 } else { pick(i) };
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
        BenchCommand::Icp {
            points,
            iterations,
            out,
        } => icp_bench(points, iterations, out.as_deref()),
        BenchCommand::MarchingCubes {
            size,
            dicom,
            repeat,
            smooth,
        } => marching_cubes(size, dicom.as_deref(), repeat, smooth, registry),
        BenchCommand::Components { mask, repeat } => components(&mask, repeat, registry),
        BenchCommand::Otsu { dicom, repeat } => otsu(&dicom, repeat, registry),
        BenchCommand::Phantom { size, repeat } => crate::bench_phantom::phantom(
            fusegraph_nodes::phantom::PhantomSize::parse(&size)
                .ok_or_else(|| anyhow::anyhow!("size is full or small"))?,
            repeat,
        ),
        BenchCommand::Sgm {
            left,
            right,
            truth,
            truth_scale,
            min_disparity,
            disparities,
            repeat,
            out,
            paths,
        } => {
            let dir = tempfile::tempdir()?;
            let folder = out.unwrap_or_else(|| dir.path().to_path_buf());
            std::fs::create_dir_all(&folder)?;
            let cases = match (left, right) {
                (Some(l), Some(r)) => vec![crate::bench_sgm::SgmCase::from_files(
                    &l,
                    &r,
                    truth.as_deref(),
                    truth_scale,
                    min_disparity,
                    disparities,
                )?],
                _ => crate::bench_sgm::default_cases(&folder)?,
            };
            crate::bench_sgm::run(&cases, repeat, paths, &folder)
        }
        BenchCommand::Refine {
            repeat,
            iterations,
            max_window_px,
        } => {
            let dir = tempfile::tempdir()?;
            let cases = crate::bench_sgm::default_cases(dir.path())?;
            let overrides = crate::bench_refine::Overrides {
                iterations,
                max_window_px,
            };
            crate::bench_refine::run(&cases, repeat, overrides)
        }
        BenchCommand::Deformable {
            points,
            sag_mm,
            repeat,
        } => crate::bench_deformable::run(points, sag_mm, repeat),
        BenchCommand::Chessboard {
            dir,
            glob,
            pattern,
            repeat,
            out,
        } => crate::bench_chessboard::run(
            &dir,
            &glob,
            board_pattern(&pattern)?,
            repeat,
            out.as_deref(),
        ),
        BenchCommand::CameraCalibration {
            dir,
            glob,
            board,
            repeat,
            out,
        } => {
            crate::bench_calibration::run_camera(&board.setup(&dir)?, &glob, repeat, out.as_deref())
        }
        BenchCommand::StereoCalibration {
            dir,
            pairs,
            left,
            right,
            board,
            repeat,
            out,
        } => {
            let pairing = match (pairs, dir) {
                (Some(file), _) => crate::bench_calibration::read_pairs(&file)?,
                (None, Some(dir)) => {
                    crate::bench_calibration::find_pairs(&board.setup(&dir)?, [&left, &right])?
                }
                (None, None) => anyhow::bail!("give a folder of photos or --pairs FILE"),
            };
            crate::bench_calibration::run(&pairing, repeat, out.as_deref())
        }
    }
}

fn icp_bench(n: usize, iterations: usize, out: Option<&std::path::Path>) -> anyhow::Result<()> {
    use anyhow::Context;
    use fusegraph_nodes::cloud::{Nearest, bumpy_ellipsoid, estimate_normals, plane_covariances};
    use fusegraph_nodes::register::{GICP_NEIGHBOURS, IcpMethod, IcpParams, Kernel, icp};
    use nalgebra::{Isometry3, Point3, Vector3};
    let target = bumpy_ellipsoid(n, 0.5);
    let offset = Isometry3::new(Vector3::new(4.0, -2.0, 1.0), Vector3::new(0.0, 0.03, 0.04));
    let source: Vec<Point3<f64>> = bumpy_ellipsoid(n, 0.25)
        .iter()
        .map(|p| offset * p)
        .collect();
    let t = Instant::now();
    let normals = estimate_normals(&target, 16, None);
    let normals_ms = t.elapsed().as_secs_f64() * 1e3;
    let t = Instant::now();
    let tree = Nearest::new(&target).ok_or_else(|| anyhow::anyhow!("empty"))?;
    let tree_ms = t.elapsed().as_secs_f64() * 1e3;
    let dir = tempfile::tempdir()?;
    let folder = out
        .map(std::path::Path::to_path_buf)
        .unwrap_or_else(|| dir.path().to_path_buf());
    std::fs::create_dir_all(&folder)?;
    let flat = |p: &[Point3<f64>]| -> Vec<f32> {
        p.iter()
            .flat_map(|q| [q.x as f32, q.y as f32, q.z as f32])
            .collect()
    };
    let nflat: Vec<f32> = normals
        .iter()
        .flat_map(|v| [v.x as f32, v.y as f32, v.z as f32])
        .collect();
    fusegraph_nodes::io::write_ply(
        &folder.join("source.ply"),
        &flat(&source),
        None,
        None,
        &[],
        "bench source",
    )?;
    fusegraph_nodes::io::write_ply(
        &folder.join("target.ply"),
        &flat(&target),
        Some(&nflat),
        None,
        &[],
        "bench target",
    )?;
    println!(
        "icp bench: {n} vs {n} points, {iterations} iterations; k-d tree {tree_ms:.1} ms, normals {normals_ms:.1} ms; clouds in {}",
        folder.display()
    );
    // GICP estimates both clouds' plane covariances inside each fit; they
    // are timed alone here and left out of its per-iteration figure, as
    // small_gicp's are (peers.py estimates them before timing).
    let t = Instant::now();
    let source_tree = Nearest::new(&source).context("empty source")?;
    let covariances = (
        plane_covariances(&source, &source_tree, GICP_NEIGHBOURS),
        plane_covariances(&target, &tree, GICP_NEIGHBOURS),
    );
    let covariances_ms = t.elapsed().as_secs_f64() * 1e3;
    drop(covariances);
    println!(
        "  GICP's plane covariances ({GICP_NEIGHBOURS} neighbours, both clouds): {covariances_ms:.1} ms"
    );
    for method in [
        IcpMethod::PointToPoint,
        IcpMethod::PointToPlane,
        IcpMethod::Gicp,
    ] {
        let run =
            |iterations: usize| -> anyhow::Result<(f64, fusegraph_nodes::register::IcpResult)> {
                let params = IcpParams {
                    method,
                    max_distance_mm: 10.0,
                    trim_ratio: 1.0,
                    kernel: Kernel::None,
                    max_iterations: iterations,
                    // Never stops early: a fixed number of iterations, timed as
                    // peers.py times small_gicp's.
                    tolerance: -1.0,
                    voxel_sizes_mm: vec![],
                };
                let t = Instant::now();
                let r = icp(
                    &source,
                    &target,
                    Some(&normals),
                    &tree,
                    &Isometry3::identity(),
                    &params,
                )
                .map_err(anyhow::Error::msg)?;
                Ok((t.elapsed().as_secs_f64() * 1e3, r))
            };
        let (run_ms, r) = run(iterations)?;
        // As peers.py times small_gicp: a run of a third as many
        // iterations, taken from this one, leaves the cost of the later
        // iterations alone (no set-up, none of the first steps, whose
        // points lie millimetres off the target and cost a k-d tree several
        // times more per search; GICP's covariances cancel too).
        let short = iterations / 3;
        let later = if short >= 1 && short < r.iterations {
            let (short_ms, short_run) = run(short)?;
            let extra = r.iterations - short_run.iterations;
            (extra > 0).then(|| {
                format!(
                    "{:.1} ms per iteration over iterations {}-{} (this run less one of {}, as peers.py times small_gicp); ",
                    (run_ms - short_ms) / extra as f64,
                    short_run.iterations + 1,
                    r.iterations,
                    short_run.iterations,
                )
            })
        } else {
            None
        };
        // The whole run's mean, GICP's covariances left out (timed above).
        let ms = if method == IcpMethod::Gicp {
            run_ms - covariances_ms
        } else {
            run_ms
        };
        println!(
            "  {method:?}: {}{:.1} ms per iteration over all {} (rmse {:.3} mm, fitness {:.3})",
            later.unwrap_or_default(),
            ms / r.iterations as f64,
            r.iterations,
            r.rmse_mm,
            r.fitness
        );
    }
    Ok(())
}

fn marching_cubes(
    n: usize,
    dicom: Option<&std::path::Path>,
    repeat: usize,
    smooth: u32,
    registry: &Registry,
) -> anyhow::Result<()> {
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
    // The whole `mri.isosurface` node: marching cubes, normals, area and
    // volume, and the engine value.
    let mut inputs = fusegraph_engine::Inputs::default();
    let volume = fusegraph_engine::value::Volume::new(grid.clone(), values.clone())?;
    inputs
        .0
        .insert("volume".into(), fusegraph_engine::Value::from(volume));
    inputs.0.insert(
        "level".into(),
        fusegraph_engine::Value::Scalar(std::sync::Arc::new(level as f64)),
    );
    let (node, _) = time_op(registry, "mri.isosurface", &inputs, repeat)?;
    println!(
        "mri.isosurface node (smooth_iterations 0, as in graphs/mri.toml), best of {repeat}: {:.1} ms, {:.2} x marching cubes alone",
        node * 1e3,
        node / best
    );
    if smooth > 0 {
        let set = [(
            "smooth_iterations",
            fusegraph_engine::ParamValue::Int(smooth as i64),
        )];
        let (node, _) = time_op_with(registry, "mri.isosurface", &inputs, &set, repeat)?;
        println!(
            "mri.isosurface node (smooth_iterations {smooth}), best of {repeat}: {:.1} ms, {:.2} x marching cubes alone",
            node * 1e3,
            node / best
        );
    }
    Ok(())
}

/// The best time of `op` (with its defaults) on `inputs` over `repeat` runs,
/// and its last outputs.
fn time_op(
    registry: &Registry,
    name: &str,
    inputs: &fusegraph_engine::Inputs,
    repeat: usize,
) -> anyhow::Result<(f64, fusegraph_engine::Outputs)> {
    time_op_with(registry, name, inputs, &[], repeat)
}

/// [`time_op`] with some parameters other than their defaults.
fn time_op_with(
    registry: &Registry,
    name: &str,
    inputs: &fusegraph_engine::Inputs,
    set: &[(&str, fusegraph_engine::ParamValue)],
    repeat: usize,
) -> anyhow::Result<(f64, fusegraph_engine::Outputs)> {
    let op = anyhow::Context::context(registry.get(name), format!("{name} is registered"))?;
    let mut params = fusegraph_engine::Params(
        op.spec()
            .params
            .iter()
            .filter_map(|p| Some((p.name.clone(), p.default.clone()?)))
            .collect(),
    );
    for (key, value) in set {
        params.0.insert((*key).to_string(), value.clone());
    }
    let mut best = f64::MAX;
    let mut last = None;
    for _ in 0..repeat.max(1) {
        let mut ctx = fusegraph_engine::RunCtx::new(name, std::path::Path::new("."));
        let t = Instant::now();
        let out = op.run(inputs, &params, &mut ctx)?;
        best = best.min(t.elapsed().as_secs_f64());
        last = Some(out);
    }
    Ok((best, last.expect("ran at least once")))
}

fn otsu(dicom: &std::path::Path, repeat: usize, registry: &Registry) -> anyhow::Result<()> {
    use fusegraph_engine::Value;
    let s = fusegraph_nodes::dicom::load_series(dicom, None)?;
    let dims = s.grid.dims;
    let volume = fusegraph_engine::value::Volume::new(s.grid, s.voxels)?;
    let mut inputs = fusegraph_engine::Inputs::default();
    inputs.0.insert("volume".into(), Value::from(volume));
    let (t, out) = time_op(registry, "mri.otsu", &inputs, repeat)?;
    let threshold = match out.0.get("threshold") {
        Some(Value::Scalar(v)) => **v,
        _ => f64::NAN,
    };
    println!(
        "{dims:?} voxels, best of {repeat}: mri.otsu {:.1} ms, threshold {threshold:.4}",
        t * 1e3
    );
    Ok(())
}

fn components(mask: &std::path::Path, repeat: usize, registry: &Registry) -> anyhow::Result<()> {
    use fusegraph_engine::Value;
    use fusegraph_nodes::io::{VoxelBuf, read_nifti};
    let nifti = read_nifti(mask).map_err(anyhow::Error::msg)?;
    let data: Vec<u8> = match nifti.voxels {
        VoxelBuf::U8(v) => v,
        VoxelBuf::F32(v) => v.iter().map(|&x| u8::from(x > 0.5)).collect(),
    };
    let grid = nifti.grid;
    let mut inputs = fusegraph_engine::Inputs::default();
    let m = fusegraph_engine::value::Mask::new(grid.clone(), data)?;
    inputs.0.insert("mask".into(), Value::from(m));
    let (cc, out) = time_op(registry, "mri.components", &inputs, repeat)?;
    let mut inputs = fusegraph_engine::Inputs::default();
    inputs.0.insert("labels".into(), out.0["labels"].clone());
    let (select, _) = time_op(registry, "mri.select_markers", &inputs, repeat)?;
    println!(
        "{:?} voxels, best of {repeat}: mri.components (26) {:.1} ms, mri.select_markers {:.1} ms",
        grid.dims,
        cc * 1e3,
        select * 1e3
    );
    Ok(())
}

/// Wall time after which the scheduler bench starts no further repeat.
const SCHEDULER_BENCH_BUDGET: std::time::Duration = std::time::Duration::from_secs(30);

fn scheduler(nodes: usize, jobs: usize, repeat: usize, registry: &Registry) -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let file = dir.path().join("bench.toml");
    std::fs::write(&file, trivial_graph(nodes))?;
    let (mut load, mut cold, mut cached, mut nocache) = (f64::MAX, f64::MAX, f64::MAX, f64::MAX);
    let started = Instant::now();
    let mut done = 0;
    for r in 0..repeat.max(1) {
        // A large graph's repeats add up to minutes: stop at the budget (the
        // best of fewer repeats is still a fair figure) and say so below.
        if r > 0 && started.elapsed() > SCHEDULER_BENCH_BUDGET {
            break;
        }
        let t = Instant::now();
        let graph = load_graph(&file, &[], registry)?;
        load = load.min(t.elapsed().as_secs_f64());
        let cache_dir = dir.path().join(format!("cache{r}"));
        let options = |cache: Option<DiskCache>| RunOptions {
            out_dir: dir.path().join("out"),
            cache,
            jobs,
            progress: false,
            provenance: Default::default(),
            keep_outputs: false,
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
        // Each repeat's cache holds one file per node: remove it before the
        // next, so the disk holds one graph's entries, not `repeat` of them.
        std::fs::remove_dir_all(&cache_dir)?;
        done += 1;
    }
    let per_node = |s: f64| s * 1e6 / nodes as f64;
    let cut = if done < repeat {
        format!(
            " (of {repeat} asked: stopped after {} s)",
            SCHEDULER_BENCH_BUDGET.as_secs()
        )
    } else {
        String::new()
    };
    println!("scheduler bench: {nodes} trivial nodes, jobs {jobs}, best of {done}{cut}");
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
