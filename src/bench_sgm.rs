//! `fusegraph bench sgm`: stereo.sgm's defaults timed (and measured against a
//! truth) on rectified pairs, which are written out so
//! `../shared/bench/peers.py sgbm` can run OpenCV on the very same images.

use fusegraph_engine::value::{Image, Pixels};
use fusegraph_nodes::calib::{rectify, remap};
use fusegraph_nodes::camera::isometry_from_matrix;
use fusegraph_nodes::eval::disparity_errors;
use fusegraph_nodes::io::{encode_pfm, load_image, read_disparity};
use fusegraph_nodes::phantom::{PhantomConfig, PhantomSize, ViewScene, generate, true_disparity};
use fusegraph_nodes::stereo::{DisparityRange, GreyImage, Paths, SgmConfig, sgm_disparity};
use std::path::Path;
use std::time::Instant;

/// One rectified pair to match.
pub struct SgmCase {
    /// What it is.
    pub name: String,
    /// Left rectified image.
    pub left: Image,
    /// Right rectified image.
    pub right: Image,
    /// Ground-truth disparity of the left image (NaN or 0 = unknown).
    pub truth: Option<Vec<f32>>,
    /// Disparities searched.
    pub min_disparity: i32,
    /// Number of disparities.
    pub disparities: usize,
}

impl SgmCase {
    /// A pair (and truth) from files.
    pub fn from_files(
        left: &Path,
        right: &Path,
        truth: Option<&Path>,
        truth_scale: f64,
        min_disparity: i32,
        disparities: usize,
    ) -> anyhow::Result<Self> {
        let truth = match truth {
            Some(t) => Some(
                read_disparity(t, truth_scale, true)
                    .map_err(anyhow::Error::msg)?
                    .data
                    .to_vec(),
            ),
            None => None,
        };
        Ok(SgmCase {
            name: left.display().to_string(),
            left: load_image(left)?,
            right: load_image(right)?,
            truth,
            min_disparity,
            disparities,
        })
    }

    /// The pair as the matchers take it, and its disparity range.
    pub fn grey_pair(&self) -> anyhow::Result<(GreyImage, GreyImage, DisparityRange)> {
        let (l, r) = (
            GreyImage::from_image(&self.left),
            GreyImage::from_image(&self.right),
        );
        let max = self.min_disparity + self.disparities as i32 - 1;
        let range =
            DisparityRange::new(self.min_disparity, max, l.width).map_err(anyhow::Error::msg)?;
        Ok((l, r, range))
    }
}

/// The phantom view 0 pair rectified with the true rig (128 disparities), and
/// the Middlebury pairs shipped in tests/data/stereo (64 disparities).
pub fn default_cases(scratch: &Path) -> anyhow::Result<Vec<SgmCase>> {
    let mut cases = vec![phantom_case(&scratch.join("phantom"))?];
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/stereo");
    for name in ["cones", "teddy"] {
        let dir = data.join(name);
        if !dir.is_dir() {
            println!("{}: not found, skipped", dir.display());
            continue;
        }
        let mut case = SgmCase::from_files(
            &dir.join("im2.png"),
            &dir.join("im6.png"),
            Some(&dir.join("disp2.pgm")),
            4.0,
            0,
            64,
        )?;
        case.name = name.into();
        cases.push(case);
    }
    Ok(cases)
}

fn phantom_case(dir: &Path) -> anyhow::Result<SgmCase> {
    let config = PhantomConfig {
        size: PhantomSize::Small,
        calibration_pairs: 3,
        views: 1,
        ..PhantomConfig::default()
    };
    let g = generate(&config, dir).map_err(anyhow::Error::msg)?;
    let rig = &g.truth.rig;
    let rect = rectify(
        &rig.left,
        &rig.right,
        &isometry_from_matrix(&rig.left_to_right),
        0.0,
    );
    let view = &g.truth.views[0];
    let mut images = Vec::new();
    for (file, camera, r, p) in [
        (&view.left, &rig.left, &rect.r1, &rect.p1),
        (&view.right, &rig.right, &rect.r2, &rect.p2),
    ] {
        let img = load_image(&dir.join(file))?;
        let Pixels::U8(src) = &img.pixels else {
            anyhow::bail!("{file}: not an 8-bit image");
        };
        let out = remap(src, 3, camera, r, p, rect.size);
        images.push(Image::new(
            rect.size.0,
            rect.size.1,
            3,
            Pixels::U8(out.into()),
        )?);
    }
    let scene = ViewScene::from_truth(&g.truth, 0).map_err(anyhow::Error::msg)?;
    let truth = true_disparity(&scene, &rig.left, &rig.right, &rect).map_err(anyhow::Error::msg)?;
    // 128 disparities from a little below the nearest-to-far truth.
    let lowest = truth
        .disparity_px
        .iter()
        .filter(|d| d.is_finite())
        .fold(f32::INFINITY, |a, &b| a.min(b));
    let right = images.pop().expect("two images");
    let left = images.pop().expect("two images");
    Ok(SgmCase {
        name: format!("phantom view 0 ({} x {})", rect.size.0, rect.size.1),
        left,
        right,
        truth: Some(truth.disparity_px),
        min_disparity: (lowest.floor() as i32 - 16).max(0),
        disparities: 128,
    })
}

/// Times every case and prints one line each, with the peer's command line.
pub fn run(
    cases: &[SgmCase],
    repeat: usize,
    paths: Option<i64>,
    folder: &Path,
) -> anyhow::Result<()> {
    let mut config = SgmConfig::default();
    if let Some(p) = paths {
        config.sgm.paths = Paths::from_count(p).map_err(anyhow::Error::msg)?;
    }
    println!(
        "bench sgm: stereo.sgm defaults (census 9 x 7, {} paths, P1 {}, P2 {}, refinement), best of {repeat}; pairs in {}",
        config.sgm.paths.count(),
        config.sgm.p1,
        config.sgm.p2,
        folder.display()
    );
    for (i, case) in cases.iter().enumerate() {
        let (l, r, range) = case.grey_pair()?;
        let mut best = f64::MAX;
        let mut disparity = Vec::new();
        for _ in 0..repeat.max(1) {
            let t = Instant::now();
            disparity = sgm_disparity(&l, &r, range, &config).map_err(anyhow::Error::msg)?;
            best = best.min(t.elapsed().as_secs_f64());
        }
        let mut line = format!(
            "  {}: {} x {}, {} disparities from {}: {:.1} ms",
            case.name,
            l.width,
            l.height,
            case.disparities,
            case.min_disparity,
            best * 1e3
        );
        let stem = folder.join(format!("pair{i}"));
        std::fs::create_dir_all(&stem)?;
        for (img, name) in [(&case.left, "left.png"), (&case.right, "right.png")] {
            let Pixels::U8(p) = &img.pixels else { continue };
            let colour = if img.channels == 3 {
                image::ExtendedColorType::Rgb8
            } else {
                image::ExtendedColorType::L8
            };
            image::save_buffer(
                stem.join(name),
                p,
                img.width as u32,
                img.height as u32,
                colour,
            )?;
        }
        let mut peer = format!(
            "peers.py sgbm {0}/left.png {0}/right.png --nd {1} --min-disp {2}",
            stem.display(),
            case.disparities,
            case.min_disparity
        );
        if let Some(truth) = &case.truth {
            let e = disparity_errors(&disparity, truth, None, &[1.0, 2.0])
                .map_err(anyhow::Error::msg)?;
            line += &format!(
                "; bad1.0 {:.2}%, bad2.0 {:.2}% (invalid counted bad), coverage {:.1}%, MAE {:.3} px",
                e.bad_pct[0], e.bad_pct[1], e.coverage_pct, e.mae_px
            );
            std::fs::write(stem.join("truth.pfm"), encode_pfm(l.width, l.height, truth))?;
            peer += &format!(" --gt {}/truth.pfm", stem.display());
        }
        println!("{line}\n    peer: {peer}");
    }
    Ok(())
}
