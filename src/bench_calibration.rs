//! `fusegraph bench camera-calibration` and `stereo-calibration`: the solvers
//! of `calib.calibrate_camera` (one camera) and `calib.stereo_calibrate` (both
//! cameras alone, then Levenberg-Marquardt over both cameras, the rig and
//! every pose), timed best of N on the corners our detector finds in a folder
//! of chessboard photos. They write those corners as CSV so that
//! `bench/opencv_calibrate.py` times OpenCV's `calibrateCamera` (and
//! `stereoCalibrate`) on exactly the same corners; `--pairs` reads a pairs
//! file back (or one of other corners) instead of finding the boards.

use fusegraph_nodes::calib::{
    BoardView, Pairing, PhotoRecord, Side, board_corner_mm, calibrate_camera, calibrate_stereo,
    find_chessboard, numbered_photos, pair_views, usual_size,
};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

/// What the bench is given: the folder and the board.
pub struct Setup<'a> {
    /// Folder of the photos.
    pub dir: &'a Path,
    /// Inner corners per row and per column.
    pub pattern: (usize, usize),
    /// Side of a square, mm.
    pub square_mm: f64,
}

/// One camera's boards, found by `calib.find_chessboard`'s detector.
fn side(setup: &Setup, glob: &str) -> anyhow::Result<Side> {
    let pattern = glob::Pattern::new(glob)?;
    let photos = numbered_photos(setup.dir, &pattern).map_err(anyhow::Error::msg)?;
    anyhow::ensure!(
        !photos.files.is_empty(),
        "{}: no photo matches {glob:?}",
        setup.dir.display()
    );
    let (cols, rows) = setup.pattern;
    let mut boards = BTreeMap::new();
    let mut records = BTreeMap::new();
    for (&view, file) in &photos.files {
        let img = fusegraph_nodes::io::load_grey(file)?;
        let size = (img.width, img.height);
        let refusal = match find_chessboard(&img.levels, img.width, img.height, cols, rows) {
            Ok(image_px) => {
                let board_mm = (0..image_px.len())
                    .map(|k| board_corner_mm(k, cols, setup.square_mm))
                    .collect();
                boards.insert(view, (BoardView { board_mm, image_px }, size));
                PhotoRecord::FOUND
            }
            Err(why) => why.code(),
        };
        records.insert(view, PhotoRecord { refusal, size });
    }
    Ok(Side {
        boards,
        photos: Some(records),
    })
}

/// The header of one camera's views' CSV.
const VIEWS_HEADER: &str = "view,corner,board_x_mm,board_y_mm,x_px,y_px,width_px,height_px";

/// Finds one camera's boards in the photos `glob` names (not timed), keeps
/// those of the usual size as `calib.calibrate_camera` does, and times its
/// solver with the op's defaults (k1 k2 p1 p2 free); prints the results and
/// writes `views.csv` under `out` if given.
pub fn run_camera(
    setup: &Setup,
    glob: &str,
    repeat: usize,
    out: Option<&Path>,
) -> anyhow::Result<()> {
    let found = side(setup, glob)?.boards;
    let sizes = found.iter().map(|(v, b)| (*v, b.1)).collect();
    let ((width, height), odd) = usual_size(&sizes);
    let views: Vec<(u32, BoardView)> = found
        .into_iter()
        .filter(|(v, _)| !odd.contains(v))
        .map(|(v, b)| (v, b.0))
        .collect();
    let boards: Vec<BoardView> = views.iter().map(|v| v.1.clone()).collect();
    let free = [true, true, true, true, false];
    let mut best = f64::MAX;
    let mut last = None;
    for _ in 0..repeat.max(1) {
        let t = Instant::now();
        let c = calibrate_camera(&boards, width, height, free).map_err(anyhow::Error::msg)?;
        best = best.min(t.elapsed().as_secs_f64());
        last = Some(c);
    }
    let c = last.expect("ran at least once");
    let k = &c.camera;
    println!(
        "{} views of {width} x {height} px ({} of another size left out), k1 k2 p1 p2 free: rms {:.6} px; \
         fx {:.4} fy {:.4} cx {:.4} cy {:.4}; k1 {:.6} k2 {:.6}",
        boards.len(),
        odd.len(),
        c.rms_px,
        k.fx,
        k.fy,
        k.cx,
        k.cy,
        k.distortion[0],
        k.distortion[1]
    );
    let sd = c.intrinsics_sd();
    println!(
        "standard deviations: fx {:.4} fy {:.4} cx {:.4} cy {:.4} px; k1 {:.6} k2 {:.6} p1 {:.7} \
         p2 {:.7}",
        sd[0], sd[1], sd[2], sd[3], sd[4], sd[5], sd[6], sd[7]
    );
    println!(
        "camera calibration, best of {repeat}: {:.1} ms ({} iterations)",
        best * 1e3,
        c.iterations
    );
    if let Some(out) = out {
        let mut csv = format!("{VIEWS_HEADER}\n");
        for (view, b) in &views {
            for (k, (m, p)) in b.board_mm.iter().zip(&b.image_px).enumerate() {
                let _ = writeln!(
                    csv,
                    "{view},{k},{},{},{:.9},{:.9},{width},{height}",
                    m.x, m.y, p.x, p.y
                );
            }
        }
        write_csv(out, "views.csv", &csv)?;
    }
    Ok(())
}

/// Writes `csv` as `out/name` and says where.
fn write_csv(out: &Path, name: &str, csv: &str) -> anyhow::Result<()> {
    std::fs::create_dir_all(out)?;
    let path = out.join(name);
    std::fs::write(&path, csv).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    println!("{}: {}", name.trim_end_matches(".csv"), path.display());
    Ok(())
}

/// The header of the pairs' CSV.
const PAIRS_HEADER: &str = "view,corner,board_x_mm,board_y_mm,left_x_px,left_y_px,right_x_px,right_y_px,width_px,height_px";

/// Pairs read back from the CSV [`pairs_csv`] writes (or one made by hand:
/// rows of a view together, the same corners in the same order on both
/// sides).
pub fn read_pairs(path: &Path) -> anyhow::Result<Pairing> {
    let text =
        std::fs::read_to_string(path).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    let mut lines = text.lines().enumerate();
    let header = lines.next().map(|(_, l)| l.trim()).unwrap_or_default();
    anyhow::ensure!(
        header == PAIRS_HEADER,
        "{}: the first line must be {PAIRS_HEADER:?}",
        path.display()
    );
    let mut pairing = Pairing {
        views: Vec::new(),
        pairs: Vec::new(),
        sizes: [(0, 0); 2],
        dropped: Vec::new(),
    };
    for (number, line) in lines.filter(|(_, l)| !l.trim().is_empty()) {
        let at = || format!("{} line {}", path.display(), number + 1);
        let f: Vec<f64> = line
            .split(',')
            .map(|x| x.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|e| anyhow::anyhow!("{}: {e}", at()))?;
        anyhow::ensure!(
            f.len() == 10 && f.iter().all(|x| x.is_finite()),
            "{}: 10 finite numbers expected",
            at()
        );
        let view = f[0] as u32;
        let size = (f[8] as usize, f[9] as usize);
        if pairing.views.last() != Some(&view) {
            anyhow::ensure!(
                !pairing.views.contains(&view),
                "{}: view {view}'s rows are not together",
                at()
            );
            pairing.views.push(view);
            let empty = || BoardView {
                board_mm: Vec::new(),
                image_px: Vec::new(),
            };
            pairing.pairs.push((empty(), empty()));
            pairing.sizes = [size; 2];
        }
        anyhow::ensure!(pairing.sizes[0] == size, "{}: another image size", at());
        let (l, r) = pairing.pairs.last_mut().expect("pushed above");
        let board = nalgebra::Point2::new(f[2], f[3]);
        l.board_mm.push(board);
        r.board_mm.push(board);
        l.image_px.push(nalgebra::Point2::new(f[4], f[5]));
        r.image_px.push(nalgebra::Point2::new(f[6], f[7]));
    }
    anyhow::ensure!(
        pairing.pairs.len() >= 3,
        "{}: {} pairs; calibration needs at least 3",
        path.display(),
        pairing.pairs.len()
    );
    Ok(pairing)
}

/// The pairs as CSV: one row per corner of each pair.
fn pairs_csv(
    views: &[u32],
    pairs: &[(BoardView, BoardView)],
    sizes: [(usize, usize); 2],
) -> String {
    let mut csv = format!("{PAIRS_HEADER}\n");
    for (view, (l, r)) in views.iter().zip(pairs) {
        for k in 0..l.board_mm.len() {
            let _ = writeln!(
                csv,
                "{view},{k},{},{},{:.9},{:.9},{:.9},{:.9},{},{}",
                l.board_mm[k].x,
                l.board_mm[k].y,
                l.image_px[k].x,
                l.image_px[k].y,
                r.image_px[k].x,
                r.image_px[k].y,
                sizes[0].0,
                sizes[0].1
            );
        }
    }
    csv
}

/// Finds the boards in the left and the right photos `globs` name (not
/// timed) and pairs them by view number.
pub fn find_pairs(setup: &Setup, globs: [&str; 2]) -> anyhow::Result<Pairing> {
    let left = side(setup, globs[0])?;
    let right = side(setup, globs[1])?;
    pair_views(&left, &right, 3).map_err(anyhow::Error::msg)
}

/// Times the stereo calibration of `pairing` with `calib.stereo_calibrate`'s
/// defaults (k1 k2 p1 p2 free) and prints its results; writes `pairs.csv`
/// under `out` if given.
pub fn run(pairing: &Pairing, repeat: usize, out: Option<&Path>) -> anyhow::Result<()> {
    let free = [true, true, true, true, false];
    let mut best = f64::MAX;
    let mut last = None;
    for _ in 0..repeat.max(1) {
        let t = Instant::now();
        let s =
            calibrate_stereo(&pairing.pairs, pairing.sizes, free).map_err(anyhow::Error::msg)?;
        best = best.min(t.elapsed().as_secs_f64());
        last = Some(s);
    }
    let s = last.expect("ran at least once");
    let corners: usize = pairing.pairs.iter().map(|p| p.0.board_mm.len()).sum();
    println!(
        "{} pairs ({corners} corners per side), k1 k2 p1 p2 free: rms {:.6} px (left {:.6}, right {:.6}); \
         left fx {:.4} fy {:.4} cx {:.4} cy {:.4}; baseline {:.5} mm",
        pairing.pairs.len(),
        s.rms_px,
        s.rms_left_right_px[0],
        s.rms_left_right_px[1],
        s.left.fx,
        s.left.fy,
        s.left.cx,
        s.left.cy,
        s.left_to_right.translation.vector.norm()
    );
    for (side, name) in ["left", "right"].iter().enumerate() {
        let alone = s.mono[side].intrinsics_sd();
        let joint = s.intrinsics_sd(side);
        println!(
            "{name} camera's standard deviations, alone / jointly: fx {:.4} / {:.4}, fy {:.4} / \
             {:.4}, cx {:.4} / {:.4}, cy {:.4} / {:.4} px; k1 {:.6} / {:.6}",
            alone[0],
            joint[0],
            alone[1],
            joint[1],
            alone[2],
            joint[2],
            alone[3],
            joint[3],
            alone[4],
            joint[4]
        );
    }
    if let Some(rig) = s.rig_spread() {
        let (r, t) = (rig.rotation_sd_deg(), rig.translation_sd_mm());
        println!(
            "rig's standard deviations: rotation {:.5} {:.5} {:.5} deg, translation {:.4} {:.4} \
             {:.4} mm, baseline {:.4} mm",
            r[0], r[1], r[2], t[0], t[1], t[2], rig.baseline_sd_mm
        );
    }
    println!(
        "stereo calibration (both cameras alone, then together), best of {repeat}: {:.1} ms",
        best * 1e3
    );
    if let Some(out) = out {
        let csv = pairs_csv(&pairing.views, &pairing.pairs, pairing.sizes);
        write_csv(out, "pairs.csv", &csv)?;
    }
    Ok(())
}
