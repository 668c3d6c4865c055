//! Acquisition conditions of the camera session: how far it is from the
//! ideal phantom. Tissue that moved since the scan, the light, the lens and
//! the sensor, the skin's texture. Declared once here and flattened into
//! `phantom.generate`; every default reproduces the ideal phantom byte for
//! byte, and a preset (`conditions = "lab"` or `"hard"`) fills every
//! parameter left at its default.

use super::defocus::Lens;
use super::lighting::{Lamp, LampSource, Lighting, balanced_colour};
use super::motion::MotionKind;
use super::rig::PIXEL_MM;
use super::sensor::SensorParams;
use super::shape::Triples;
use crate::camera::CameraModel;
use fusegraph_engine::typed::declared_defaults;
use fusegraph_plugin_api::derive::{Choice, Params};
use nalgebra::{Point3, Vector3};
use std::collections::BTreeMap;

/// The smallest f-number a lens may have (0 aside: a pinhole).
const MIN_F_NUMBER: f64 = 0.5;

/// Named sets of conditions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Choice)]
pub enum ConditionsPreset {
    /// The ideal phantom: still tissue, one distant white lamp, matte skin,
    /// a pinhole lens, lossless PNG, a richly textured skin.
    Ideal,
    /// What a careful lab gets: two lamps, mild highlights and shadows,
    /// auto white balance slightly off, f/8 focused at 500 mm, realistic
    /// noise, a Bayer sensor, JPEG 90, a less textured skin; no motion.
    Lab,
    /// Every condition but motion at a demanding level: one low tungsten
    /// lamp, white balance set for daylight, glossy skin, f/4 focused at
    /// 450 mm, more noise, half a stop over-exposed, strong vignetting,
    /// JPEG 70, a nearly uniform skin, green distractors on the table and a
    /// tool over the dome.
    Hard,
}

/// The conditions of the camera session (the MRI is always as scanned).
#[derive(Debug, Clone, PartialEq, Params)]
pub struct Conditions {
    /// A preset filling every condition left at its default: ideal (today's
    /// phantom), lab or hard
    #[param(default = ConditionsPreset::Ideal)]
    pub conditions: ConditionsPreset,
    /// How the tissue moved between the MRI and the camera session: none,
    /// sag (gravity), compression (a plate from above), squeeze (two
    /// paddles across motion_direction_deg) or shift (lateral)
    #[param(default = MotionKind::None)]
    pub motion: MotionKind,
    /// Largest displacement of the tissue over the dome (0 = none); zero on
    /// the table
    #[param(default = 0.0, unit = "mm", min = 0.0, max = 30.0)]
    pub motion_peak_mm: f64,
    /// Horizontal direction of the motion, phantom frame, from +x
    #[param(default = 0.0, unit = "deg", min = -360.0, max = 360.0)]
    pub motion_direction_deg: f64,
    /// Lamp positions, world frame, flattened x, y, z triples (empty: one
    /// distant lamp from (0.45, -0.35, 0.82), the ideal phantom's)
    #[param(default = Triples(Vec::new()), unit = "mm", length_multiple_of = 3)]
    pub lamp_positions_mm: Triples,
    /// Each lamp's irradiance at the phantom relative to the ideal lamp's:
    /// none (all 1), one for all, or one per lamp
    #[param(default = Vec::<f64>::new())]
    pub lamp_intensities: Vec<f64>,
    /// Each lamp's colour temperature: none (all 6500 K), one for all, or
    /// one per lamp
    #[param(default = Vec::<f64>::new(), unit = "K")]
    pub lamp_kelvin: Vec<f64>,
    /// Fraction of the light that is ambient
    #[param(default = 0.35, min = 0.0, max = 1.0)]
    pub ambient: f64,
    /// Colour temperature the camera's white balance is set for (lamps of
    /// another temperature tint the images)
    #[param(default = 6500.0, unit = "K", min = 1667.0, max = 25000.0)]
    pub white_balance_kelvin: f64,
    /// Blinn-Phong highlight strength on skin and markers (0 = matte)
    #[param(default = 0.0, min = 0.0, max = 2.0)]
    pub specular: f64,
    /// Blinn-Phong exponent (larger: smaller, sharper highlights)
    #[param(default = 40.0, min = 1.0, max = 1000.0)]
    pub shininess: f64,
    /// Cast shadows of the dome and the markers
    #[param(default = false)]
    pub shadows: bool,
    /// Lens f-number (0 = a pinhole: everything in focus; else 0.5 or more); defocus follows
    /// the thin-lens blur circle
    #[param(default = 0.0, min = 0.0, max = 64.0)]
    pub f_number: f64,
    /// Distance the lens is focused at, along its axis
    #[param(default = 500.0, unit = "mm", min = 50.0, max = 10000.0)]
    pub focus_mm: f64,
    /// Exposure relative to a correct one (+1: twice the light; clips at
    /// saturation)
    #[param(default = 0.0, unit = "stops", min = -5.0, max = 5.0)]
    pub exposure_stops: f64,
    /// Read noise standard deviation, 8-bit levels
    #[param(default = 1.5, unit = "DN", min = 0.0, max = 50.0)]
    pub read_noise_dn: f64,
    /// Electrons at saturation, for shot noise (0 = none)
    #[param(default = 0.0, unit = "e", min = 0.0, max = 1000000.0)]
    pub full_well_e: f64,
    /// Strength of the lens's cos^4 vignetting (0 = none, 1 = natural)
    #[param(default = 1.0, min = 0.0, max = 4.0)]
    pub vignetting: f64,
    /// Record colour through an RGGB Bayer mosaic, demosaiced bilinearly
    #[param(default = false)]
    pub bayer: bool,
    /// Write the photos as JPEG at this quality (1-100); 0 = lossless PNG
    #[param(default = 0, min = 0, max = 100)]
    pub jpeg_quality: u8,
    /// Peak-to-peak contrast of the skin's fine texture, in % of its mean
    /// albedo (60 = the ideal phantom's; 0 = uniform skin)
    #[param(default = 60.0, unit = "%", min = 0.0, max = 100.0)]
    pub skin_texture_pct: f64,
    /// Green things on the table off the phantom: a sticker of a marker's
    /// size, a strip of tape, a cup
    #[param(default = false)]
    pub distractors: bool,
    /// A grey tool held 12 mm over the dome, hiding part of it (and maybe a
    /// marker) from the views that look past it
    #[param(default = false)]
    pub occluder: bool,
}

impl Default for Conditions {
    /// The ideal phantom: every condition at its declared default.
    fn default() -> Self {
        declared_defaults().expect("every condition has a default")
    }
}

/// Calls macro `$m` with the field name of every condition but the preset.
macro_rules! every_condition {
    ($m:ident) => {
        $m!(
            motion,
            motion_peak_mm,
            motion_direction_deg,
            lamp_positions_mm,
            lamp_intensities,
            lamp_kelvin,
            ambient,
            white_balance_kelvin,
            specular,
            shininess,
            shadows,
            f_number,
            focus_mm,
            exposure_stops,
            read_noise_dn,
            full_well_e,
            vignetting,
            bayer,
            jpeg_quality,
            skin_texture_pct,
            distractors,
            occluder,
        )
    };
}

/// Direction towards the ideal phantom's one distant lamp, world frame.
const IDEAL_LAMP: [f64; 3] = [0.45, -0.35, 0.82];

impl Conditions {
    /// The preset's values.
    pub fn preset(preset: ConditionsPreset) -> Self {
        let ideal = Conditions::default();
        match preset {
            ConditionsPreset::Ideal => ideal,
            ConditionsPreset::Lab => Conditions {
                conditions: preset,
                // Key lamp where the ideal one shines from, 700 mm off; a
                // fill lamp at half its strength from the other side.
                lamp_positions_mm: Triples(vec![[330.0, -255.0, 600.0], [-405.0, 200.0, 550.0]]),
                lamp_intensities: vec![1.0, 0.5],
                lamp_kelvin: vec![4000.0, 5000.0],
                ambient: 0.25,
                white_balance_kelvin: 4300.0,
                specular: 0.15,
                shininess: 30.0,
                shadows: true,
                f_number: 8.0,
                focus_mm: 500.0,
                read_noise_dn: 2.0,
                full_well_e: 12000.0,
                bayer: true,
                jpeg_quality: 90,
                skin_texture_pct: 30.0,
                ..ideal
            },
            ConditionsPreset::Hard => Conditions {
                conditions: preset,
                lamp_positions_mm: Triples(vec![[480.0, 120.0, 260.0]]),
                lamp_intensities: vec![1.2],
                lamp_kelvin: vec![3200.0],
                ambient: 0.2,
                white_balance_kelvin: 5500.0,
                specular: 0.4,
                shininess: 20.0,
                shadows: true,
                f_number: 4.0,
                focus_mm: 450.0,
                exposure_stops: 0.5,
                read_noise_dn: 3.0,
                full_well_e: 5000.0,
                vignetting: 1.5,
                bayer: true,
                jpeg_quality: 70,
                skin_texture_pct: 10.0,
                distractors: true,
                occluder: true,
                ..ideal
            },
        }
    }

    /// The conditions in force: each parameter left at its declared default
    /// takes the preset's value, the others stay as set.
    pub fn resolved(&self) -> Conditions {
        let ideal = Conditions::default();
        let preset = Conditions::preset(self.conditions);
        macro_rules! pick {
            ($($field:ident),* $(,)?) => {
                Conditions {
                    conditions: self.conditions,
                    $($field: if self.$field == ideal.$field {
                        preset.$field.clone()
                    } else {
                        self.$field.clone()
                    },)*
                }
            };
        }
        every_condition!(pick)
    }

    /// Every condition by its parameter name (with its unit), for the ground
    /// truth; `None` for the ideal phantom, whose truth file stays as it was.
    pub fn record(&self) -> Option<BTreeMap<String, serde_json::Value>> {
        if *self == Conditions::default() {
            return None;
        }
        macro_rules! record {
            ($($field:ident),* $(,)?) => {
                BTreeMap::from([$((stringify!($field).to_string(), serde_json::json!(self.$field)),)*])
            };
        }
        let mut r = every_condition!(record);
        r.insert("conditions".into(), self.conditions.name().into());
        Some(r)
    }

    /// Problems with the lamp lists, by parameter name.
    pub fn problems(&self) -> Vec<(&'static str, String)> {
        let lamps = self.lamp_count();
        let mut problems = Vec::new();
        for (name, list) in [
            ("lamp_intensities", &self.lamp_intensities),
            ("lamp_kelvin", &self.lamp_kelvin),
        ] {
            if list.len() > 1 && list.len() != lamps {
                problems.push((
                    name,
                    format!(
                        "{} values for {lamps} lamp(s): give none, one for all, or one per lamp",
                        list.len()
                    ),
                ));
            }
        }
        if self.lamp_intensities.iter().any(|&i| i.is_nan() || i < 0.0) {
            problems.push(("lamp_intensities", "intensities are >= 0".into()));
        }
        if let Some(k) = self
            .lamp_kelvin
            .iter()
            .find(|&&k| !(1667.0..=25000.0).contains(&k))
        {
            problems.push(("lamp_kelvin", format!("{k} K is outside 1667..=25000 K")));
        }
        // A tiny f-number is an aperture metres wide: blur circles of
        // thousands of pixels, which would take the renderer minutes.
        if self.f_number > 0.0 && self.f_number < MIN_F_NUMBER {
            problems.push((
                "f_number",
                format!(
                    "f/{} is wider than any lens (f-numbers start near 0.7): give {MIN_F_NUMBER} \
                     or more, or 0 for a pinhole",
                    self.f_number
                ),
            ));
        }
        problems
    }

    fn lamp_count(&self) -> usize {
        self.lamp_positions_mm.0.len().max(1)
    }

    /// The lighting of the phantom views; `phantom_centre` (world, mm) is
    /// where a lamp at a position gives its stated intensity.
    pub fn lighting(&self, phantom_centre: &Point3<f64>) -> Lighting {
        let per_lamp = |list: &[f64], i: usize, default: f64| match list.len() {
            0 => default,
            1 => list[0],
            _ => list[i],
        };
        let lamps: Vec<Lamp> = (0..self.lamp_count())
            .map(|i| {
                let source = match self.lamp_positions_mm.0.get(i) {
                    None => LampSource::Distant(Vector3::from(IDEAL_LAMP).normalize()),
                    Some(&p) => LampSource::At {
                        position: Point3::from(p),
                        reference_mm: (Point3::from(p) - phantom_centre).norm(),
                    },
                };
                Lamp {
                    source,
                    intensity: per_lamp(&self.lamp_intensities, i, 1.0),
                    colour: balanced_colour(
                        per_lamp(&self.lamp_kelvin, i, 6500.0),
                        self.white_balance_kelvin,
                    ),
                }
            })
            .collect();
        // Ambient light is the lamps' light off the room: their mean colour.
        let total: f64 = lamps.iter().map(|l| l.intensity).sum();
        let ambient_colour = std::array::from_fn(|c| {
            if total > 0.0 {
                lamps.iter().map(|l| l.intensity * l.colour[c]).sum::<f64>() / total
            } else {
                1.0
            }
        });
        Lighting {
            lamps,
            ambient: self.ambient,
            ambient_colour,
            specular: self.specular,
            shininess: self.shininess,
            shadows: self.shadows,
        }
    }

    /// The lens of `camera` (pixel pitch [`PIXEL_MM`]); `None` for a pinhole.
    pub fn lens(&self, camera: &CameraModel) -> Option<Lens> {
        (self.f_number > 0.0).then_some(Lens {
            focal_mm: camera.fx * PIXEL_MM,
            f_number: self.f_number,
            focus_mm: self.focus_mm,
            pixel_mm: PIXEL_MM,
        })
    }

    /// The sensor, its noise seeded by `seed`.
    pub fn sensor(&self, seed: u64) -> SensorParams {
        SensorParams {
            read_noise: self.read_noise_dn / 255.0,
            full_well_e: self.full_well_e,
            exposure_gain: 2f64.powf(self.exposure_stops),
            vignetting: self.vignetting,
            bayer: self.bayer,
            seed,
        }
    }

    /// The skin texture's contrast as a fraction.
    pub fn skin_texture(&self) -> f64 {
        self.skin_texture_pct / 100.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_fill_what_is_left_at_its_default() {
        let mut c = Conditions {
            conditions: ConditionsPreset::Lab,
            ..Conditions::default()
        };
        c.jpeg_quality = 50;
        let r = c.resolved();
        assert_eq!(r.jpeg_quality, 50, "set: kept");
        assert_eq!(r.f_number, 8.0, "left at the default: the preset's");
        assert_eq!(r.motion, MotionKind::None);
        assert_eq!(Conditions::default().resolved(), Conditions::default());
    }

    #[test]
    fn the_ideal_light_and_sensor_are_the_old_ones() {
        let c = Conditions::default();
        let light = c.lighting(&Point3::origin());
        assert_eq!(
            light,
            Lighting::ideal(Vector3::from(IDEAL_LAMP).normalize())
        );
        let sensor = c.sensor(7);
        assert_eq!(sensor, SensorParams::ideal(1.5 / 255.0, 7));
        assert!(c.lens(&super::super::Rig::paper_rig().left).is_none());
        assert_eq!(c.skin_texture(), 0.6);
        assert!(c.problems().is_empty());
    }

    #[test]
    fn lamp_lists_must_fit_the_lamps() {
        let mut c = Conditions {
            lamp_positions_mm: Triples(vec![[0.0, 0.0, 500.0], [100.0, 0.0, 500.0]]),
            lamp_kelvin: vec![3000.0, 4000.0, 5000.0],
            lamp_intensities: vec![-1.0],
            ..Default::default()
        };
        let names: Vec<_> = c.problems().into_iter().map(|p| p.0).collect();
        assert_eq!(names, ["lamp_kelvin", "lamp_intensities"]);
        c.lamp_kelvin = vec![3000.0];
        c.lamp_intensities = vec![1.0, 0.5];
        assert!(c.problems().is_empty());
        // An aperture metres wide is refused; a pinhole (0) and f/0.5 are not.
        for (f, refused) in [(0.001, true), (0.49, true), (0.0, false), (0.5, false)] {
            c.f_number = f;
            let names: Vec<_> = c.problems().into_iter().map(|p| p.0).collect();
            assert_eq!(names == ["f_number"], refused, "f/{f}: {names:?}");
        }
        let light = c.lighting(&Point3::new(0.0, 0.0, 0.0));
        assert_eq!(light.lamps.len(), 2);
        assert_eq!(light.lamps[1].intensity, 0.5);
    }
}
