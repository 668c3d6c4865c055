//! Points of a coloured cloud near a colour: the markers' faces (and, within
//! a radius, their walls), which a skin surface from another modality lacks.

use super::cloud::Nearest;
use crate::stereo::hsv;
use nalgebra::Point3;

/// A colour range in HSV.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HueRange {
    /// Hue range [min, max], deg; min > max wraps through 0.
    pub hue_deg: (f64, f64),
    /// Smallest saturation (0..1).
    pub min_saturation: f64,
    /// Smallest value (0..1).
    pub min_value: f64,
}

impl HueRange {
    /// Whether 8-bit `rgb` is in the range.
    pub fn contains(&self, rgb: [u8; 3]) -> bool {
        let [r, g, b] = rgb.map(|c| c as f64 / 255.0);
        let (h, s, v) = hsv(r, g, b);
        let (h0, h1) = self.hue_deg;
        let hue = if h0 <= h1 {
            (h0..=h1).contains(&h)
        } else {
            h >= h0 || h <= h1
        };
        hue && s >= self.min_saturation && v >= self.min_value
    }
}

/// Which points to keep: those farther than `radius_mm` from every point of
/// the colour `range` (those included).
pub fn away_from_colour(
    points: &[Point3<f64>],
    colors: &[[u8; 3]],
    range: &HueRange,
    radius_mm: f64,
) -> Vec<bool> {
    let coloured: Vec<Point3<f64>> = points
        .iter()
        .zip(colors)
        .filter(|(_, c)| range.contains(**c))
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
        let green = HueRange {
            hue_deg: (90.0, 170.0),
            min_saturation: 0.45,
            min_value: 0.12,
        };
        assert!(green.contains([25, 184, 51]));
        assert!(!green.contains([200, 160, 140]), "skin");
        assert!(!green.contains([128, 128, 128]), "grey wall");
        let points = [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(3.0, 0.0, 0.0),
            Point3::new(10.0, 0.0, 0.0),
        ];
        let colors = [[25, 184, 51], [128, 128, 128], [200, 160, 140]];
        assert_eq!(
            away_from_colour(&points, &colors, &green, 5.0),
            [false, false, true]
        );
        let skin = [[200, 160, 140]; 3];
        assert_eq!(away_from_colour(&points, &skin, &green, 5.0), [true; 3]);
    }
}
