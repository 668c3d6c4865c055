//! Things beside the phantom in the camera session: green distractors on the
//! table (a sticker the size of a marker, a strip of tape, a cup) and a tool
//! held over the dome that hides part of it from some views. Each is a capped
//! cylinder of one colour, in the world frame.

use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

/// A capped cylinder of one colour, world frame (mm).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Prop {
    /// What it stands for (`sticker`, `tape`, `cup`, `tool`).
    pub name: String,
    /// Centre of its base cap, world, mm.
    pub base_world_mm: [f64; 3],
    /// Unit axis from the base cap to the top cap, world.
    pub axis_world: [f64; 3],
    /// Radius, mm.
    pub radius_mm: f64,
    /// Length along the axis, mm.
    pub height_mm: f64,
    /// Albedo, linear RGB.
    pub colour: [f32; 3],
    /// Glossy (takes highlights).
    pub glossy: bool,
}

impl Prop {
    /// The first hit of the ray from `o` along unit `d` (world) beyond
    /// `t_min`: its distance and outward unit normal.
    pub fn intersect(
        &self,
        o: &Point3<f64>,
        d: &Vector3<f64>,
        t_min: f64,
    ) -> Option<(f64, Vector3<f64>)> {
        let n = Vector3::from(self.axis_world);
        let w = o - Point3::from(self.base_world_mm);
        let (wn, dn) = (w.dot(&n), d.dot(&n));
        let (w_perp, d_perp) = (w - n * wn, d - n * dn);
        let mut best: Option<(f64, Vector3<f64>)> = None;
        let mut consider = |t: f64, normal: Vector3<f64>| {
            if t > t_min && best.is_none_or(|(b, _)| t < b) {
                best = Some((t, normal));
            }
        };
        let a = d_perp.norm_squared();
        if a > 1e-15 {
            let b = w_perp.dot(&d_perp);
            let c = w_perp.norm_squared() - self.radius_mm * self.radius_mm;
            let disc = b * b - a * c;
            if disc >= 0.0 {
                for t in [(-b - disc.sqrt()) / a, (-b + disc.sqrt()) / a] {
                    let h = wn + t * dn;
                    if (0.0..=self.height_mm).contains(&h) {
                        consider(t, (w_perp + d_perp * t).normalize());
                    }
                }
            }
        }
        if dn.abs() > 1e-15 {
            for (h, normal) in [(0.0, -n), (self.height_mm, n)] {
                let t = (h - wn) / dn;
                if (w_perp + d_perp * t).norm_squared() <= self.radius_mm * self.radius_mm {
                    consider(t, normal);
                }
            }
        }
        best
    }
}

/// The first prop along a ray (world) beyond `t_min`: its index, distance
/// and outward normal.
pub fn first_prop(
    props: &[Prop],
    o: &Point3<f64>,
    d: &Vector3<f64>,
    t_min: f64,
) -> Option<(usize, f64, Vector3<f64>)> {
    props
        .iter()
        .enumerate()
        .filter_map(|(i, p)| p.intersect(o, d, t_min).map(|(t, n)| (i, t, n)))
        .min_by(|a, b| a.1.total_cmp(&b.1))
}

/// Green things on the table around a phantom whose base is centred at
/// `centre` (world, on the table) and `base_radius_mm` wide, in `green`: a
/// sticker of a marker's size, a strip of tape and a cup, all off the dome.
pub fn distractors(centre: &Point3<f64>, base_radius_mm: f64, green: [f32; 3]) -> Vec<Prop> {
    let at = |dx: f64, dy: f64, dz: f64| {
        let r = base_radius_mm;
        [centre.x + dx * r, centre.y + dy * r, centre.z + dz]
    };
    vec![
        Prop {
            name: "sticker".into(),
            base_world_mm: at(1.35, 0.55, 0.0),
            axis_world: [0.0, 0.0, 1.0],
            radius_mm: 4.5,
            height_mm: 0.5,
            colour: green,
            glossy: false,
        },
        Prop {
            name: "tape".into(),
            base_world_mm: at(-1.5, -0.9, 1.5),
            axis_world: [0.8, 0.6, 0.0],
            radius_mm: 1.5,
            height_mm: 70.0,
            colour: green,
            glossy: false,
        },
        Prop {
            name: "cup".into(),
            base_world_mm: at(-1.45, 1.05, 0.0),
            axis_world: [0.0, 0.0, 1.0],
            radius_mm: 30.0,
            height_mm: 80.0,
            colour: green,
            glossy: true,
        },
    ]
}

/// A grey tool (a needle guide, 10 mm thick) held over the dome: from
/// `clear_mm` above the apex at `apex` (world), slanting up and away.
pub fn occluder(apex: &Point3<f64>, clear_mm: f64) -> Prop {
    let axis = Vector3::new(0.35, -0.45, 0.82).normalize();
    Prop {
        name: "tool".into(),
        base_world_mm: [apex.x - 18.0, apex.y + 12.0, apex.z + clear_mm],
        axis_world: axis.into(),
        radius_mm: 5.0,
        height_mm: 400.0,
        colour: [0.45, 0.45, 0.47],
        glossy: true,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cylinder_is_hit_on_its_side_and_its_caps() {
        let cup = Prop {
            name: "cup".into(),
            base_world_mm: [0.0, 0.0, 0.0],
            axis_world: [0.0, 0.0, 1.0],
            radius_mm: 10.0,
            height_mm: 20.0,
            colour: [0.0, 1.0, 0.0],
            glossy: false,
        };
        let side = cup
            .intersect(&Point3::new(-50.0, 0.0, 5.0), &Vector3::x(), 0.0)
            .unwrap();
        assert!((side.0 - 40.0).abs() < 1e-12 && (side.1 + Vector3::x()).norm() < 1e-12);
        let top = cup
            .intersect(&Point3::new(3.0, 4.0, 100.0), &-Vector3::z(), 0.0)
            .unwrap();
        assert!((top.0 - 80.0).abs() < 1e-12 && (top.1 - Vector3::z()).norm() < 1e-12);
        assert!(
            cup.intersect(&Point3::new(-50.0, 11.0, 5.0), &Vector3::x(), 0.0)
                .is_none()
        );
        assert!(
            cup.intersect(&Point3::new(-50.0, 0.0, 25.0), &Vector3::x(), 0.0)
                .is_none()
        );
    }
}
