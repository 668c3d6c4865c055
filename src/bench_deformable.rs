//! `fusegraph bench deformable`: the deformable fit (`register.deformable`'s
//! solver, its defaults) on a synthetic breast whose motion is known, so the
//! time comes with the field's error against the truth.

use fusegraph_nodes::register::synthetic_breast::{dome, interior, markers, sag, skin_area_above};
use fusegraph_nodes::register::{DeformParams, LandmarkPairs, fit_deformation};
use nalgebra::Point3;
use std::time::Instant;

/// What the camera sees of the skin: above this height, mm.
const SEEN_ABOVE_MM: f64 = 30.0;

/// Times `fit_deformation` (best of `repeat`) on a dome of about `points`
/// scanned skin points, seen from above with about as many, sagged by
/// `sag_mm` at the apex, 12 markers on both; prints the time, the solver's
/// work and the field's error at points inside against the sag.
pub fn run(points: usize, sag_mm: f64, repeat: usize) -> anyhow::Result<()> {
    anyhow::ensure!(
        sag_mm.is_finite() && (0.0..=30.0).contains(&sag_mm),
        "--sag-mm {sag_mm}: must be between 0 and 30"
    );
    let step = |area: f64| (area / points as f64).sqrt();
    let (scan, normals) = dome(step(skin_area_above(0.0)));
    let now: Vec<Point3<f64>> = dome(step(skin_area_above(SEEN_ABOVE_MM)))
        .0
        .into_iter()
        .filter(|p| p.z > SEEN_ABOVE_MM)
        .map(|p| p + sag(&p, sag_mm))
        .collect();
    let scan_markers = markers(&scan);
    let now_markers: Vec<Point3<f64>> = scan_markers.iter().map(|p| p + sag(p, sag_mm)).collect();
    let params = DeformParams::default();
    println!(
        "bench deformable: register.deformable's defaults ({} mm lattice, {} steps a stage); \
         a dome of {} scanned skin points, {} seen from above {SEEN_ABOVE_MM} mm sagged by \
         {sag_mm} mm at the apex, {} markers; best of {repeat}",
        params.spacing_mm,
        params.steps_per_stage,
        scan.len(),
        now.len(),
        scan_markers.len()
    );
    let mut best = f64::INFINITY;
    let mut fit = None;
    for _ in 0..repeat {
        let t = Instant::now();
        let landmarks = LandmarkPairs {
            scan: &scan_markers,
            now: &now_markers,
        };
        let d = fit_deformation(&scan, &normals, &now, Some(landmarks), None, &params)
            .map_err(|e| anyhow::anyhow!("the fit failed: {e}"))?;
        best = best.min(t.elapsed().as_secs_f64() * 1e3);
        fit = Some(d);
    }
    let d = fit.ok_or_else(|| anyhow::anyhow!("--repeat must be at least 1"))?;
    let errors: Vec<f64> = interior()
        .iter()
        .map(|p| (d.field.displacement(p) - sag(p, sag_mm)).norm())
        .collect();
    let mean = errors.iter().sum::<f64>() / errors.len() as f64;
    let worst = errors.iter().copied().fold(0.0, f64::max);
    println!(
        "  {best:.1} ms; lattice {:?} nodes, at most {} solver iterations a step; skin residual \
         {:.3} -> {:.3} mm; inside ({} points 15-40 mm deep) error mean {mean:.3} mm, worst \
         {worst:.3} mm",
        d.field.dims,
        d.solver_iterations,
        d.rigid_residual_mm,
        d.residual_mm,
        errors.len()
    );
    Ok(())
}
