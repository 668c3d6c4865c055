//! Tissue that moves between the MRI and the camera session: a smooth
//! displacement field of the dome, zero on the table (the chest wall) and
//! largest towards the apex, applied to everything the cameras see (skin,
//! markers, lesions move together) while the MRI stays as scanned.
//!
//! Every kind has the form, in the phantom frame (mm, base on z = 0),
//!
//! u(p) = A w(z) (g(p) v + M h(p)),
//!
//! with w the smoothstep 3t^2 - 2t^3 of t = z / H (zero value and slope on the
//! table, 1 at the apex height H), h the horizontal offset from the dome's
//! axis divided by its base radius R, g = 1 - gamma |h|^2, a direction v and a
//! matrix M chosen by the kind. The amplitude A is set so that the largest
//! displacement over the dome (skin and inside) is the peak asked for.
//! Written here: the field is ours to define, and its Jacobian is needed in
//! closed form (for normals and the inverse map).

use super::shape::PhantomShape;
use fusegraph_plugin_api::derive::Choice;
use nalgebra::{Matrix3, Point3, Vector3};
use serde::{Deserialize, Serialize};

/// How the tissue moves between the scan and the camera session.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Choice)]
#[serde(rename_all = "snake_case")]
pub enum MotionKind {
    /// No motion: the cameras see the phantom as scanned.
    None,
    /// Gravity sag: the dome droops down and towards the direction, most at
    /// its apex and centre.
    Sag,
    /// Compression by a plate from above: the apex moves down, the sides
    /// bulge out.
    Compression,
    /// Squeezed between two paddles across the direction: the dome narrows
    /// along it and widens across it.
    Squeeze,
    /// A lateral shift towards the direction, growing with height (a shear).
    Shift,
}

/// A displacement field of the dome, phantom frame (mm); see the module doc.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MotionField {
    /// The kind, as asked.
    pub kind: MotionKind,
    /// Largest displacement over the dome, mm.
    pub peak_mm: f64,
    /// Horizontal direction of the motion in the phantom frame, deg from +x.
    pub direction_deg: f64,
    /// Amplitude A (mm), set so the largest displacement is `peak_mm`.
    pub amplitude_mm: f64,
    /// Apex height H, mm above the table.
    pub apex_height_mm: f64,
    /// The dome's axis on the table (x, y), mm.
    pub axis_mm: [f64; 2],
    /// Base radius R, mm.
    pub base_radius_mm: f64,
    /// gamma: how much less the sides move than the centre (sag).
    pub gamma: f64,
    /// v, the uniform direction term.
    pub direction: [f64; 3],
    /// M, the radial term (rows).
    pub radial: [[f64; 3]; 3],
}

/// Ratio of the sides' bulge to the apex's travel (compression, squeeze).
const BULGE: f64 = 0.5;

impl MotionField {
    /// The field of `kind` for `shape`, its largest displacement over the
    /// dome `peak_mm` (>= 0), towards `direction_deg` (phantom frame, from +x).
    pub fn new(kind: MotionKind, peak_mm: f64, direction_deg: f64, shape: &PhantomShape) -> Self {
        let (s, c) = direction_deg.to_radians().sin_cos();
        let d = Vector3::new(c, s, 0.0);
        let across = Vector3::new(-s, c, 0.0);
        let flat = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, 0.0));
        let (v, m, gamma) = match kind {
            MotionKind::None => (Vector3::zeros(), Matrix3::zeros(), 0.0),
            MotionKind::Sag => (Vector3::new(c, s, -1.0).normalize(), Matrix3::zeros(), 0.5),
            MotionKind::Compression => (-Vector3::z(), flat * BULGE, 0.0),
            MotionKind::Squeeze => (
                Vector3::zeros(),
                -d * d.transpose() + across * across.transpose() * BULGE,
                0.0,
            ),
            MotionKind::Shift => (d, Matrix3::zeros(), 0.0),
        };
        let (axis, radius, apex) = dome_extent(shape);
        let mut field = MotionField {
            kind,
            peak_mm,
            direction_deg,
            amplitude_mm: 1.0,
            apex_height_mm: apex,
            axis_mm: axis,
            base_radius_mm: radius,
            gamma,
            direction: v.into(),
            radial: m.transpose().into(),
        };
        let largest = dome_points(shape)
            .iter()
            .map(|p| field.displacement(p).norm())
            .fold(0.0, f64::max);
        field.amplitude_mm = if kind == MotionKind::None || largest == 0.0 {
            0.0
        } else {
            peak_mm / largest
        };
        field
    }

    /// The field of no motion (for any shape).
    pub fn still() -> Self {
        MotionField {
            kind: MotionKind::None,
            peak_mm: 0.0,
            direction_deg: 0.0,
            amplitude_mm: 0.0,
            apex_height_mm: 1.0,
            axis_mm: [0.0; 2],
            base_radius_mm: 1.0,
            gamma: 0.0,
            direction: [0.0; 3],
            radial: [[0.0; 3]; 3],
        }
    }

    /// Whether the field moves nothing.
    pub fn is_still(&self) -> bool {
        self.amplitude_mm == 0.0
    }

    fn terms(&self, p: &Point3<f64>) -> (f64, f64, Vector3<f64>, f64, Vector3<f64>) {
        let h = self.apex_height_mm;
        let t = (p.z / h).clamp(0.0, 1.0);
        let w = t * t * (3.0 - 2.0 * t);
        let dw = if p.z > 0.0 && p.z < h {
            6.0 * t * (1.0 - t) / h
        } else {
            0.0
        };
        let r = self.base_radius_mm;
        let offset = Vector3::new(
            (p.x - self.axis_mm[0]) / r,
            (p.y - self.axis_mm[1]) / r,
            0.0,
        );
        let g = 1.0 - self.gamma * offset.norm_squared();
        (w, dw, offset, g, Vector3::from(self.direction))
    }

    fn radial(&self) -> Matrix3<f64> {
        Matrix3::from(self.radial).transpose()
    }

    /// The displacement at `p` (phantom frame, mm), mm.
    pub fn displacement(&self, p: &Point3<f64>) -> Vector3<f64> {
        if self.is_still() {
            return Vector3::zeros();
        }
        let (w, _, offset, g, v) = self.terms(p);
        self.amplitude_mm * w * (v * g + self.radial() * offset)
    }

    /// Where `p` (phantom frame, as scanned) is in the camera session.
    pub fn moved(&self, p: &Point3<f64>) -> Point3<f64> {
        if self.is_still() {
            return *p;
        }
        p + self.displacement(p)
    }

    /// The deformation gradient I + du/dp at `p`.
    pub fn gradient(&self, p: &Point3<f64>) -> Matrix3<f64> {
        let (w, dw, offset, g, v) = self.terms(p);
        let m = self.radial();
        let r = self.base_radius_mm;
        let a = self.amplitude_mm;
        // Columns: d u / d x, d u / d y, d u / d z.
        let dg = -2.0 * self.gamma * offset / r;
        let dx = a * w * (v * dg.x + m.column(0) / r);
        let dy = a * w * (v * dg.y + m.column(1) / r);
        let dz = a * dw * (v * g + m * offset);
        Matrix3::identity() + Matrix3::from_columns(&[dx, dy, dz])
    }

    /// The scanned point that moves to `p` (Newton on `moved(q) = p`, from
    /// `q = p`); exact to about 1e-9 mm for the fields this module makes.
    pub fn unmoved(&self, p: &Point3<f64>) -> Point3<f64> {
        self.unmoved_near(p, p)
    }

    /// [`MotionField::unmoved`] starting Newton from `guess` (a nearby
    /// point's answer, shifted): one or two steps instead of four.
    pub fn unmoved_near(&self, p: &Point3<f64>, guess: &Point3<f64>) -> Point3<f64> {
        if self.is_still() {
            return *p;
        }
        let mut q = *guess;
        for _ in 0..8 {
            let residual = self.moved(&q) - p;
            if residual.norm_squared() < 1e-20 {
                break;
            }
            q -= self.newton_step(&q, &residual);
        }
        q
    }

    /// One Newton step towards `unmoved(p)` from `q`, a close estimate (the
    /// error squares: 0.01 mm becomes about 1e-6 mm).
    pub fn unmoved_step(&self, p: &Point3<f64>, q: &Point3<f64>) -> Point3<f64> {
        if self.is_still() {
            return *p;
        }
        let residual = self.moved(q) - p;
        q - self.newton_step(q, &residual)
    }

    /// The Newton step F(q)^-1 r (the closed-form 3 x 3 inverse: this runs
    /// for every ray through moved tissue); `r` itself where F is singular.
    fn newton_step(&self, q: &Point3<f64>, residual: &Vector3<f64>) -> Vector3<f64> {
        self.gradient(q)
            .try_inverse()
            .map_or(*residual, |inverse| inverse * residual)
    }

    /// |F^-T n| for unit normal `n` at scanned point `q`: a distance `s`
    /// along `n` from the surface becomes `s / |F^-T n|` from the moved
    /// surface (first order).
    pub fn moved_normal_stretch(&self, q: &Point3<f64>, n: &Vector3<f64>) -> f64 {
        if self.is_still() {
            return 1.0;
        }
        self.gradient(q)
            .try_inverse()
            .map_or(1.0, |inv| (inv.transpose() * n).norm())
    }

    /// A unit normal `n` at scanned point `q`, as the moved surface has it
    /// (the inverse transpose of the gradient).
    pub fn moved_normal(&self, q: &Point3<f64>, n: &Vector3<f64>) -> Vector3<f64> {
        if self.is_still() {
            return *n;
        }
        let f = self.gradient(q);
        f.try_inverse()
            .map_or(*n, |inv| (inv.transpose() * n).normalize())
    }
}

/// The dome's axis on the table, its base radius and its apex height (mm,
/// phantom frame).
pub(crate) fn dome_extent(shape: &PhantomShape) -> ([f64; 2], f64, f64) {
    let c = shape.ellipsoid_center_mm;
    let rot = shape.rotation();
    let axes = shape.semi_axes_mm;
    // Highest point of the rotated ellipsoid: centre z + |row z of R diag(a)|.
    let apex = c[2]
        + (0..3)
            .map(|i| (rot[(2, i)] * axes[i]).powi(2))
            .sum::<f64>()
            .sqrt();
    ([c[0], c[1]], axes[0].max(axes[1]), apex)
}

/// Points over the dome (a 24 x 24 x 24 lattice over its bounding box, the
/// ones inside, and their columns' tops on the skin), for the peak.
fn dome_points(shape: &PhantomShape) -> Vec<Point3<f64>> {
    let (axis, radius, apex) = dome_extent(shape);
    let n = 24;
    let at = |i: usize| i as f64 / (n - 1) as f64;
    let mut points = Vec::new();
    for i in 0..n {
        for j in 0..n {
            let (x, y) = (
                axis[0] + radius * (2.0 * at(i) - 1.0),
                axis[1] + radius * (2.0 * at(j) - 1.0),
            );
            let mut top = None;
            for k in 0..n {
                let p = Point3::new(x, y, apex * at(k));
                if shape.inside_dome(&p) {
                    points.push(p);
                    top = Some(p);
                }
            }
            // The skin above the column's highest inside point.
            if let Some(p) = top
                && let Some(hit) = shape.intersect(&p, &Vector3::z(), 0.0)
            {
                points.push(p + Vector3::z() * hit.t);
            }
        }
    }
    points
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::phantom::ShapeParams;
    use rand::SeedableRng;

    fn shape() -> PhantomShape {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        PhantomShape::build(&ShapeParams::default(), &mut rng).unwrap()
    }

    const KINDS: [MotionKind; 4] = [
        MotionKind::Sag,
        MotionKind::Compression,
        MotionKind::Squeeze,
        MotionKind::Shift,
    ];

    #[test]
    fn zero_on_the_table_and_the_peak_asked_for_over_the_dome() {
        let s = shape();
        for kind in KINDS {
            let f = MotionField::new(kind, 10.0, 30.0, &s);
            for (x, y) in [(0.0, 0.0), (30.0, -20.0), (-45.0, 10.0)] {
                let d = f.displacement(&Point3::new(x, y, 0.0));
                assert_eq!(d.norm(), 0.0, "{kind:?} on the table");
            }
            let largest = dome_points(&s)
                .iter()
                .map(|p| f.displacement(p).norm())
                .fold(0.0, f64::max);
            assert!((largest - 10.0).abs() < 1e-9, "{kind:?}: {largest}");
            // Lesions and markers sit inside the dome's span: nothing moves
            // further than the peak by more than the lattice's resolution.
            for m in &s.markers {
                assert!(f.displacement(&m.face_center()).norm() < 10.5, "{kind:?}");
            }
        }
        let still = MotionField::new(MotionKind::None, 10.0, 0.0, &s);
        assert!(still.is_still());
        let p = Point3::new(3.0, 4.0, 20.0);
        assert_eq!(still.moved(&p), p);
    }

    #[test]
    fn the_gradient_is_the_derivative_and_the_field_smooth() {
        let s = shape();
        for kind in KINDS {
            let f = MotionField::new(kind, 15.0, -70.0, &s);
            for p in [
                Point3::new(10.0, -5.0, 12.0),
                Point3::new(-30.0, 20.0, 40.0),
                Point3::new(0.0, 0.0, 1.0),
            ] {
                let g = f.gradient(&p);
                let e = 1e-5;
                for j in 0..3 {
                    let mut step = Vector3::zeros();
                    step[j] = e;
                    let numeric = (f.moved(&(p + step)) - f.moved(&(p - step))) / (2.0 * e);
                    let diff = (numeric - g.column(j)).norm();
                    assert!(diff < 1e-6, "{kind:?} column {j}: {diff}");
                }
                // Smooth and invertible: the gradient stays near the identity.
                let strain = (g - Matrix3::identity()).norm();
                assert!(strain < 0.9, "{kind:?}: {strain}");
                assert!(g.determinant() > 0.2, "{kind:?}");
            }
        }
    }

    #[test]
    fn unmoved_inverts_moved() {
        let s = shape();
        for kind in KINDS {
            let f = MotionField::new(kind, 15.0, 45.0, &s);
            for p in [
                Point3::new(10.0, -5.0, 12.0),
                Point3::new(-30.0, 20.0, 40.0),
                Point3::new(5.0, 5.0, 70.0),
            ] {
                let back = f.unmoved(&f.moved(&p));
                assert!((back - p).norm() < 1e-8, "{kind:?}: {p} -> {back}");
            }
        }
    }
}
