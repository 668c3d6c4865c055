//! Ray casting through the phantom after a [`MotionField`]: a straight ray of
//! the camera session is a curved path through the scanned phantom, followed
//! as chords. Each chord's end points are mapped back by the field's inverse,
//! the analytic intersection runs on the chord, and the first chord hit is
//! refined on one short chord around it. With a smooth field the chord's
//! sagitta bounds the error: about 0.1 mm for the coarse chords and 1e-3 mm
//! for the short one, at 15 mm of motion over the dome.
//!
//! Four things keep it within a small factor of the still phantom's cost:
//! only the span of the ray inside the ellipsoid grown by the markers' reach
//! and the motion's peak is followed (nothing moved lies outside it), the
//! inverse map of the coarse chords is read from a grid (trilinear, built
//! once; the short chord's ends are exact), a chord that stays further
//! from the dome's ellipsoid than anything on it reaches is not intersected,
//! and the supersamples of a pixel whose neighbours all met the skin search
//! only the span of their distances ([`MovedShape::intersect_near`]).

use super::motion::MotionField;
use super::shape::{PhantomShape, RaysFrom, Surface};
use nalgebra::{Matrix3, Point3, Vector3};
use rayon::prelude::*;

/// Length of the coarse chords, mm along the ray (their sagitta is about
/// 0.1 mm; the short chord makes the hit exact).
const COARSE_CHORD_MM: f64 = 16.0;
/// Half the length of the refining chord, mm along the ray.
const FINE_HALF_MM: f64 = 0.5;
/// How far beyond the span of its neighbours' distances a ray's hit on the
/// skin is looked for, mm (a pixel's rays on a smooth surface stay well
/// within their neighbours' span: the margin only takes the curvature).
const NEAR_MARGIN_MM: f64 = 0.5;
/// The longest span searched near the neighbours' distances, mm (longer
/// ones, on skin seen edge-on, follow the whole ray).
const NEAR_SPAN_LIMIT_MM: f64 = 8.0;
/// Spacing of the inverse map's grid, mm: its interpolation error is about
/// |u''| h^2 / 8, under 0.1 mm for the fields `MotionField` makes at 15 mm
/// (as good as the coarse chords' sagitta; the short chord's ends take a
/// Newton step from it, which leaves about 1e-4 mm).
const GRID_STEP_MM: f64 = 2.0;

/// A ray hit on the moved phantom.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MovedHit {
    /// Distance along the (unit) ray, mm.
    pub t: f64,
    /// Outward unit normal of the moved surface.
    pub normal: Vector3<f64>,
    /// What was hit.
    pub surface: Surface,
    /// The hit point as scanned (phantom frame, mm): where textures are read.
    pub scanned: Point3<f64>,
}

/// The phantom as the camera session sees it: a shape moved by a field,
/// with what ray casting through it needs precomputed.
#[derive(Debug, Clone)]
pub struct MovedShape {
    /// The phantom as scanned.
    pub shape: PhantomShape,
    /// The motion since the scan.
    pub field: MotionField,
    box_min: Point3<f64>,
    box_max: Point3<f64>,
    /// How far anything on the phantom (markers) reaches beyond its
    /// ellipsoid, mm.
    reach_mm: f64,
    /// Maps phantom points to the ellipsoid's unit-sphere coordinates.
    to_sphere: Matrix3<f64>,
    /// The same for the ellipsoid with every semi-axis grown by the reach
    /// and the peak: it holds the offset surface, so everything moved.
    to_grown_sphere: Matrix3<f64>,
    /// Unit-sphere radius within which a point is deeper inside the
    /// ellipsoid than the motion's peak (and so inside the moved body, when
    /// also that high above the base).
    deep_radius: f64,
    smallest_axis_mm: f64,
    inverse: Option<InverseGrid>,
}

impl MovedShape {
    /// `shape` moved by `field`; builds the inverse map's grid when the field
    /// moves anything (about 0.1 s).
    pub fn new(shape: PhantomShape, field: MotionField) -> Self {
        let reach_mm = shape
            .markers
            .iter()
            .map(|m| m.height_mm + m.radius_mm)
            .fold(0.0, f64::max);
        // Everything the field moves lies in the dome's box grown by the
        // markers' reach and the motion's peak.
        let grow = reach_mm + field.peak_mm + 1.0;
        let r = field.base_radius_mm + grow;
        let [ax, ay] = field.axis_mm;
        let box_min = Point3::new(ax - r, ay - r, -grow);
        let box_max = Point3::new(ax + r, ay + r, field.apex_height_mm + grow);
        let axes = Vector3::from(shape.semi_axes_mm);
        let unrotate = shape.rotation().inverse().into_inner();
        let to_sphere = Matrix3::from_diagonal(&axes.map(|a| 1.0 / a)) * unrotate;
        let to_grown_sphere = Matrix3::from_diagonal(&axes.map(|a| 1.0 / (a + grow))) * unrotate;
        let inverse = (!field.is_still()).then(|| InverseGrid::new(&field, &box_min, &box_max));
        MovedShape {
            deep_radius: 1.0 - (field.peak_mm + 1.0) / axes.min(),
            smallest_axis_mm: axes.min(),
            shape,
            field,
            box_min,
            box_max,
            reach_mm,
            to_sphere,
            to_grown_sphere,
            inverse,
        }
    }

    /// The first surface hit by the ray from `origin` along unit `dir`
    /// (phantom frame, camera session), beyond `t_min`.
    pub fn intersect(
        &self,
        origin: &Point3<f64>,
        dir: &Vector3<f64>,
        t_min: f64,
    ) -> Option<MovedHit> {
        let Some(grid) = &self.inverse else {
            return unmoved_hit(origin, dir, self.shape.intersect(origin, dir, t_min));
        };
        let (t0, t1) = self.clip(origin, dir)?;
        let t0 = t0.max(t_min);
        if t0 >= t1 {
            return None;
        }
        let chords = ((t1 - t0) / COARSE_CHORD_MM).ceil().max(1.0) as usize;
        let coarse = self.first_chord_hit(origin, dir, t0, t1, chords, |p| grid.at(p))?;
        let (a, b) = (
            (coarse.t - FINE_HALF_MM).max(t0),
            (coarse.t + FINE_HALF_MM).min(t1),
        );
        // The short chord's ends to about 1e-6 mm: a Newton step from the grid.
        let guess = |p: &Point3<f64>| self.field.unmoved_step(p, &grid.at(p));
        let mut hit = self
            .first_chord_hit(origin, dir, a, b, 1, guess)
            .unwrap_or(coarse);
        // Chord hits carry the scanned surface's normal until here.
        hit.normal = self.field.moved_normal(&hit.scanned, &hit.normal);
        Some(hit)
    }

    /// Rays from `origin` (phantom frame) ready for
    /// [`MovedShape::intersect_from`]; `None` where the tissue moved (the
    /// moved body is followed along each ray, which shares nothing).
    pub fn rays_from(&self, origin: &Point3<f64>) -> Option<RaysFrom<'_>> {
        self.inverse.is_none().then(|| self.shape.rays_from(origin))
    }

    /// [`MovedShape::intersect`] from the origin of `rays` (which
    /// [`MovedShape::rays_from`] made) along unit `dir`.
    pub fn intersect_from(
        &self,
        rays: &RaysFrom,
        dir: &Vector3<f64>,
        t_min: f64,
    ) -> Option<MovedHit> {
        unmoved_hit(rays.origin(), dir, rays.intersect(dir, t_min))
    }

    /// [`MovedShape::intersect`] for a ray whose neighbours, within a pixel
    /// of it on every side, all met the skin at distances within
    /// `span_mm`: only that span, widened by [`NEAR_MARGIN_MM`], is
    /// searched, on short chords (as exact as `intersect`'s refining one).
    /// Where the span holds no skin, or is too long to be worth it, the
    /// whole ray is followed. Nothing in front of the span can be missed
    /// unless it is thinner than the pixel grid, which the renderer's
    /// supersampling does not resolve either.
    pub fn intersect_near(
        &self,
        origin: &Point3<f64>,
        dir: &Vector3<f64>,
        t_min: f64,
        span_mm: (f64, f64),
    ) -> Option<MovedHit> {
        let Some(grid) = &self.inverse else {
            return self.intersect(origin, dir, t_min);
        };
        let (a, b) = (
            (span_mm.0 - NEAR_MARGIN_MM).max(t_min),
            span_mm.1 + NEAR_MARGIN_MM,
        );
        if !(b - a).is_finite() || b - a > NEAR_SPAN_LIMIT_MM {
            return self.intersect(origin, dir, t_min);
        }
        let chords = ((b - a) / (2.0 * FINE_HALF_MM)).ceil().max(1.0) as usize;
        let exact = |p: &Point3<f64>| self.field.unmoved_step(p, &grid.at(p));
        match self.first_chord_hit(origin, dir, a, b, chords, exact) {
            Some(mut hit) if hit.surface == Surface::Skin => {
                hit.normal = self.field.moved_normal(&hit.scanned, &hit.normal);
                Some(hit)
            }
            _ => self.intersect(origin, dir, t_min),
        }
    }

    /// The ray's span inside the box and the grown ellipsoid, if any.
    fn clip(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Option<(f64, f64)> {
        let (mut lo, mut hi) = (0.0f64, f64::INFINITY);
        for i in 0..3 {
            if dir[i].abs() < 1e-15 {
                if origin[i] < self.box_min[i] || origin[i] > self.box_max[i] {
                    return None;
                }
                continue;
            }
            let a = (self.box_min[i] - origin[i]) / dir[i];
            let b = (self.box_max[i] - origin[i]) / dir[i];
            lo = lo.max(a.min(b));
            hi = hi.min(a.max(b));
        }
        let centre = Point3::from(self.shape.ellipsoid_center_mm);
        let (o, d) = (
            self.to_grown_sphere * (origin - centre),
            self.to_grown_sphere * dir,
        );
        let (a, b, c) = (d.norm_squared(), o.dot(&d), o.norm_squared() - 1.0);
        let disc = b * b - a * c;
        if disc <= 0.0 {
            return None;
        }
        let sq = disc.sqrt();
        lo = lo.max((-b - sq) / a);
        hi = hi.min((-b + sq) / a);
        // A point deeper in the tissue than the motion reaches is inside the
        // moved body: the ray met its surface before.
        if self.deep_radius > 0.0 {
            let (o, d) = (self.to_sphere * (origin - centre), self.to_sphere * dir);
            let (a, b, c) = (
                d.norm_squared(),
                o.dot(&d),
                o.norm_squared() - self.deep_radius * self.deep_radius,
            );
            let disc = b * b - a * c;
            if disc > 0.0 {
                let deep = (-b - disc.sqrt()) / a;
                if deep > lo && (origin + dir * deep).z > self.field.peak_mm + 1.0 {
                    hi = hi.min(deep);
                }
            }
        }
        (lo < hi).then_some((lo, hi))
    }

    /// A lower bound of the distance from `q` (scanned) to the ellipsoid, mm:
    /// the unit-sphere map stretches distances by at most 1 / smallest axis.
    fn ellipsoid_distance_bound(&self, q: &Point3<f64>) -> f64 {
        let c = Point3::from(self.shape.ellipsoid_center_mm);
        ((self.to_sphere * (q - c)).norm() - 1.0).abs() * self.smallest_axis_mm
    }

    /// The first hit on `chords` chords of the ray's span [t0, t1], their
    /// ends mapped back by `unmoved`; its normal is the scanned surface's.
    fn first_chord_hit(
        &self,
        origin: &Point3<f64>,
        dir: &Vector3<f64>,
        t0: f64,
        t1: f64,
        chords: usize,
        unmoved: impl Fn(&Point3<f64>) -> Point3<f64>,
    ) -> Option<MovedHit> {
        let at = |i: usize| t0 + (t1 - t0) * i as f64 / chords as f64;
        let mut start = unmoved(&(origin + dir * t0));
        let mut start_clear = self.ellipsoid_distance_bound(&start);
        for i in 0..chords {
            let (a, b) = (at(i), at(i + 1));
            let end = unmoved(&(origin + dir * b));
            let end_clear = self.ellipsoid_distance_bound(&end);
            let chord = end - start;
            let length = chord.norm();
            // Every point of the chord is within half its length of an end.
            let far = start_clear.min(end_clear) - 0.5 * length > self.reach_mm;
            if length > 0.0 && !far {
                let along = chord / length;
                if let Some(h) = self
                    .shape
                    .intersect(&start, &along, 0.0)
                    .filter(|h| h.t <= length)
                {
                    let scanned = start + along * h.t;
                    return Some(MovedHit {
                        t: a + (b - a) * h.t / length,
                        normal: h.normal,
                        surface: h.surface,
                        scanned,
                    });
                }
            }
            (start, start_clear) = (end, end_clear);
        }
        None
    }
}

/// The field's inverse (`unmoved(p) - p`) sampled on a regular grid over a
/// box, read back trilinearly.
#[derive(Debug, Clone)]
struct InverseGrid {
    origin: Point3<f64>,
    dims: [usize; 3],
    offsets: Vec<Vector3<f64>>,
}

impl InverseGrid {
    fn new(field: &MotionField, min: &Point3<f64>, max: &Point3<f64>) -> Self {
        let dims: [usize; 3] =
            std::array::from_fn(|i| ((max[i] - min[i]) / GRID_STEP_MM).ceil() as usize + 2);
        let origin = *min;
        let offsets = (0..dims[2])
            .into_par_iter()
            .flat_map_iter(|k| {
                (0..dims[1]).flat_map(move |j| {
                    (0..dims[0]).map(move |i| {
                        let p = origin + Vector3::new(i as f64, j as f64, k as f64) * GRID_STEP_MM;
                        field.unmoved(&p) - p
                    })
                })
            })
            .collect();
        InverseGrid {
            origin,
            dims,
            offsets,
        }
    }

    /// The interpolated scanned point of `p` (clamped to the grid).
    fn at(&self, p: &Point3<f64>) -> Point3<f64> {
        let g = (p - self.origin) / GRID_STEP_MM;
        let mut base = [0usize; 3];
        let mut frac = [0.0f64; 3];
        for i in 0..3 {
            let x = g[i].clamp(0.0, (self.dims[i] - 2) as f64);
            base[i] = (x as usize).min(self.dims[i] - 2);
            frac[i] = x - base[i] as f64;
        }
        let index = |i: usize, j: usize, k: usize| i + self.dims[0] * (j + self.dims[1] * k);
        let mut offset = Vector3::zeros();
        for corner in 0..8 {
            let (di, dj, dk) = (corner & 1, (corner >> 1) & 1, corner >> 2);
            let w = if di == 1 { frac[0] } else { 1.0 - frac[0] }
                * if dj == 1 { frac[1] } else { 1.0 - frac[1] }
                * if dk == 1 { frac[2] } else { 1.0 - frac[2] };
            offset += self.offsets[index(base[0] + di, base[1] + dj, base[2] + dk)] * w;
        }
        p + offset
    }
}

/// A hit on the unmoved shape as a [`MovedHit`]: it lies where it was scanned.
fn unmoved_hit(
    origin: &Point3<f64>,
    dir: &Vector3<f64>,
    hit: Option<super::shape::Hit>,
) -> Option<MovedHit> {
    hit.map(|h| MovedHit {
        t: h.t,
        normal: h.normal,
        surface: h.surface,
        scanned: origin + dir * h.t,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::phantom::ShapeParams;
    use crate::phantom::motion::MotionKind;
    use rand::SeedableRng;

    fn shape() -> PhantomShape {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        PhantomShape::build(&ShapeParams::default(), &mut rng).unwrap()
    }

    #[test]
    fn a_ray_hits_the_moved_skin_where_the_field_moved_it() {
        let s = shape();
        for kind in [
            MotionKind::Sag,
            MotionKind::Compression,
            MotionKind::Shift,
            MotionKind::Squeeze,
        ] {
            let field = MotionField::new(kind, 12.0, 20.0, &s);
            let moved = MovedShape::new(s.clone(), field.clone());
            // Rays from a camera-like eye towards moved skin points: each must
            // land on the moved point it aimed at (or on something in front).
            let eye = Point3::new(40.0, -250.0, 300.0);
            let mut checked = 0;
            for (x, y) in [(0.0, 0.0), (15.0, -10.0), (-20.0, -25.0), (25.0, 5.0)] {
                let Some(top) = s.intersect(&Point3::new(x, y, 200.0), &-Vector3::z(), 0.0) else {
                    continue;
                };
                if top.surface != Surface::Skin {
                    continue;
                }
                let scanned = Point3::new(x, y, 200.0 - top.t);
                let target = field.moved(&scanned);
                let dir = (target - eye).normalize();
                let hit = moved.intersect(&eye, &dir, 0.0).expect("a hit");
                let expected_t = (target - eye).norm();
                if hit.surface == Surface::Skin && (hit.scanned - scanned).norm() < 1.0 {
                    assert!(
                        (hit.t - expected_t).abs() < 2e-3,
                        "{kind:?}: t {} vs {expected_t}",
                        hit.t
                    );
                    assert!(
                        (field.moved(&hit.scanned) - target).norm() < 2e-3,
                        "{kind:?}"
                    );
                    checked += 1;
                } else {
                    assert!(hit.t < expected_t, "{kind:?}: something in front");
                }
            }
            assert!(checked >= 2, "{kind:?}: {checked}");
        }
    }

    #[test]
    fn the_inverse_grid_is_the_inverse_to_a_tenth_of_a_millimetre_and_a_step_makes_it_exact() {
        let s = shape();
        for kind in [
            MotionKind::Sag,
            MotionKind::Compression,
            MotionKind::Squeeze,
            MotionKind::Shift,
        ] {
            let field = MotionField::new(kind, 15.0, 60.0, &s);
            let moved = MovedShape::new(s.clone(), field.clone());
            let grid = moved.inverse.as_ref().unwrap();
            let mut worst: f64 = 0.0;
            for i in 0..500 {
                let f = i as f64;
                let p = Point3::new(
                    (f * 0.731).sin() * 70.0,
                    (f * 1.313).cos() * 70.0,
                    (f * 0.377).sin().abs() * 70.0,
                );
                let exact = field.unmoved(&p);
                worst = worst.max((grid.at(&p) - exact).norm());
                let stepped = field.unmoved_step(&p, &grid.at(&p));
                assert!((stepped - exact).norm() < 1e-3, "{kind:?} at {p}");
            }
            assert!(worst < 0.1, "{kind:?}: {worst} mm");
        }
    }

    #[test]
    fn a_ray_searched_near_its_neighbours_skin_hits_what_the_whole_ray_hits() {
        let s = shape();
        let field = MotionField::new(MotionKind::Sag, 12.0, 30.0, &s);
        let moved = MovedShape::new(s.clone(), field);
        let eye = Point3::new(60.0, -300.0, 350.0);
        // Pixel-sized steps of the ray at 400 mm (0.3 mm), over the dome.
        let step = 0.3 / 400.0;
        let (mut near_checked, mut fallbacks) = (0, 0);
        for k in 0..40 {
            let (x, y) = ((k % 8) as f64 * 10.0 - 35.0, (k / 8) as f64 * 15.0 - 30.0);
            let centre = (Point3::new(x, y, 20.0) - eye).normalize();
            let (u, v) = (
                centre.cross(&Vector3::z()).normalize(),
                centre.cross(&centre.cross(&Vector3::z())).normalize(),
            );
            let ray = |i: f64, j: f64| (centre + u * i * step + v * j * step).normalize();
            let neighbours: Vec<_> = (-1..=1)
                .flat_map(|j| (-1..=1).map(move |i| (i as f64, j as f64)))
                .map(|(i, j)| moved.intersect(&eye, &ray(i, j), 0.0))
                .collect();
            if !neighbours
                .iter()
                .all(|h| h.is_some_and(|h| h.surface == Surface::Skin))
            {
                continue;
            }
            let ts = neighbours.iter().map(|h| h.unwrap().t);
            let span = (
                ts.clone().fold(f64::INFINITY, f64::min),
                ts.fold(0.0, f64::max),
            );
            for (i, j) in [(0.0, 0.0), (0.4, -0.3), (-0.45, 0.45), (0.2, 0.1)] {
                let dir = ray(i, j);
                let whole = moved.intersect(&eye, &dir, 0.0).unwrap();
                let near = moved.intersect_near(&eye, &dir, 0.0, span).unwrap();
                assert_eq!(near.surface, whole.surface);
                // Both are short chords of the ray's curved path: a few um
                // apart, a hundredth of the skin texture's finest feature.
                assert!(
                    (near.t - whole.t).abs() < 5e-3,
                    "t {} vs {}",
                    near.t,
                    whole.t
                );
                assert!((near.scanned - whole.scanned).norm() < 5e-3);
                assert!((near.normal - whole.normal).norm() < 1e-3);
                near_checked += 1;
                // A span the ray does not meet the skin in: the whole ray.
                let wrong = (span.0 - 30.0, span.0 - 20.0);
                let fallback = moved.intersect_near(&eye, &dir, 0.0, wrong).unwrap();
                assert!((fallback.t - whole.t).abs() < 1e-9);
                fallbacks += 1;
            }
        }
        assert!(near_checked >= 60, "{near_checked} rays checked");
        assert_eq!(fallbacks, near_checked);
    }

    #[test]
    fn no_motion_is_the_scanned_shape_exactly() {
        let s = shape();
        let field = MotionField::new(MotionKind::None, 10.0, 0.0, &s);
        let moved = MovedShape::new(s.clone(), field.clone());
        let eye = Point3::new(10.0, -200.0, 250.0);
        let dir = (Point3::new(0.0, 0.0, 30.0) - eye).normalize();
        let a = s.intersect(&eye, &dir, 1e-6).unwrap();
        let b = moved.intersect(&eye, &dir, 1e-6).unwrap();
        assert_eq!((a.t, a.normal, a.surface), (b.t, b.normal, b.surface));
    }
}
