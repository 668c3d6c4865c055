//! `fusegraph bench chessboard`: chessboard detection on every image of a
//! folder, one thread, as `../shared/bench` times OpenCV's
//! `findChessboardCorners` + `cornerSubPix`: decoding included, best of N.
//! Prints each image's outcome (corners found, or why not) and writes the
//! corners as CSV (`file, corner, x_px, y_px`) for a side-by-side comparison.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// One image's outcome: the corners or the refusal, and the best times (ms).
struct Outcome {
    file: PathBuf,
    result: Result<Vec<nalgebra::Point2<f64>>, fusegraph_nodes::calib::Refusal>,
    decode_ms: f64,
    detect_ms: f64,
}

fn detect_one(file: &Path, cols: usize, rows: usize, repeat: usize) -> anyhow::Result<Outcome> {
    let (mut decode_ms, mut detect_ms) = (f64::MAX, f64::MAX);
    let mut result = Err(fusegraph_nodes::calib::Refusal::ImageTooSmall);
    for _ in 0..repeat.max(1) {
        let t = Instant::now();
        let img = fusegraph_nodes::io::load_grey(file)?;
        decode_ms = decode_ms.min(t.elapsed().as_secs_f64() * 1e3);
        let t = Instant::now();
        result =
            fusegraph_nodes::calib::find_chessboard(&img.levels, img.width, img.height, cols, rows);
        detect_ms = detect_ms.min(t.elapsed().as_secs_f64() * 1e3);
    }
    Ok(Outcome {
        file: file.to_path_buf(),
        result,
        decode_ms,
        detect_ms,
    })
}

/// Runs the detector on the files of `dir` matching `glob` and prints the
/// outcomes and times; writes `corners.csv` under `out` if given.
pub fn run(
    dir: &Path,
    glob: &str,
    (cols, rows): (usize, usize),
    repeat: usize,
    out: Option<&Path>,
) -> anyhow::Result<()> {
    let pattern = glob::Pattern::new(glob)?;
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| anyhow::anyhow!("{}: {e}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.file_name()
                .is_some_and(|n| pattern.matches(&n.to_string_lossy()))
        })
        .collect();
    files.sort();
    anyhow::ensure!(
        !files.is_empty(),
        "{}: no file matches {glob:?}",
        dir.display()
    );
    // One thread, as OpenCV's detector runs.
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    let outcomes: Vec<Outcome> = pool.install(|| {
        files
            .iter()
            .map(|f| detect_one(f, cols, rows, repeat))
            .collect::<anyhow::Result<_>>()
    })?;
    let mut csv = String::from("file,corner,x_px,y_px\n");
    let (mut found, mut total_ms) = (0, 0.0);
    for o in &outcomes {
        let name = o.file.file_name().unwrap_or_default().to_string_lossy();
        total_ms += o.decode_ms + o.detect_ms;
        match &o.result {
            Ok(corners) => {
                found += 1;
                println!(
                    "{name}: found, decode {:.1} ms, detect {:.1} ms",
                    o.decode_ms, o.detect_ms
                );
                for (k, c) in corners.iter().enumerate() {
                    let _ = writeln!(csv, "{name},{k},{:.6},{:.6}", c.x, c.y);
                }
            }
            Err(why) => println!(
                "{name}: refused ({why}), decode {:.1} ms, detect {:.1} ms",
                o.decode_ms, o.detect_ms
            ),
        }
    }
    println!(
        "chessboard bench: {found} of {} found; {:.1} ms per image on one thread, decoding included (best of {repeat})",
        outcomes.len(),
        total_ms / outcomes.len() as f64
    );
    if let Some(out) = out {
        std::fs::create_dir_all(out)?;
        let path = out.join("corners.csv");
        std::fs::write(&path, csv).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        println!("corners: {}", path.display());
    }
    Ok(())
}
