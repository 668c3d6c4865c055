//! What the tissue stands on: a breast's root on the chest wall, a
//! phantom's base on its table. The scan holds the tissue's flat base; the
//! cameras see the plane it rests on now (the table around it). A field
//! fitted to the skin alone must guess how the inside moved from how the
//! skin did, and it carries the skin's motion down to the base; the base
//! resting on the plane seen now says what the inside does at the bottom,
//! and the field interpolates between the two instead of extrapolating.

use crate::cloud::{Plane, dominant_plane};
use nalgebra::{Point3, Vector3};

/// Scan points this close to the scan's flat base belong to it, mm (the
/// isosurface's own error is a fraction of a voxel).
pub const BASE_THRESHOLD_MM: f64 = 1.0;

/// A flat base holds at least this share of the scan's skin points (a
/// phantom's base disc holds about a third; a skin without one, a few per
/// cent on its flattest patch).
pub const MIN_BASE_SHARE: f64 = 0.1;

/// The base and the plane seen now must be this close in angle, deg (after
/// the rigid registration).
pub const MAX_BASE_TILT_DEG: f64 = 20.0;

/// The support for [`super::fit_deformation`]: the scan's points on its
/// base, and the plane they rest on now (same frame as the scan, mm).
#[derive(Debug, Clone)]
pub struct Support {
    /// The scan's points on its flat base.
    pub base: Vec<Point3<f64>>,
    /// The plane seen now, its normal towards the tissue.
    pub plane: Plane,
}

impl Support {
    /// RMS distance of the base moved by `displacement` from the plane, mm.
    pub fn residual_mm(&self, displacement: impl Fn(&Point3<f64>) -> Vector3<f64>) -> f64 {
        let sum: f64 = self
            .base
            .iter()
            .map(|b| self.plane.distance(&(b + displacement(b))).powi(2))
            .sum();
        (sum / self.base.len().max(1) as f64).sqrt()
    }
}

/// The scan's points (with outward unit `normals`) on its flat base resting
/// on `plane` (same frame, its normal towards the tissue): the scan's
/// dominant plane within [`BASE_THRESHOLD_MM`], when it holds
/// [`MIN_BASE_SHARE`] of the points and lies within [`MAX_BASE_TILT_DEG`]
/// of `plane`, and of its points those that face the plane (outward normal
/// against the plane's). An error saying why there is none.
pub fn base_on(
    scan: &[Point3<f64>],
    normals: &[Vector3<f64>],
    plane: &Plane,
) -> Result<Support, String> {
    let (base_plane, held) = dominant_plane(scan, BASE_THRESHOLD_MM, 300, 1)
        .ok_or("the scan's skin has fewer than 3 points")?;
    let share = held as f64 / scan.len() as f64;
    if share < MIN_BASE_SHARE {
        return Err(format!(
            "the scan's skin has no flat base (its flattest part holds {:.0} % of it, under {:.0} %)",
            100.0 * share,
            100.0 * MIN_BASE_SHARE
        ));
    }
    let tilt_deg = base_plane
        .normal
        .dot(&plane.normal)
        .abs()
        .min(1.0)
        .acos()
        .to_degrees();
    if tilt_deg > MAX_BASE_TILT_DEG {
        return Err(format!(
            "the scan's flat base lies {tilt_deg:.0} deg from the plane seen now (over {MAX_BASE_TILT_DEG} deg): not the plane it rests on"
        ));
    }
    let facing = -(MAX_BASE_TILT_DEG.to_radians().cos());
    let base: Vec<Point3<f64>> = scan
        .iter()
        .zip(normals)
        .filter(|(p, n)| {
            base_plane.distance(p).abs() <= BASE_THRESHOLD_MM && n.dot(&plane.normal) <= facing
        })
        .map(|(p, _)| *p)
        .collect();
    if base.is_empty() {
        return Err("no point of the scan's flat base faces the plane seen now".into());
    }
    Ok(Support {
        base,
        plane: *plane,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::register::deformable::synthetic::{dome, dome_with_base};

    #[test]
    fn a_domes_base_is_found_facing_its_table_and_a_skin_without_one_is_refused() {
        let (points, normals) = dome(3.0);
        // The dome's skin only (no base): its flattest part is small.
        let table = Plane {
            normal: Vector3::z(),
            offset: 0.0,
        };
        let e = base_on(&points, &normals, &table).unwrap_err();
        assert!(e.contains("no flat base"), "{e}");
        // With its base disc (z = 0, normals down).
        let (scan, outward) = dome_with_base(3.0);
        let support = base_on(&scan, &outward, &table).unwrap();
        assert_eq!(support.base.len(), scan.len() - points.len());
        assert!(support.base.iter().all(|p| p.z == 0.0));
        assert!(support.residual_mm(|_| Vector3::zeros()) < 1e-12);
        assert!((support.residual_mm(|_| Vector3::new(0.0, 0.0, 2.0)) - 2.0).abs() < 1e-12);
        // A plane seen across it is not what it rests on.
        let wall = Plane {
            normal: Vector3::x(),
            offset: 0.0,
        };
        assert!(
            base_on(&scan, &outward, &wall)
                .unwrap_err()
                .contains("deg from")
        );
    }
}
