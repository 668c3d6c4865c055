//! The phantom's shape cut down to the parts near a segment of space: the
//! markers and lesions that can hold a point within a margin of it. The MRI
//! classifies millions of points; a voxel row or a voxel's sub-samples meet
//! one marker at most, so testing only those gives the same materials as
//! [`PhantomShape::material_at`] for a fraction of the work.

use super::shape::{Lesion, Marker, Material, PhantomShape};
use nalgebra::Point3;

/// [`PhantomShape`] near a segment; see [`PhantomShape::near_segment`].
pub struct ShapeNear<'a> {
    shape: &'a PhantomShape,
    /// The markers that can hold a point near the segment, in the shape's
    /// order (the first marker holding a point decides its material).
    markers: Vec<&'a Marker>,
    /// The lesions that can hold a point near the segment.
    lesions: Vec<&'a Lesion>,
}

impl PhantomShape {
    /// The parts of the shape that can hold a point within `margin_mm` of the
    /// segment from `a` to `b` (phantom frame, mm; `a == b` for a ball).
    pub fn near_segment(&self, a: &Point3<f64>, b: &Point3<f64>, margin_mm: f64) -> ShapeNear<'_> {
        // A hair of slack, so rounding in the distance never drops a part
        // that a point on the margin's edge touches.
        let reach = |radius: f64| radius + margin_mm + 1e-9 * (1.0 + radius + margin_mm);
        ShapeNear {
            shape: self,
            markers: self
                .markers
                .iter()
                .filter(|m| {
                    distance_to_segment(&Point3::from(m.skin_point_mm), a, b)
                        <= reach(m.bounding_radius_squared().sqrt())
                })
                .collect(),
            lesions: self
                .lesions
                .iter()
                .filter(|l| {
                    distance_to_segment(&Point3::from(l.center_mm), a, b) <= reach(l.radius_mm)
                })
                .collect(),
        }
    }
}

impl ShapeNear<'_> {
    /// What `p` is made of: [`PhantomShape::material_at`]'s answer for any
    /// point within the margin of the segment this was cut for.
    pub fn material_at(&self, p: &Point3<f64>) -> Material {
        self.shape.material_among(
            self.markers.iter().copied(),
            self.lesions.iter().copied(),
            p,
        )
    }

    /// A ball around each marker and lesion kept (centre, radius; phantom
    /// frame, mm) outside which the part holds no point: there a point's
    /// material is the dome's alone.
    pub fn part_spheres(&self) -> impl Iterator<Item = (Point3<f64>, f64)> + '_ {
        let markers = self.markers.iter().map(|m| {
            (
                Point3::from(m.skin_point_mm),
                m.bounding_radius_squared().sqrt(),
            )
        });
        let lesions = self
            .lesions
            .iter()
            .map(|l| (Point3::from(l.center_mm), l.radius_mm));
        markers.chain(lesions)
    }
}

/// Distance from `p` to the segment from `a` to `b`, mm.
fn distance_to_segment(p: &Point3<f64>, a: &Point3<f64>, b: &Point3<f64>) -> f64 {
    let ab = b - a;
    let length2 = ab.norm_squared();
    let t = if length2 > 0.0 {
        ((p - a).dot(&ab) / length2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p - (a + ab * t)).norm()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::phantom::shape::ShapeParams;
    use nalgebra::Vector3;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn points_near_the_segment_get_the_whole_shapes_material() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let shape = PhantomShape::build(&ShapeParams::default(), &mut rng).unwrap();
        let mut parts_dropped = 0;
        let mut materials = std::collections::HashSet::new();
        // Segments through each marker's gel and each lesion, and at random.
        let anchors: Vec<Point3<f64>> = shape
            .markers
            .iter()
            .map(|m| m.gel_center())
            .chain(shape.lesions.iter().map(|l| Point3::from(l.center_mm)))
            .collect();
        for trial in 0..400 {
            let a = anchors[trial % anchors.len()]
                + Vector3::from_fn(|_, _| rng.random_range(-4.0..4.0));
            let b = a + Vector3::from_fn(|_, _| rng.random_range(-30.0..30.0)) * (trial % 2) as f64;
            let margin = rng.random_range(0.0..2.0);
            let near = shape.near_segment(&a, &b, margin);
            parts_dropped += shape.markers.len() - near.markers.len();
            for _ in 0..200 {
                let t: f64 = rng.random_range(0.0..1.0);
                let offset = Vector3::from_fn(|_, _| rng.random_range(-1.0..1.0));
                let p = a + (b - a) * t + offset.normalize() * margin * rng.random_range(0.0..1.0);
                let whole = shape.material_at(&p);
                assert_eq!(
                    near.material_at(&p),
                    whole,
                    "{p} near {a} - {b} ({margin} mm)"
                );
                materials.insert(format!("{whole:?}"));
            }
        }
        // The test means something: the cut dropped parts and the points
        // met every material.
        assert!(parts_dropped > 1000, "{parts_dropped}");
        assert_eq!(materials.len(), 5, "{materials:?}");
    }
}
