//! Points of a coloured cloud near a colour: the markers' faces (and, within
//! a radius, their walls), which a skin surface from another modality lacks.
//! The colour test is [`crate::stereo::colour_mask`], the one the marker
//! finder uses.

use super::Nearest;
use crate::stereo::{BlobParams, colour_mask};
use nalgebra::Point3;

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
    points.iter().map(|p| tree.nearest(p).1 > r2).collect()
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
}
