//! Points of a coloured cloud near a colour: the markers' faces (and, within
//! a radius, their walls), which a skin surface from another modality lacks.
//! The colour test is [`crate::stereo::colour_mask`], the one the marker
//! finder uses.

use super::Nearest;
use crate::stereo::{BlobParams, colour_mask};
use nalgebra::Point3;
use rayon::prelude::*;

/// Which points to keep: those farther than `radius_mm` from every point
/// whose colour (`rgb`, 3 bytes a point) passes `colour`'s HSV thresholds
/// (those included).
pub fn away_from_colour(
    points: &[Point3<f64>],
    rgb: &[u8],
    colour: &BlobParams,
    radius_mm: f64,
) -> Vec<bool> {
    let coloured: Vec<Point3<f64>> = points
        .iter()
        .zip(colour_mask(rgb, colour))
        .filter(|(_, c)| *c)
        .map(|(p, _)| *p)
        .collect();
    let Some(tree) = Nearest::new(&coloured) else {
        return vec![true; points.len()];
    };
    let r2 = radius_mm * radius_mm;
    // A search bounded by the radius: most of a skin lies far from every
    // marker, and its searches end at the tree's first cells.
    points
        .par_iter()
        .map(|p| {
            tree.nearest_two_within(p, radius_mm)
                .is_none_or(|((_, d2), _)| d2 > r2)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_near_green_go_and_the_rest_stay() {
        let green = BlobParams::default();
        let mask = colour_mask(&[25, 184, 51, 200, 160, 140, 128, 128, 128], &green);
        assert_eq!(mask, [true, false, false], "green, skin, grey wall");
        let points = [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(3.0, 0.0, 0.0),
            Point3::new(10.0, 0.0, 0.0),
        ];
        let rgb = [25, 184, 51, 128, 128, 128, 200, 160, 140];
        assert_eq!(
            away_from_colour(&points, &rgb, &green, 5.0),
            [false, false, true]
        );
        let skin = [200, 160, 140].repeat(3);
        assert_eq!(away_from_colour(&points, &skin, &green, 5.0), [true; 3]);
    }

    #[test]
    fn the_bounded_search_keeps_what_every_distance_says() {
        // A cloud with a few green points among many others; points kept are
        // exactly those farther than the radius from every green one.
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let mut next = || rng.random::<f64>();
        let points: Vec<Point3<f64>> = (0..3000)
            .map(|_| Point3::new(next() * 100.0, next() * 100.0, next() * 10.0))
            .collect();
        let rgb: Vec<u8> = (0..points.len())
            .flat_map(|i| {
                if i % 97 == 0 {
                    [25, 184, 51]
                } else {
                    [200, 160, 140]
                }
            })
            .collect();
        let green: Vec<&Point3<f64>> = points.iter().step_by(97).collect();
        let kept = away_from_colour(&points, &rgb, &BlobParams::default(), 6.0);
        for (p, keep) in points.iter().zip(&kept) {
            let far = green.iter().all(|g| (*g - p).norm_squared() > 36.0);
            assert_eq!(*keep, far, "{p:?}");
        }
        assert!(kept.iter().filter(|k| !**k).count() > green.len());
    }
}
