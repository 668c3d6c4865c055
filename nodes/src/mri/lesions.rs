//! Lesions found in an MRI volume from the scan alone: blobs inside the
//! tissue whose intensity departs from the tissue around them.
//!
//! 1. The tissue: the foreground mask with its enclosed holes filled (a
//!    lesion darker than the threshold is a hole in it), and the exact
//!    distance of every tissue voxel to the outside (air, the table or chest
//!    wall, a marker's plastic).
//! 2. The tissue's noise: the robust spread (1.4826 MAD) of neighbouring
//!    voxels' differences over tissue at least 2 mm inside, divided by
//!    sqrt(2): blind to the slow bias field and to the few edges.
//! 3. Candidates: scale-normalised Laplacian-of-Gaussian blob detection
//!    (Lindeberg, IJCV 30(2), 1998): sigma^2 times the Laplacian of the
//!    volume smoothed by sigma, for sigmas spaced by 2^(1/3) from the
//!    smallest to the largest radius over sqrt(3) (a ball of radius r
//!    answers most at sigma = r / sqrt(3)); its local maxima over space and
//!    scale (the sign turned for bright lesions).
//! 4. Each candidate measured on the unsmoothed volume: the surrounding
//!    tissue's level (the median of the shell between 1.5 and 2.5 radii),
//!    the lesion voxels (those past half-way to the centre's level, joined
//!    to the centre; none may reach 2.5 radii out, or the blob is part of
//!    something larger), its contrast (surround minus the core's mean), volume
//!    and equivalent diameter, and its centre as the centroid weighted by
//!    each voxel's fraction of lesion ((surround - value) / contrast,
//!    clamped to 0..1, over the voxels and one voxel around them), which
//!    counts partial-volume rims at their share.
//! 5. Kept when the contrast is at least `min_contrast_sigma` noise SDs and
//!    stands out from noise with a z-score of at least [`MIN_Z`] (a volume
//!    holds millions of voxels to be fooled by), the diameter is in range,
//!    the lesion lies inside the tissue (its centre at least its radius
//!    plus `margin_mm` from the outside: rims, the chest wall and markers
//!    are not lesions) and no stronger lesion holds its centre.
//!
//! Written here: no Rust crate detects blobs in volumes.

use super::filters::{
    distance_to_outside_mm, fill_holes, gaussian_smooth, gaussian_smooth_owned, laplacian,
    laplacian_into,
};
use rayon::prelude::*;

/// A detection must stand out from the noise by this many standard errors:
/// its core's mean against the shell's, over millions of voxels and a dozen
/// scales, where 5 would let a few noise blobs through.
pub const MIN_Z: f64 = 6.0;

/// A blob response counts as a candidate when it is this many SDs of the
/// response to the tissue's noise (taken as white) above zero: noise's own
/// maxima rarely are, a lesion's (smoothed over its size) by far.
const CANDIDATE_SDS: f64 = 5.0;

/// At most this many candidates, strongest first, are measured (each costs a
/// look at the voxels within 2.5 radii).
const MAX_CANDIDATES: usize = 400;

/// Whether lesions are darker or brighter than the tissue.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Polarity {
    /// Darker than the tissue (e.g. a lesion on a T1-weighted scan without
    /// contrast agent).
    Darker,
    /// Brighter than the tissue (e.g. an enhancing lesion after gadolinium).
    Brighter,
}

/// How [`detect_lesions`] searches.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LesionParams {
    /// Darker or brighter than the tissue.
    pub polarity: Polarity,
    /// Smallest diameter kept, mm.
    pub min_diameter_mm: f64,
    /// Largest diameter kept, mm.
    pub max_diameter_mm: f64,
    /// Smallest contrast kept, in SDs of the tissue's noise (the
    /// contrast-to-noise ratio).
    pub min_contrast_sigma: f64,
    /// How far beyond its radius a lesion's centre must lie from the
    /// tissue's outside, mm.
    pub margin_mm: f64,
}

impl Default for LesionParams {
    fn default() -> Self {
        LesionParams {
            polarity: Polarity::Darker,
            min_diameter_mm: 2.0,
            max_diameter_mm: 20.0,
            min_contrast_sigma: 3.0,
            margin_mm: 1.0,
        }
    }
}

/// One lesion found.
#[derive(Debug, Clone, PartialEq)]
pub struct FoundLesion {
    /// Centre, continuous voxel index (i, j, k).
    pub centre_voxel: [f64; 3],
    /// Equivalent diameter (of a ball of the same volume), mm.
    pub diameter_mm: f64,
    /// Volume, partial-volume voxels at their share, mm^3.
    pub volume_mm3: f64,
    /// Surrounding tissue minus the lesion's core (darker; the other way
    /// for brighter), in the volume's units.
    pub contrast: f64,
    /// `contrast` in SDs of the tissue's noise.
    pub contrast_sigma: f64,
    /// The scale at which the blob answered most, mm.
    pub sigma_mm: f64,
}

/// What [`detect_lesions`] found and measured.
#[derive(Debug, Clone, PartialEq)]
pub struct LesionSearch {
    /// The lesions kept, strongest contrast first.
    pub lesions: Vec<FoundLesion>,
    /// The tissue's noise SD, in the volume's units.
    pub noise_sigma: f64,
    /// The tissue's median level.
    pub tissue_level: f64,
    /// Candidates measured (blob maxima inside the tissue).
    pub candidates: usize,
}

/// Finds lesions in `volume` (`dims`, `spacing_mm`, i fastest) inside the
/// foreground `mask` (same layout, non-zero = tissue or anything above the
/// tissue threshold).
pub fn detect_lesions(
    volume: &[f32],
    mask: &[u8],
    dims: [usize; 3],
    spacing_mm: [f64; 3],
    p: &LesionParams,
) -> Result<LesionSearch, String> {
    let n = dims.iter().product::<usize>();
    if volume.len() != n || mask.len() != n {
        return Err(format!(
            "volume ({}) and mask ({}) must both hold {n} voxels",
            volume.len(),
            mask.len()
        ));
    }
    if !(p.min_diameter_mm > 0.0 && p.max_diameter_mm >= p.min_diameter_mm) {
        return Err(format!(
            "diameters {} .. {} mm: the smallest must be above 0 and at most the largest",
            p.min_diameter_mm, p.max_diameter_mm
        ));
    }
    let tissue = fill_holes(mask, dims);
    let depth = distance_to_outside_mm(&tissue, dims, spacing_mm);
    let stride = sample_stride(n);
    let interior: Vec<f64> = (0..n)
        .step_by(stride)
        .filter(|&c| depth[c] >= 2.0)
        .map(|c| volume[c] as f64)
        .collect();
    if interior.len() < 100 {
        return Err(format!(
            "the mask holds {} voxels 2 mm inside its outline: too little tissue to search",
            interior.len() * stride
        ));
    }
    let tissue_level = median(interior);
    let noise_sigma = noise_sd(volume, &depth, dims, stride);
    if noise_sigma <= 0.0 {
        return Err("the tissue shows no noise: its contrast has no unit".into());
    }
    let sign = match p.polarity {
        Polarity::Darker => 1.0f32,
        Polarity::Brighter => -1.0,
    };

    // Scale-normalised LoG responses, each scale smoothed from the one
    // before (Gaussians compose: sigma^2 adds) with shorter kernels than
    // from the volume. Only three scales are held at once: a scale's maxima
    // are found once the next is known (a real scan's 50 M voxels times a
    // dozen scales would not fit).
    let sigmas = scales(p);
    let [nx, ny, nz] = dims;
    let mut smooth = volume.to_vec();
    let mut smoothed_to = 0.0f64;
    let mut window: std::collections::VecDeque<Vec<f32>> = std::collections::VecDeque::new();
    let mut candidates: Vec<(f32, usize, usize)> = Vec::new();
    for step in 0..=sigmas.len() {
        if let Some(&s) = sigmas.get(step) {
            smooth = gaussian_smooth_owned(
                smooth,
                dims,
                spacing_mm,
                (s * s - smoothed_to * smoothed_to).sqrt(),
            );
            smoothed_to = s;
            // The oldest scale is done with: its memory takes the new one.
            let mut l = if window.len() == 3 {
                window.pop_front().expect("three held")
            } else {
                vec![0.0; n]
            };
            laplacian_into(&smooth, &mut l, dims, spacing_mm);
            let norm = (s * s) as f32 * sign;
            l.par_iter_mut().for_each(|v| *v *= norm);
            window.push_back(l);
        } else if window.len() == 3 {
            // The last scale has no larger neighbour: only the one below.
            window.pop_front();
        }
        // The scale before this step, between its neighbours in `window`.
        let Some(si) = step.checked_sub(1) else {
            continue;
        };
        let own = if step == sigmas.len() {
            window.len() - 1
        } else {
            window.len() - 2
        };
        let scales_held: Vec<&[f32]> = window.iter().map(|v| &v[..]).collect();
        let r = scales_held[own];
        let radius = 3f64.sqrt() * sigmas[si];
        let floor = (CANDIDATE_SDS * noise_sigma * noise_gain(spacing_mm, sigmas[si])) as f32;
        let found: Vec<(f32, usize, usize)> = (1..nz.saturating_sub(1))
            .into_par_iter()
            .flat_map_iter(|k| {
                let mut out = Vec::new();
                for j in 1..ny.saturating_sub(1) {
                    for i in 1..nx.saturating_sub(1) {
                        let c = i + nx * (j + ny * k);
                        let v = r[c];
                        if v <= floor || (depth[c] as f64) < 0.5 * radius + p.margin_mm {
                            continue;
                        }
                        if is_maximum(&scales_held, own, c, [nx, ny]) {
                            out.push((v, si, c));
                        }
                    }
                }
                out
            })
            .collect();
        candidates.extend(found);
    }
    candidates.sort_by(|a, b| b.0.total_cmp(&a.0));
    candidates.truncate(MAX_CANDIDATES);

    let mut lesions: Vec<(FoundLesion, Vec<usize>)> = Vec::new();
    let measured = candidates.len();
    for &(_, si, c) in &candidates {
        if lesions
            .iter()
            .any(|(_, voxels)| voxels.binary_search(&c).is_ok())
        {
            continue;
        }
        let radius = 3f64.sqrt() * sigmas[si];
        let Some((lesion, voxels, excess)) =
            measure(volume, &tissue, dims, spacing_mm, c, radius, sign)
        else {
            continue;
        };
        let fits =
            lesion.diameter_mm >= p.min_diameter_mm && lesion.diameter_mm <= p.max_diameter_mm;
        let centre = voxel_of(lesion.centre_voxel, dims);
        let inside =
            centre.is_some_and(|ci| depth[ci] as f64 >= 0.5 * lesion.diameter_mm + p.margin_mm);
        let strong = lesion.contrast / noise_sigma >= p.min_contrast_sigma;
        // The lesion voxels' mean excess over the surround, in standard
        // errors of a mean of that many voxels.
        let significant = excess / (noise_sigma / (voxels.len() as f64).sqrt()) >= MIN_Z;
        let taken =
            centre.is_some_and(|ci| lesions.iter().any(|(_, v)| v.binary_search(&ci).is_ok()));
        if fits && inside && strong && significant && !taken {
            lesions.push((
                FoundLesion {
                    contrast_sigma: lesion.contrast / noise_sigma,
                    sigma_mm: sigmas[si],
                    ..lesion
                },
                voxels,
            ));
        }
    }
    let mut lesions: Vec<FoundLesion> = lesions.into_iter().map(|(l, _)| l).collect();
    lesions.sort_by(|a, b| b.contrast_sigma.total_cmp(&a.contrast_sigma));
    Ok(LesionSearch {
        lesions,
        noise_sigma,
        tissue_level,
        candidates: measured,
    })
}

/// The LoG scales searched, mm: radius / sqrt(3) from the smallest to the
/// largest radius, spaced by 2^(1/3) (the blob is measured on the volume
/// itself, so the scale need only find it).
fn scales(p: &LesionParams) -> Vec<f64> {
    let (lo, hi) = (
        0.5 * p.min_diameter_mm / 3f64.sqrt(),
        0.5 * p.max_diameter_mm / 3f64.sqrt(),
    );
    let step = 2f64.cbrt();
    let mut out = vec![lo];
    while *out.last().unwrap_or(&hi) * step < hi * step.sqrt() {
        out.push(out[out.len() - 1] * step);
    }
    out
}

/// Whether `scales[own][c]` is the largest of its 3 x 3 x 3 neighbours at
/// its own scale and at the scales held beside it (`scales` adjacent, at
/// most three).
fn is_maximum(scales: &[&[f32]], own: usize, c: usize, [nx, ny]: [usize; 2]) -> bool {
    let v = scales[own][c];
    for (n, r) in scales.iter().enumerate() {
        for dk in -1isize..=1 {
            for dj in -1isize..=1 {
                for di in -1isize..=1 {
                    let o = (c as isize + di + nx as isize * (dj + ny as isize * dk)) as usize;
                    if o == c && n == own {
                        continue;
                    }
                    let w = r[o];
                    if w > v || (w == v && o < c) {
                        return false;
                    }
                }
            }
        }
    }
    true
}

/// The SD of the scale-normalised LoG response (at `sigma_mm`) to white
/// noise of unit SD: the root sum of squares of the filter's impulse
/// response, found by filtering one unit voxel.
fn noise_gain(spacing_mm: [f64; 3], sigma_mm: f64) -> f64 {
    let dims: [usize; 3] =
        std::array::from_fn(|a| 2 * (3.0 * sigma_mm / spacing_mm[a]).ceil() as usize + 5);
    let mut impulse = vec![0.0f32; dims.iter().product()];
    let centre = dims[0] / 2 + dims[0] * (dims[1] / 2 + dims[1] * (dims[2] / 2));
    impulse[centre] = 1.0;
    let response = laplacian(
        &gaussian_smooth(&impulse, dims, spacing_mm, sigma_mm),
        dims,
        spacing_mm,
    );
    sigma_mm
        * sigma_mm
        * response
            .iter()
            .map(|v| (*v as f64).powi(2))
            .sum::<f64>()
            .sqrt()
}

/// The tissue's statistics are taken from every `sample_stride`-th voxel:
/// all of them up to 4 M voxels (the phantom's scans), a few million of a
/// real scan's tens of millions (a median needs no more, and a copy of
/// them all would take gigabytes). Odd, so it does not follow the rows.
fn sample_stride(voxels: usize) -> usize {
    (voxels / 4_000_000) | 1
}

/// The tissue's noise SD: 1.4826 MAD of neighbouring voxels' differences
/// along i (and j) over tissue at least 2 mm inside, over sqrt(2), from every
/// `stride`-th voxel.
fn noise_sd(volume: &[f32], depth: &[f32], dims: [usize; 3], stride: usize) -> f64 {
    let [nx, ny, _] = dims;
    let mut diffs: Vec<f64> = Vec::new();
    for c in (0..depth.len()).step_by(stride) {
        if depth[c] < 2.0 {
            continue;
        }
        let (i, j) = (c % nx, (c / nx) % ny);
        if i + 1 < nx && depth[c + 1] >= 2.0 {
            diffs.push((volume[c + 1] - volume[c]) as f64);
        }
        if j + 1 < ny && depth[c + nx] >= 2.0 {
            diffs.push((volume[c + nx] - volume[c]) as f64);
        }
    }
    if diffs.is_empty() {
        return 0.0;
    }
    let centre = median(diffs.clone());
    let mad = median(diffs.iter().map(|d| (d - centre).abs()).collect());
    1.4826 * mad / 2f64.sqrt()
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mid = v.len() / 2;
    v.select_nth_unstable_by(mid, f64::total_cmp);
    v[mid]
}

/// The voxel holding a continuous index, if inside the volume.
fn voxel_of(ijk: [f64; 3], dims: [usize; 3]) -> Option<usize> {
    let r: [isize; 3] = std::array::from_fn(|a| ijk[a].round() as isize);
    (0..3)
        .all(|a| r[a] >= 0 && (r[a] as usize) < dims[a])
        .then(|| r[0] as usize + dims[0] * (r[1] as usize + dims[1] * r[2] as usize))
}

/// The six face steps (axis, direction) of a voxel.
const FACE_STEPS: [(usize, isize); 6] = [(0, -1), (0, 1), (1, -1), (1, 1), (2, -1), (2, 1)];

/// The candidate at voxel `c` with LoG radius `radius_mm` measured on the
/// volume: its lesion (without `contrast_sigma` and `sigma_mm`) and its
/// voxels (sorted) and their mean excess over the surround, or `None` when
/// it has no contrast or no shell.
fn measure(
    volume: &[f32],
    tissue: &[u8],
    dims: [usize; 3],
    spacing: [f64; 3],
    c: usize,
    radius_mm: f64,
    sign: f32,
) -> Option<(FoundLesion, Vec<usize>, f64)> {
    let [nx, ny, _] = dims;
    let at = [c % nx, (c / nx) % ny, c / (nx * ny)];
    // Values as "how far toward the lesion's side": darker lesions make
    // smaller values larger.
    let value = |o: usize| -(sign * volume[o]) as f64;
    let reach = 2.5 * radius_mm;
    let span: [(usize, usize); 3] = std::array::from_fn(|a| {
        let h = (reach / spacing[a]).ceil() as usize;
        (at[a].saturating_sub(h), (at[a] + h).min(dims[a] - 1))
    });
    let dist_mm = |o: [usize; 3]| {
        (0..3)
            .map(|a| ((o[a] as f64 - at[a] as f64) * spacing[a]).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    let (mut shell, mut core) = (Vec::new(), Vec::new());
    for k in span[2].0..=span[2].1 {
        for j in span[1].0..=span[1].1 {
            for i in span[0].0..=span[0].1 {
                let o = i + nx * (j + ny * k);
                if tissue[o] == 0 {
                    continue;
                }
                let d = dist_mm([i, j, k]);
                if d >= 1.5 * radius_mm && d <= reach {
                    shell.push(value(o));
                } else if d <= 0.5 * radius_mm {
                    core.push(value(o));
                }
            }
        }
    }
    // Too little tissue around to tell a surround (the core holds at least
    // the centre voxel, unless that is not tissue).
    if shell.len() < 8 {
        return None;
    }
    let surround = median(shell);
    let core_level = core.iter().sum::<f64>() / core.len().max(1) as f64;
    // Darker lesions: values negated, so the core is above the surround.
    let contrast = core_level - surround;
    if core.is_empty() || contrast <= 0.0 {
        return None;
    }
    // Lesion voxels: past half-way from the surround to the core, joined to
    // the centre (6-connected), within the shell's reach.
    let half = surround + 0.5 * contrast;
    if value(c) < half {
        return None;
    }
    // The face neighbours of a voxel (i, j, k) within the box, with their
    // indices.
    let neighbours = |p: [isize; 3]| {
        FACE_STEPS.iter().filter_map(move |&(a, s)| {
            let mut q = p;
            q[a] += s;
            (0..3)
                .all(|b| q[b] >= span[b].0 as isize && q[b] <= span[b].1 as isize)
                .then(|| (q, q[0] as usize + nx * (q[1] as usize + ny * q[2] as usize)))
        })
    };
    let mut voxels = vec![c];
    let mut seen = std::collections::HashSet::from([c]);
    let mut stack = vec![at.map(|v| v as isize)];
    while let Some(p) = stack.pop() {
        for (q, o) in neighbours(p) {
            if tissue[o] != 0 && value(o) >= half && seen.insert(o) {
                if (0..3).any(|a| {
                    (q[a] == span[a].0 as isize && span[a].0 > 0)
                        || (q[a] == span[a].1 as isize && span[a].1 + 1 < dims[a])
                }) {
                    // It reaches past 2.5 radii: part of something larger
                    // than this scale's blob.
                    return None;
                }
                voxels.push(o);
                stack.push(q);
            }
        }
    }
    // Partial-volume weights over the voxels and one voxel around them.
    // Ordered, so the sums below do not depend on a hash's order.
    let mut rim: std::collections::BTreeSet<usize> = voxels.iter().copied().collect();
    for &o in &voxels {
        let p = [o % nx, (o / nx) % ny, o / (nx * ny)].map(|v| v as isize);
        rim.extend(neighbours(p).map(|(_, n)| n));
    }
    let voxel_mm3 = spacing.iter().product::<f64>();
    let (mut weight, mut sum) = (0.0, [0.0f64; 3]);
    for &o in &rim {
        let w = ((value(o) - surround) / contrast).clamp(0.0, 1.0);
        let p = [o % nx, (o / nx) % ny, o / (nx * ny)];
        weight += w;
        for a in 0..3 {
            sum[a] += w * p[a] as f64;
        }
    }
    if weight <= 0.0 {
        return None;
    }
    let volume_mm3 = weight * voxel_mm3;
    let excess = voxels.iter().map(|&o| value(o) - surround).sum::<f64>() / voxels.len() as f64;
    voxels.sort_unstable();
    Some((
        FoundLesion {
            centre_voxel: sum.map(|s| s / weight),
            diameter_mm: (6.0 * volume_mm3 / std::f64::consts::PI).cbrt(),
            volume_mm3,
            contrast,
            contrast_sigma: 0.0,
            sigma_mm: 0.0,
        },
        voxels,
        excess,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// A box of tissue (level 1.0, `noise` SD) in air, 1 mm voxels, with balls
    /// `(centre mm, diameter mm, signal)` drawn with their partial volume
    /// (5^3 samples per voxel).
    fn scan(
        dims: [usize; 3],
        balls: &[([f64; 3], f64, f32)],
        noise: f64,
        seed: u64,
    ) -> (Vec<f32>, Vec<u8>) {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let normal = Normal::new(0.0, noise).unwrap();
        let [nx, ny, nz] = dims;
        let mut volume = vec![0.0f32; nx * ny * nz];
        let mut mask = vec![0u8; nx * ny * nz];
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    let c = i + nx * (j + ny * k);
                    let tissue = (3..nx - 3).contains(&i)
                        && (3..ny - 3).contains(&j)
                        && (3..nz - 3).contains(&k);
                    if !tissue {
                        volume[c] = normal.sample(&mut rng).abs() as f32;
                        continue;
                    }
                    mask[c] = 1;
                    let mut v = 0.0f64;
                    for s in 0..125 {
                        let p = [
                            i as f64 + ((s % 5) as f64 - 2.0) / 5.0,
                            j as f64 + (((s / 5) % 5) as f64 - 2.0) / 5.0,
                            k as f64 + ((s / 25) as f64 - 2.0) / 5.0,
                        ];
                        let inside = balls.iter().find(|(c, d, _)| {
                            (0..3).map(|a| (p[a] - c[a]).powi(2)).sum::<f64>().sqrt() <= 0.5 * d
                        });
                        v += inside.map_or(1.0, |b| b.2 as f64);
                    }
                    volume[c] = (v / 125.0 + normal.sample(&mut rng)) as f32;
                }
            }
        }
        (volume, mask)
    }

    fn error_mm(found: &FoundLesion, truth: [f64; 3]) -> f64 {
        (0..3)
            .map(|a| (found.centre_voxel[a] - truth[a]).powi(2))
            .sum::<f64>()
            .sqrt()
    }

    #[test]
    fn dark_and_bright_balls_are_found_where_they_are_and_measured() {
        let dims = [48, 44, 40];
        let dark = ([15.3, 20.6, 18.2], 6.0, 0.8f32);
        let bright = ([32.7, 22.1, 21.5], 5.0, 1.25f32);
        let (volume, mask) = scan(dims, &[dark, bright], 0.02, 1);
        let spacing = [1.0; 3];
        let found =
            detect_lesions(&volume, &mask, dims, spacing, &LesionParams::default()).unwrap();
        assert_eq!(found.lesions.len(), 1, "{found:?}");
        let l = &found.lesions[0];
        assert!(error_mm(l, dark.0) < 0.15, "{l:?}");
        assert!((l.diameter_mm - 6.0).abs() < 0.3, "{l:?}");
        // Contrast 0.2 at noise 0.02: 10 SDs; the noise itself within 10 %.
        assert!(
            (found.noise_sigma - 0.02).abs() < 0.002,
            "{}",
            found.noise_sigma
        );
        assert!(
            (l.contrast - 0.2).abs() < 0.02 && (l.contrast_sigma - 10.0).abs() < 1.5,
            "{l:?}"
        );
        let brighter = LesionParams {
            polarity: Polarity::Brighter,
            ..LesionParams::default()
        };
        let found = detect_lesions(&volume, &mask, dims, spacing, &brighter).unwrap();
        assert_eq!(found.lesions.len(), 1, "{:?}", found.lesions);
        assert!(
            error_mm(&found.lesions[0], bright.0) < 0.15,
            "{:?}",
            found.lesions
        );
        assert!((found.lesions[0].diameter_mm - 5.0).abs() < 0.3);
    }

    #[test]
    fn noise_alone_rims_and_blobs_out_of_range_are_not_lesions() {
        let dims = [40, 40, 36];
        let spacing = [1.0; 3];
        let (volume, mask) = scan(dims, &[], 0.03, 2);
        let found =
            detect_lesions(&volume, &mask, dims, spacing, &LesionParams::default()).unwrap();
        assert!(found.lesions.is_empty(), "{:?}", found.lesions);
        // A dark ball cut by the tissue's edge (a notch in the skin) and one
        // larger than the range.
        let notch = ([3.5, 20.0, 18.0], 6.0, 0.0f32);
        let big = ([22.0, 20.0, 18.0], 14.0, 0.7f32);
        let (volume, mask) = scan(dims, &[notch, big], 0.02, 3);
        let small_range = LesionParams {
            max_diameter_mm: 10.0,
            ..LesionParams::default()
        };
        let found = detect_lesions(&volume, &mask, dims, spacing, &small_range).unwrap();
        assert!(found.lesions.is_empty(), "{:?}", found.lesions);
        // In range, the big one is found (and the notch still not).
        let found =
            detect_lesions(&volume, &mask, dims, spacing, &LesionParams::default()).unwrap();
        assert_eq!(found.lesions.len(), 1, "{:?}", found.lesions);
        assert!(
            error_mm(&found.lesions[0], big.0) < 0.2,
            "{:?}",
            found.lesions
        );
    }

    #[test]
    fn the_smallest_ball_found_shrinks_as_the_contrast_to_noise_ratio_grows() {
        // On 1 mm voxels, at CNR 5 and 10: the smallest of 2, 3, 4, 6 mm
        // balls found in every one of 3 noise draws, each within 0.3 mm (at
        // CNR 5 a 2 mm ball's partial volume leaves it under the default
        // 3 noise SDs of contrast).
        let dims = [36, 36, 36];
        let smallest = |cnr: f64| {
            [2.0, 3.0, 4.0, 6.0].into_iter().find(|&d| {
                (0..3).all(|seed| {
                    let ball = ([17.4, 18.3, 17.8], d, 0.8f32);
                    let (volume, mask) = scan(dims, &[ball], 0.2 / cnr, 10 + seed);
                    let found =
                        detect_lesions(&volume, &mask, dims, [1.0; 3], &LesionParams::default())
                            .unwrap();
                    found.lesions.len() == 1 && error_mm(&found.lesions[0], ball.0) <= 0.3
                })
            })
        };
        assert_eq!(smallest(10.0), Some(2.0));
        assert_eq!(smallest(5.0), Some(3.0));
    }

    #[test]
    fn every_voxel_is_sampled_up_to_4_m_and_an_odd_stride_beyond() {
        assert_eq!(sample_stride(3_400_000), 1);
        assert_eq!(sample_stride(4_000_000), 1);
        for n in [8_000_000, 52_000_000, 200_000_000] {
            let s = sample_stride(n);
            assert!(
                s % 2 == 1 && n / s <= 4_000_000 && n / s >= 2_000_000,
                "{n}: {s}"
            );
        }
    }

    #[test]
    fn mismatched_sizes_and_empty_tissue_are_errors() {
        let p = LesionParams::default();
        assert!(detect_lesions(&[0.0; 8], &[1; 7], [2, 2, 2], [1.0; 3], &p).is_err());
        let e = detect_lesions(&[0.0; 8], &[0; 8], [2, 2, 2], [1.0; 3], &p).unwrap_err();
        assert!(e.contains("too little tissue"), "{e}");
        let bad = LesionParams {
            min_diameter_mm: 8.0,
            max_diameter_mm: 4.0,
            ..p
        };
        assert!(detect_lesions(&[0.0; 8], &[1; 8], [2, 2, 2], [1.0; 3], &bad).is_err());
    }
}
