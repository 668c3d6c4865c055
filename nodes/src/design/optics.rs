//! Thin-lens design formulas. All lengths in mm.

/// Focal length giving a field of view `fov_mm` at distance `distance_mm` on a
/// sensor `sensor_mm` wide: f = s * D / FOV.
pub fn focal_length_mm(sensor_mm: f64, distance_mm: f64, fov_mm: f64) -> f64 {
    sensor_mm * distance_mm / fov_mm
}

/// The lens in `lenses_mm` closest to `focal_mm` (ties go to the longer lens,
/// which keeps the field at least as narrow as asked).
pub fn nearest_lens_mm(focal_mm: f64, lenses_mm: &[f64]) -> Option<f64> {
    lenses_mm.iter().copied().min_by(|a, b| {
        (a - focal_mm)
            .abs()
            .total_cmp(&(b - focal_mm).abs())
            .then(b.total_cmp(a))
    })
}

/// Blur circle diameter on the sensor of a point at `object_mm` when a lens of
/// focal length `focal_mm` and aperture diameter `aperture_mm` is focused at
/// `focus_mm`: c = A f |D1 - D2| / ((D1 - f) D2).
pub fn blur_circle_mm(aperture_mm: f64, focal_mm: f64, focus_mm: f64, object_mm: f64) -> f64 {
    aperture_mm * focal_mm * (focus_mm - object_mm).abs() / ((focus_mm - focal_mm) * object_mm)
}

/// The focus distance that makes the blur equal at both ends of [near, far]
/// (and so smallest at its worst): solving c(near) = c(far) gives the harmonic
/// mean 2 near far / (near + far), whatever the lens.
pub fn focus_for_range_mm(near_mm: f64, far_mm: f64) -> f64 {
    2.0 * near_mm * far_mm / (near_mm + far_mm)
}

/// The smallest f-number (largest aperture) keeping the blur at most
/// `circle_mm` over [near, far] when focused at `focus_mm`.
pub fn min_f_number(
    focal_mm: f64,
    focus_mm: f64,
    near_mm: f64,
    far_mm: f64,
    circle_mm: f64,
) -> f64 {
    // c = (f / N) f |D1 - D2| / ((D1 - f) D2) <= circle at both ends.
    let worst = [near_mm, far_mm]
        .iter()
        .map(|&d| focal_mm * (focus_mm - d).abs() / ((focus_mm - focal_mm) * d))
        .fold(0.0, f64::max);
    focal_mm * worst / circle_mm
}

/// Verging angle of a rig of baseline `baseline_mm` whose optical axes cross at
/// `distance_mm`: theta = atan(b / D), in degrees.
pub fn verging_angle_deg(baseline_mm: f64, distance_mm: f64) -> f64 {
    (baseline_mm / distance_mm).atan().to_degrees()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_papers_lens() {
        let f = focal_length_mm(4.8, 400.0, 250.0);
        assert!((f - 7.68).abs() < 1e-12);
        let lens = nearest_lens_mm(f, &[4.0, 6.0, 8.0, 12.0, 16.0, 25.0, 35.0, 50.0]).unwrap();
        assert_eq!(lens, 8.0);
        // The 8 mm lens's real field at 400 mm: 4.8 * 400 / 8 = 240 mm.
        assert!((4.8 * 400.0 / lens - 240.0).abs() < 1e-12);
        assert_eq!(
            nearest_lens_mm(7.0, &[6.0, 8.0]),
            Some(8.0),
            "tie goes to the longer lens"
        );
    }

    #[test]
    fn the_papers_verging_angle() {
        assert!((verging_angle_deg(55.0, 400.0) - 7.8291).abs() < 1e-4);
    }

    #[test]
    fn blur_circle_by_hand() {
        // f = 8 mm, N = 8 -> A = 1 mm, focused at 500 mm.
        // D2 = 400: 1 * 8 * 100 / (492 * 400) = 0.0040650 mm
        // D2 = 500: 0
        // D2 = 700: 1 * 8 * 200 / (492 * 700) = 0.0046458 mm
        let c = |d| blur_circle_mm(1.0, 8.0, 500.0, d);
        assert!((c(400.0) - 800.0 / 196_800.0).abs() < 1e-12);
        assert_eq!(c(500.0), 0.0);
        assert!((c(700.0) - 1600.0 / 344_400.0).abs() < 1e-12);
    }

    #[test]
    fn focus_balances_the_range() {
        let d1 = focus_for_range_mm(400.0, 700.0);
        assert!((d1 - 509.0909).abs() < 1e-4);
        let (near, far) = (
            blur_circle_mm(1.0, 8.0, d1, 400.0),
            blur_circle_mm(1.0, 8.0, d1, 700.0),
        );
        assert!((near - far).abs() < 1e-12);
        // The f-number that makes that worst blur exactly one 6 um pixel.
        let n = min_f_number(8.0, d1, 400.0, 700.0, 0.006);
        assert!((blur_circle_mm(8.0 / n, 8.0, d1, 400.0) - 0.006).abs() < 1e-12);
    }
}
