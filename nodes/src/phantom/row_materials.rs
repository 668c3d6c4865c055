//! Materials along a straight row of points, such as a row of MRI voxel
//! centres. Away from the markers and lesions near the row, a point's
//! material is the dome's alone (tissue inside, background outside), and
//! the dome (an ellipsoid cut by the table's plane) is convex, so the row
//! meets it in one interval, found here in closed form. A point is
//! classified by that interval unless it lies where a marker or lesion could
//! hold it, or within a hair of the dome's surface; those few are classified
//! point by point. Either way the material is [`ShapeNear::material_at`]'s,
//! at a fraction of the cost for the millions of points an MRI classifies.

use super::shape::{Material, PhantomShape};
use super::shape_near::ShapeNear;
use nalgebra::{Point3, Vector3};

/// Materials of the points `start + t step` of a row (phantom frame, mm;
/// `0 <= t <= span`), each known to within `slack_mm` of that line.
pub struct RowMaterials<'s, 'n> {
    near: &'n ShapeNear<'s>,
    /// The dome's implicit function along the row, `q(t) = q[0] + t (q[1] +
    /// t q[2])`: the squared length in the ellipsoid's unit-sphere frame,
    /// less 1 (negative inside).
    q: [f64; 3],
    /// `|q|` at most this far from its value on the exact line: closer to
    /// zero, the point is classified on its own.
    q_guard: f64,
    /// Height over the table along the row, `z(t) = z[0] + t z[1]`, mm.
    z: [f64; 2],
    /// Heights closer to zero than this are classified on their own, mm.
    z_guard_mm: f64,
    /// Ranges of t where a marker or lesion may hold the point.
    near_parts: Vec<(f64, f64)>,
}

impl<'s, 'n> RowMaterials<'s, 'n> {
    /// The row `start + t step` (phantom frame, mm; `0 <= t <= span`) on
    /// `shape`. `near` must hold every marker and lesion that can hold a
    /// point the row will be asked about, and those points must lie
    /// within `slack_mm` of the line.
    pub fn new(
        shape: &PhantomShape,
        near: &'n ShapeNear<'s>,
        (start, step): (&Point3<f64>, &Vector3<f64>),
        span: f64,
        slack_mm: f64,
    ) -> Self {
        let (u0, du) = (shape.to_unit_sphere(start), shape.to_unit_frame(step));
        let q = [
            u0.norm_squared() - 1.0,
            2.0 * u0.dot(&du),
            du.norm_squared(),
        ];
        // A point off the line by δ (|δ| <= slack) moves u by at most
        // |δ| / a_min, and q by 2 |u| |δ| / a_min + (|δ| / a_min)^2; |u| is
        // largest at the row's ends. Rounding in q itself is far below 1e-9.
        let reach = slack_mm / Vector3::from(shape.semi_axes_mm).min();
        let u_max = u0.norm().max((u0 + du * span).norm());
        RowMaterials {
            near,
            q,
            q_guard: 2.0 * (2.0 * u_max * reach + reach * reach) + 1e-9,
            z: [start.z, step.z],
            z_guard_mm: 2.0 * slack_mm + 1e-9,
            near_parts: near
                .part_spheres()
                .filter_map(|(centre, radius)| {
                    sphere_range(start, step, &centre, radius + 2.0 * slack_mm + 1e-9)
                })
                .collect(),
        }
    }

    /// The material at parameter `t` of the row (`0 <= t <= span`),
    /// `point` giving the point itself where it must be classified alone.
    #[inline]
    pub fn material_at(&self, t: f64, point: impl FnOnce() -> Point3<f64>) -> Material {
        let q = self.q[0] + t * (self.q[1] + t * self.q[2]);
        let z = self.z[0] + t * self.z[1];
        let decided = q.abs() > self.q_guard
            && z.abs() > self.z_guard_mm
            && !self.near_parts.iter().any(|&(lo, hi)| lo <= t && t <= hi);
        if decided {
            if q < 0.0 && z > 0.0 {
                Material::Tissue
            } else {
                Material::Background
            }
        } else {
            self.near.material_at(&point())
        }
    }
}

/// The range of t where `start + t step` lies within `radius` of `centre`,
/// widened by a hair for rounding; `None` where the line misses the ball.
fn sphere_range(
    start: &Point3<f64>,
    step: &Vector3<f64>,
    centre: &Point3<f64>,
    radius: f64,
) -> Option<(f64, f64)> {
    let offset = start - centre;
    let (a, b, c) = (
        step.norm_squared(),
        step.dot(&offset),
        offset.norm_squared() - radius * radius,
    );
    if a == 0.0 {
        return (c <= 0.0).then_some((f64::NEG_INFINITY, f64::INFINITY));
    }
    let disc = b * b - a * c;
    if disc < 0.0 {
        return None;
    }
    let root = disc.sqrt();
    let hair = 1e-6 * (1.0 + (b.abs() + root) / a);
    Some(((-b - root) / a - hair, (-b + root) / a + hair))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::phantom::shape::ShapeParams;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Rows in every direction through the dome, its markers and lesions,
    /// at sub-voxel steps: every point's material is the whole shape's.
    #[test]
    fn rows_give_the_whole_shapes_materials() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let shape = PhantomShape::build(&ShapeParams::default(), &mut rng).unwrap();
        let anchors: Vec<Point3<f64>> = shape
            .markers
            .iter()
            .map(|m| m.gel_center())
            .chain(shape.lesions.iter().map(|l| Point3::from(l.center_mm)))
            .chain([Point3::from(shape.ellipsoid_center_mm)])
            .collect();
        let (mut decided, mut alone) = (0, 0);
        let mut materials = std::collections::HashSet::new();
        for trial in 0..300 {
            let through = anchors[trial % anchors.len()]
                + Vector3::from_fn(|_, _| rng.random_range(-6.0..6.0));
            let step = Vector3::from_fn(|_, _| rng.random_range(-1.0..1.0)).normalize()
                * rng.random_range(0.2..1.5);
            let count = 300;
            let start = through - step * (count as f64 / 2.0);
            let slack = 1e-6;
            let end = start + step * (count - 1) as f64;
            let near = shape.near_segment(&start, &end, slack);
            let span = (count - 1) as f64;
            let row = RowMaterials::new(&shape, &near, (&start, &step), span, slack);
            for i in 0..count {
                let t = i as f64;
                // Off the line by up to the slack, as a grid's rounding is.
                let p = start
                    + step * t
                    + Vector3::from_fn(|_, _| rng.random_range(-1.0..1.0)) * (slack / 2.0);
                let whole = shape.material_at(&p);
                let mut asked = false;
                let found = row.material_at(t, || {
                    asked = true;
                    p
                });
                assert_eq!(found, whole, "trial {trial}, t {t}");
                if asked {
                    alone += 1
                } else {
                    decided += 1
                }
                materials.insert(format!("{whole:?}"));
            }
        }
        // The shortcut is taken for most points, and the rows met every
        // material.
        assert!(decided > 10 * alone, "{decided} decided, {alone} alone");
        assert_eq!(materials.len(), 5, "{materials:?}");
    }

    /// A point on the dome's surface itself is classified alone, not by
    /// the interval, even on a row no marker or lesion comes near.
    #[test]
    fn points_on_the_surface_are_classified_alone() {
        let shape = PhantomShape::build(&ShapeParams::default(), &mut ChaCha8Rng::seed_from_u64(2))
            .unwrap();
        let c = Point3::from(shape.ellipsoid_center_mm);
        let step = Vector3::new(0.7, 0.1, 0.0);
        let mut tested = 0;
        for height_mm in (1..60).map(|h| h as f64) {
            let start = Point3::new(c.x, c.y + 3.0, height_mm);
            let end = start + step * 400.0;
            let near = shape.near_segment(&start, &end, 1e-6);
            let row = RowMaterials::new(&shape, &near, (&start, &step), 400.0, 1e-6);
            let q_at = |t: f64| row.q[0] + t * (row.q[1] + t * row.q[2]);
            if !row.near_parts.is_empty() || q_at(0.0) >= 0.0 || q_at(400.0) <= 0.0 {
                continue;
            }
            // The crossing, by bisection; asked right at it.
            let (mut lo, mut hi) = (0.0, 400.0);
            for _ in 0..200 {
                let mid = 0.5 * (lo + hi);
                if q_at(mid) < 0.0 { lo = mid } else { hi = mid }
            }
            let mut asked = false;
            let found = row.material_at(lo, || {
                asked = true;
                start + step * lo
            });
            assert!(asked, "height {height_mm}: the surface point was decided");
            assert_eq!(found, shape.material_at(&(start + step * lo)));
            assert!(!asked_at(&row, 0.0) && !asked_at(&row, 400.0));
            tested += 1;
        }
        assert!(tested > 10, "{tested} rows tested");
    }

    /// Whether the row classifies the point at `t` alone.
    fn asked_at(row: &RowMaterials, t: f64) -> bool {
        let mut asked = false;
        row.material_at(t, || {
            asked = true;
            Point3::origin()
        });
        asked
    }
}
