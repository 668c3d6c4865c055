//! Point clouds drawn over each other for the report: an orthographic side
//! view (the target's widest and thinnest principal axes), one panel per
//! state, target grey and source orange, so a registration's before and after
//! can be seen at a glance.

use nalgebra::{Matrix3, Point3, Vector3};

/// Panels (`panel_px` square each, side by side) of `target` with each
/// source cloud of `sources` over it, in the target's frame. 8-bit RGB and its
/// size; `None` when the target is empty.
pub fn overlay_panels(
    target: &[Point3<f64>],
    sources: &[&[Point3<f64>]],
    panel_px: usize,
) -> Option<(Vec<u8>, usize, usize)> {
    if target.is_empty() || sources.is_empty() {
        return None;
    }
    let n = target.len() as f64;
    let centre = target.iter().map(|p| p.coords).sum::<Vector3<f64>>() / n;
    let mut cov = Matrix3::zeros();
    for p in target {
        let d = p.coords - centre;
        cov += d * d.transpose();
    }
    let eig = cov.symmetric_eigen();
    let (wide, thin) = (eig.eigenvalues.argmax().0, eig.eigenvalues.argmin().0);
    let (u, mut v) = (
        eig.eigenvectors.column(wide).into_owned(),
        eig.eigenvectors.column(thin).into_owned(),
    );
    // Up is where the cloud reaches farthest from its centre (a dome's cap).
    let (lo, hi) = target.iter().fold((0.0f64, 0.0f64), |(lo, hi), p| {
        let b = (p.coords - centre).dot(&v);
        (lo.min(b), hi.max(b))
    });
    if -lo > hi {
        v = -v;
    }
    let project = |p: &Point3<f64>| {
        let d = p.coords - centre;
        (d.dot(&u), d.dot(&v))
    };
    let extent = target
        .iter()
        .map(|p| {
            let (a, b) = project(p);
            a.abs().max(b.abs())
        })
        .fold(0.0, f64::max)
        .max(1e-9)
        * 1.1;
    let (w, h) = (panel_px * sources.len(), panel_px);
    let mut rgb = vec![255u8; w * h * 3];
    let mut plot = |panel: usize, p: &Point3<f64>, colour: [u8; 3]| {
        let (a, b) = project(p);
        let x = ((a / extent + 1.0) * 0.5 * (panel_px - 1) as f64).round();
        let y = ((1.0 - (b / extent + 1.0) * 0.5) * (panel_px - 1) as f64).round();
        if (0.0..panel_px as f64).contains(&x) && (0.0..panel_px as f64).contains(&y) {
            let i = (y as usize * w + panel * panel_px + x as usize) * 3;
            rgb[i..i + 3].copy_from_slice(&colour);
        }
    };
    for (panel, source) in sources.iter().enumerate() {
        for p in target {
            plot(panel, p, [150, 150, 150]);
        }
        for p in source.iter() {
            plot(panel, p, [235, 120, 20]);
        }
    }
    // A dark line between panels.
    for panel in 1..sources.len() {
        for y in 0..h {
            let i = (y * w + panel * panel_px) * 3;
            rgb[i..i + 3].copy_from_slice(&[40, 40, 40]);
        }
    }
    Some((rgb, w, h))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn panels_show_both_clouds() {
        // A strip, thin along z: the side view shows x and z.
        let target: Vec<Point3<f64>> = (0..400)
            .map(|i| Point3::new(i as f64 * 0.25, (i % 7) as f64 * 3.0, (i % 3) as f64 * 0.3))
            .collect();
        let moved: Vec<Point3<f64>> = target
            .iter()
            .map(|p| p + Vector3::new(0.0, 0.0, 6.0))
            .collect();
        let (rgb, w, h) = overlay_panels(&target, &[&moved, &target], 100).unwrap();
        assert_eq!((w, h), (200, 100));
        let count = |c: [u8; 3]| rgb.chunks(3).filter(|p| *p == c).count();
        assert!(count([235, 120, 20]) > 50, "source drawn");
        assert!(
            count([150, 150, 150]) > 20,
            "target drawn where not covered"
        );
        assert!(overlay_panels(&[], &[&moved], 10).is_none());
    }
}

/// Slice `k` of a volume (`dims`, i fastest) in grey, scaled between its 1st
/// and 99th percentiles, with `mask` (same layout) tinted red over it: the
/// Otsu foreground on an MRI slice. 8-bit RGB, `dims[0] x dims[1]`.
pub fn mask_over_slice(volume: &[f32], mask: &[u8], dims: [usize; 3], k: usize) -> Vec<u8> {
    grey_slice(volume, Some(mask), dims, k)
}

/// Slice `k` in grey between its 1st and 99th percentiles, `mask` (if any)
/// tinted red: [`mask_over_slice`]'s drawing.
fn grey_slice(volume: &[f32], mask: Option<&[u8]>, dims: [usize; 3], k: usize) -> Vec<u8> {
    let (w, h) = (dims[0], dims[1]);
    let slice = &volume[k * w * h..(k + 1) * w * h];
    let mut sorted: Vec<f32> = slice.iter().copied().filter(|v| v.is_finite()).collect();
    sorted.sort_by(f32::total_cmp);
    let at = |q: f64| {
        sorted
            .get(((sorted.len().max(1) - 1) as f64 * q) as usize)
            .copied()
    };
    let (lo, hi) = (at(0.01).unwrap_or(0.0), at(0.99).unwrap_or(1.0));
    let span = (hi - lo).max(1e-6);
    let mut rgb = Vec::with_capacity(w * h * 3);
    for (i, &v) in slice.iter().enumerate() {
        let g = ((v - lo) / span).clamp(0.0, 1.0) * 255.0;
        if mask.is_some_and(|m| m[k * w * h + i] != 0) {
            rgb.extend([(0.5 * g + 127.0) as u8, (0.5 * g) as u8, (0.5 * g) as u8]);
        } else {
            rgb.extend([g as u8; 3]);
        }
    }
    rgb
}

/// Slices of a volume (`dims`, i fastest) side by side, each in grey
/// (scaled between its 1st and 99th percentiles) with a green circle:
/// `panels` holds each panel's slice `k`, the circle's centre (i, j) in
/// voxels and its radius in voxels along i (drawn round: the slice's
/// pixels are taken as square). 8-bit RGB and its size; `None` without
/// panels.
pub fn circles_over_slices(
    volume: &[f32],
    dims: [usize; 3],
    panels: &[(usize, [f64; 2], f64)],
) -> Option<(Vec<u8>, usize, usize)> {
    if panels.is_empty() {
        return None;
    }
    let (w, h) = (dims[0], dims[1]);
    let width = w * panels.len();
    let mut rgb = vec![0u8; width * h * 3];
    for (n, &(k, centre, radius)) in panels.iter().enumerate() {
        let slice = grey_slice(volume, None, dims, k.min(dims[2] - 1));
        for j in 0..h {
            for i in 0..w {
                let at = 3 * (n * w + i + width * j);
                rgb[at..at + 3].copy_from_slice(&slice[3 * (i + w * j)..3 * (i + w * j) + 3]);
                let r = ((i as f64 - centre[0]).powi(2) + (j as f64 - centre[1]).powi(2)).sqrt();
                if (r - radius.max(1.0)).abs() < 0.5 {
                    rgb[at..at + 3].copy_from_slice(&[40, 220, 60]);
                }
            }
        }
    }
    Some((rgb, width, h))
}

#[cfg(test)]
mod slice_tests {
    use super::*;

    #[test]
    fn masked_voxels_are_tinted_red() {
        let dims = [4, 3, 2];
        let volume: Vec<f32> = (0..24).map(|i| i as f32).collect();
        let mut mask = vec![0u8; 24];
        mask[12 + 5] = 1; // slice 1, voxel (1, 1)
        let rgb = mask_over_slice(&volume, &mask, dims, 1);
        assert_eq!(rgb.len(), 4 * 3 * 3);
        let px = |i: usize| [rgb[3 * i], rgb[3 * i + 1], rgb[3 * i + 2]];
        assert!(px(5)[0] > px(5)[1] + 100, "red tint {:?}", px(5));
        assert_eq!(px(4)[0], px(4)[1]);
    }
}
