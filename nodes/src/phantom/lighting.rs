//! How the phantom scene is lit: lamps (distant, or at a position with
//! inverse-square falloff), each of an intensity and a colour temperature,
//! ambient light, Blinn-Phong highlights, cast shadows, and a camera white
//! balance that may be set for another colour temperature than the lamps'.
//!
//! Colour temperature to linear sRGB: the Planckian locus in CIE 1931 xy by
//! Kim et al.'s cubic fit (US patent 7024034; "Design of advanced color
//! temperature control system for HDTV applications", J. Korean Phys. Soc.
//! 2002), 1667-25000 K, to XYZ at Y = 1 and through the sRGB (D65) matrix.
//! Written here: a dozen lines of published constants.

use nalgebra::{Point3, Vector3};

/// One lamp, world frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Lamp {
    /// Where the light comes from.
    pub source: LampSource,
    /// Irradiance it gives, relative to the ideal phantom's lamp (at the
    /// phantom's centre for a lamp at a position).
    pub intensity: f64,
    /// Its colour as the camera records it after white balance (linear RGB,
    /// green = 1 for a lamp of the balanced temperature: [1, 1, 1]).
    pub colour: [f64; 3],
}

/// Where a lamp's light comes from.
#[derive(Debug, Clone, PartialEq)]
pub enum LampSource {
    /// Far away, from this unit direction (towards the lamp).
    Distant(Vector3<f64>),
    /// At this point, mm, with falloff 1 / d^2 normalised at `reference_mm`.
    At {
        /// Position, world, mm.
        position: Point3<f64>,
        /// Distance at which the intensity is as given, mm.
        reference_mm: f64,
    },
}

impl Lamp {
    /// Unit direction towards the lamp from `p` (world), the irradiance
    /// factor there, and the distance to the lamp (infinite when distant).
    pub fn towards(&self, p: &Point3<f64>) -> (Vector3<f64>, f64, f64) {
        match &self.source {
            LampSource::Distant(d) => (*d, self.intensity, f64::INFINITY),
            LampSource::At {
                position,
                reference_mm,
            } => {
                let to = position - p;
                let d = to.norm();
                (to / d, self.intensity * (reference_mm / d).powi(2), d)
            }
        }
    }
}

/// Where light is reflected: a surface point, its outward unit normal and
/// the unit direction to the eye, world frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfacePoint {
    /// The point, mm.
    pub point: Point3<f64>,
    /// Outward unit normal.
    pub normal: Vector3<f64>,
    /// Unit direction towards the eye.
    pub to_eye: Vector3<f64>,
}

/// The whole lighting of the phantom scene.
#[derive(Debug, Clone, PartialEq)]
pub struct Lighting {
    /// The lamps.
    pub lamps: Vec<Lamp>,
    /// Fraction of the light that is ambient (reaches every surface evenly).
    pub ambient: f64,
    /// Colour of the ambient light (linear RGB, after white balance).
    pub ambient_colour: [f64; 3],
    /// Blinn-Phong highlight strength on the phantom (skin and markers).
    pub specular: f64,
    /// Blinn-Phong exponent (larger: smaller, sharper highlights).
    pub shininess: f64,
    /// Whether surfaces hidden from a lamp are in its shadow.
    pub shadows: bool,
}

impl Lighting {
    /// The ideal phantom's light: one distant white lamp from `direction`,
    /// 35 % ambient, matte, no shadows.
    pub fn ideal(direction: Vector3<f64>) -> Self {
        Lighting {
            lamps: vec![Lamp {
                source: LampSource::Distant(direction),
                intensity: 1.0,
                colour: [1.0; 3],
            }],
            ambient: 0.35,
            ambient_colour: [1.0; 3],
            specular: 0.0,
            shininess: 40.0,
            shadows: false,
        }
    }

    /// Light leaving a surface point: `albedo` (linear RGB) times `texture`
    /// under the ambient light and each lamp `lit` lets reach the point
    /// (`lit(lamp index, direction, distance)` is false in a shadow; it is
    /// asked only of lamps the surface faces, when shadows are cast), plus
    /// highlights when `glossy`.
    pub fn shade(
        &self,
        albedo: [f32; 3],
        texture: f64,
        at: &SurfacePoint,
        glossy: bool,
        lit: impl Fn(usize, &Vector3<f64>, f64) -> bool,
    ) -> [f32; 3] {
        let mut diffuse = [0.0f64; 3];
        let mut highlight = [0.0f64; 3];
        for (i, lamp) in self.lamps.iter().enumerate() {
            let (l, irradiance, distance) = lamp.towards(&at.point);
            let facing = at.normal.dot(&l).max(0.0);
            if facing == 0.0 || (self.shadows && !lit(i, &l, distance)) {
                continue;
            }
            for (d, colour) in diffuse.iter_mut().zip(lamp.colour) {
                *d += irradiance * colour * facing;
            }
            if glossy && self.specular > 0.0 {
                let half = (l + at.to_eye).normalize();
                let s =
                    self.specular * irradiance * at.normal.dot(&half).max(0.0).powf(self.shininess);
                for (h, colour) in highlight.iter_mut().zip(lamp.colour) {
                    *h += s * colour;
                }
            }
        }
        // Kept in the ideal phantom's order of operations (same bits).
        std::array::from_fn(|c| {
            let light = self.ambient * self.ambient_colour[c] + (1.0 - self.ambient) * diffuse[c];
            (albedo[c] as f64 * (light * texture) + highlight[c]) as f32
        })
    }
}

/// Linear sRGB of a black body at `kelvin` (1667-25000 K, clamped), scaled to
/// green = 1.
pub fn kelvin_rgb(kelvin: f64) -> [f64; 3] {
    let t = kelvin.clamp(1667.0, 25000.0);
    let (t2, t3) = (t * t, t * t * t);
    let x = if t <= 4000.0 {
        -0.2661239e9 / t3 - 0.2343589e6 / t2 + 0.8776956e3 / t + 0.179910
    } else {
        -3.0258469e9 / t3 + 2.1070379e6 / t2 + 0.2226347e3 / t + 0.240390
    };
    let (x2, x3) = (x * x, x * x * x);
    let y = if t <= 2222.0 {
        -1.1063814 * x3 - 1.34811020 * x2 + 2.18555832 * x - 0.20219683
    } else if t <= 4000.0 {
        -0.9549476 * x3 - 1.37418593 * x2 + 2.09137015 * x - 0.16748867
    } else {
        3.0817580 * x3 - 5.87338670 * x2 + 3.75112997 * x - 0.37001483
    };
    let xyz = Vector3::new(x / y, 1.0, (1.0 - x - y) / y);
    let to_srgb = nalgebra::Matrix3::new(
        3.2406, -1.5372, -0.4986, //
        -0.9689, 1.8758, 0.0415, //
        0.0557, -0.2040, 1.0570,
    );
    let rgb = to_srgb * xyz;
    [rgb.x / rgb.y, 1.0, rgb.z / rgb.y]
}

/// The colour a camera white-balanced for `balanced_kelvin` records of a
/// lamp at `lamp_kelvin` (green = 1; [1, 1, 1] when they agree).
pub fn balanced_colour(lamp_kelvin: f64, balanced_kelvin: f64) -> [f64; 3] {
    let (lamp, white) = (kelvin_rgb(lamp_kelvin), kelvin_rgb(balanced_kelvin));
    std::array::from_fn(|c| lamp[c] / white[c])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A point at height `z` on the axis, seen from straight above.
    fn at(z: f64, normal: Vector3<f64>) -> SurfacePoint {
        SurfacePoint {
            point: Point3::new(0.0, 0.0, z),
            normal,
            to_eye: Vector3::z(),
        }
    }

    #[test]
    fn warm_light_is_red_and_cold_light_is_blue() {
        let d65 = kelvin_rgb(6504.0);
        // D65 is sRGB's white: near-equal channels.
        assert!(d65.iter().all(|&c| (c - 1.0).abs() < 0.06), "{d65:?}");
        let tungsten = kelvin_rgb(2856.0);
        assert!(tungsten[0] > 1.4 && tungsten[2] < 0.5, "{tungsten:?}");
        let shade = kelvin_rgb(10000.0);
        assert!(shade[2] > shade[0], "{shade:?}");
        assert_eq!(balanced_colour(3200.0, 3200.0), [1.0; 3]);
    }

    #[test]
    fn the_ideal_light_is_ambient_plus_lambert() {
        let light = Lighting::ideal(Vector3::z());
        let lit = |_: usize, _: &Vector3<f64>, _: f64| true;
        let facing = light.shade([1.0; 3], 1.0, &at(0.0, Vector3::z()), true, lit);
        assert_eq!(facing, [1.0; 3]);
        let sideways = light.shade([0.5; 3], 1.0, &at(0.0, Vector3::x()), true, lit);
        assert_eq!(sideways, [0.175; 3]);
    }

    #[test]
    fn highlights_shadows_and_falloff() {
        let mut light = Lighting::ideal(Vector3::z());
        light.lamps[0].source = LampSource::At {
            position: Point3::new(0.0, 0.0, 100.0),
            reference_mm: 100.0,
        };
        light.specular = 0.5;
        light.shadows = true;
        let up = Vector3::z();
        let open = |_: usize, _: &Vector3<f64>, _: f64| true;
        // The mirror direction: the full highlight on top of the diffuse.
        let c = light.shade([0.5; 3], 1.0, &at(0.0, up), true, open);
        assert!((c[0] - 1.0).abs() < 1e-6, "{c:?}");
        // Twice as far: a quarter of the lamp's light.
        let d = light.shade([1.0; 3], 1.0, &at(-100.0, up), false, open);
        assert!((d[0] - (0.35 + 0.65 * 0.25)).abs() < 1e-6, "{d:?}");
        let shadowed = light.shade([1.0; 3], 1.0, &at(0.0, up), true, |_, _, _| false);
        assert!((shadowed[0] - 0.35).abs() < 1e-6, "{shadowed:?}");
    }
}
