//! Correspondences between two marker sets without assuming order or equal
//! counts: every triplet of source markers is tried against every ordered
//! triplet of target markers whose pairwise distances agree (up to one common
//! scale when scale is allowed); each agreeing pair of triplets proposes a
//! similarity, and the proposal that maps the most markers one-to-one within the
//! tolerance (then the smallest error) wins.

use super::procrustes::{Similarity, umeyama};
use nalgebra::Point3;

/// Matched pairs (source index, target index) and the similarity fitted to them.
#[derive(Debug, Clone, PartialEq)]
pub struct MarkerMatch {
    /// Pairs of indices.
    pub pairs: Vec<(usize, usize)>,
    /// Source -> target similarity fitted to all pairs.
    pub transform: Similarity,
    /// RMS distance of the pairs after the fit, mm.
    pub rmse_mm: f64,
}

/// Greedy one-to-one assignment of mapped source points to target points within
/// `tolerance_mm`, closest first.
fn assign(
    t: &Similarity,
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    tolerance_mm: f64,
) -> Vec<(usize, usize, f64)> {
    let mut candidates: Vec<(f64, usize, usize)> = Vec::new();
    for (i, s) in source.iter().enumerate() {
        let m = t.apply(s);
        for (j, d) in target.iter().enumerate() {
            let e = (m - d).norm();
            if e <= tolerance_mm {
                candidates.push((e, i, j));
            }
        }
    }
    candidates.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (mut used_s, mut used_t) = (vec![false; source.len()], vec![false; target.len()]);
    let mut out = Vec::new();
    for (e, i, j) in candidates {
        if !used_s[i] && !used_t[j] {
            used_s[i] = true;
            used_t[j] = true;
            out.push((i, j, e));
        }
    }
    out
}

/// Finds the correspondences; `None` when fewer than 3 markers can be matched.
pub fn match_markers(
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    tolerance_mm: f64,
    with_scale: bool,
) -> Option<MarkerMatch> {
    let (n, m) = (source.len(), target.len());
    if n < 3 || m < 3 {
        return None;
    }
    let d = |p: &[Point3<f64>], a: usize, b: usize| (p[a] - p[b]).norm();
    let mut best: Option<(usize, f64, Similarity)> = None;
    for a in 0..n {
        for b in a + 1..n {
            for c in b + 1..n {
                let sd = [d(source, a, b), d(source, b, c), d(source, a, c)];
                // Small triangles pin the rotation poorly.
                if sd.iter().any(|&x| x < 3.0 * tolerance_mm) {
                    continue;
                }
                for x in 0..m {
                    for y in 0..m {
                        for z in 0..m {
                            if x == y || y == z || x == z {
                                continue;
                            }
                            let td = [d(target, x, y), d(target, y, z), d(target, x, z)];
                            let scale = if with_scale {
                                td.iter().sum::<f64>() / sd.iter().sum::<f64>()
                            } else {
                                1.0
                            };
                            if (0..3).any(|k| (td[k] - scale * sd[k]).abs() > 2.0 * tolerance_mm) {
                                continue;
                            }
                            let Some(t) = umeyama(
                                &[source[a], source[b], source[c]],
                                &[target[x], target[y], target[z]],
                                None,
                                with_scale,
                            ) else {
                                continue;
                            };
                            let pairs = assign(&t, source, target, tolerance_mm);
                            let error: f64 = pairs.iter().map(|p| p.2 * p.2).sum();
                            let better = best.as_ref().is_none_or(|(count, err, _)| {
                                pairs.len() > *count || (pairs.len() == *count && error < *err)
                            });
                            if better {
                                best = Some((pairs.len(), error, t));
                            }
                        }
                    }
                }
            }
        }
    }
    let (count, _, t) = best?;
    if count < 3 {
        return None;
    }
    // Refit on every pair, then reassign once with the better transform.
    let refit = |t: &Similarity| {
        let pairs = assign(t, source, target, tolerance_mm);
        let (s, d): (Vec<_>, Vec<_>) = pairs
            .iter()
            .map(|&(i, j, _)| (source[i], target[j]))
            .unzip();
        umeyama(&s, &d, None, with_scale).map(|t2| (pairs, t2))
    };
    let (_, t1) = refit(&t)?;
    let (pairs, t2) = refit(&t1)?;
    let (s, d): (Vec<_>, Vec<_>) = pairs
        .iter()
        .map(|&(i, j, _)| (source[i], target[j]))
        .unzip();
    Some(MarkerMatch {
        rmse_mm: t2.rmse(&s, &d),
        pairs: pairs.iter().map(|&(i, j, _)| (i, j)).collect(),
        transform: t2,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Vector3};

    #[test]
    fn finds_correspondences_with_missing_and_spurious_markers() {
        let source: Vec<Point3<f64>> = (0..12)
            .map(|i| {
                let a = i as f64 * 0.52 + (i * i) as f64 * 0.031;
                Point3::new(55.0 * a.cos(), 50.0 * a.sin(), 20.0 + 15.0 * (i % 3) as f64)
            })
            .collect();
        let truth = Similarity {
            rotation: Rotation3::from_euler_angles(2.5, 0.4, -1.9),
            translation: Vector3::new(-30.0, 80.0, 450.0),
            scale: 1.0,
        };
        // Target: markers 1..10 (0 and 11 missing) with noise, shuffled, plus one spurious.
        let mut target: Vec<(Option<usize>, Point3<f64>)> = (1..11)
            .map(|i| {
                (
                    Some(i),
                    truth.apply(&source[i])
                        + Vector3::new(0.3, -0.2, 0.25) * ((i % 2) as f64 - 0.5),
                )
            })
            .collect();
        target.push((None, Point3::new(0.0, 60.0, 470.0)));
        target.reverse();
        let pts: Vec<Point3<f64>> = target.iter().map(|t| t.1).collect();
        let m = match_markers(&source, &pts, 2.0, false).unwrap();
        assert_eq!(m.pairs.len(), 10);
        for (i, j) in &m.pairs {
            assert_eq!(
                target[*j].0,
                Some(*i),
                "source {i} matched to the wrong target"
            );
        }
        assert!(m.rmse_mm < 0.3);
        assert!(match_markers(&source[..2], &pts, 2.0, false).is_none());
    }
}
