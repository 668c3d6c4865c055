//! What the simulated cameras look at: a printed chessboard in front of a
//! cluttered wall (calibration), and the phantom on a cloth-covered table
//! under its [`Lighting`] (phantom views).

use super::lighting::{Lighting, SurfacePoint};
use super::moved_shape::MovedShape;
use super::props::{Prop, first_prop};
use super::render::{Scene, Seen};
use super::shape::Surface;
use super::texture::{ValueNoise, fast_floor};
use nalgebra::{Isometry3, Matrix3, Point3, Vector3};
use std::cell::Cell;

/// A chessboard of `cols x rows` inner corners (OpenCV's pattern size), squares
/// `square_mm` across, white border `margin_mm` wide. Board frame: x along the
/// columns, y along the rows, origin at the first inner corner, z into the board.
#[derive(Debug, Clone)]
pub struct Chessboard {
    /// Inner corners per row.
    pub cols: usize,
    /// Inner corners per column.
    pub rows: usize,
    /// Square size, mm.
    pub square_mm: f64,
    /// White border around the squares, mm.
    pub margin_mm: f64,
}

impl Chessboard {
    /// Inner corner positions in the board frame, row by row (mm).
    pub fn corners(&self) -> Vec<Point3<f64>> {
        (0..self.rows)
            .flat_map(|r| (0..self.cols).map(move |c| (c, r)))
            .map(|(c, r)| Point3::new(c as f64 * self.square_mm, r as f64 * self.square_mm, 0.0))
            .collect()
    }

    /// Board reflectance at board coordinates (x, y) mm, or `None` off the board.
    fn albedo(&self, x: f64, y: f64) -> Option<f32> {
        let s = self.square_mm;
        let (x0, y0) = (-s - self.margin_mm, -s - self.margin_mm);
        let (x1, y1) = (
            self.cols as f64 * s + self.margin_mm,
            self.rows as f64 * s + self.margin_mm,
        );
        if x < x0 || y < y0 || x > x1 || y > y1 {
            return None;
        }
        let (ix, iy) = (fast_floor(x / s), fast_floor(y / s));
        let in_squares = ix >= -1 && iy >= -1 && ix < self.cols as i64 && iy < self.rows as i64;
        let black = in_squares && (ix + iy).rem_euclid(2) == 0;
        Some(if black { 0.07 } else { 0.82 })
    }
}

/// A chessboard at `board_to_world`, lit unevenly, before a cluttered wall.
pub struct ChessboardScene {
    board: Chessboard,
    world_to_board: (Matrix3<f64>, Vector3<f64>),
    seed: u64,
}

impl ChessboardScene {
    /// The board placed at `board_to_world` (the world here is the left camera's
    /// frame); `seed` varies the wall's clutter.
    pub fn new(board: Chessboard, board_to_world: &Isometry3<f64>, seed: u64) -> Self {
        let inv = board_to_world.inverse();
        ChessboardScene {
            board,
            world_to_board: (
                inv.rotation.to_rotation_matrix().into_inner(),
                inv.translation.vector,
            ),
            seed,
        }
    }
}

impl Scene for ChessboardScene {
    fn radiance_at(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> ([f32; 3], f64) {
        let (r, t) = &self.world_to_board;
        let (o, d) = (r * origin.coords + t, r * dir);
        if d.z.abs() > 1e-12 {
            let t = -o.z / d.z;
            if t > 0.0 {
                let p = o + d * t;
                if let Some(a) = self.board.albedo(p.x, p.y) {
                    // Light falling off across the board (uneven lighting).
                    let light = 0.8
                        + 0.2
                            * (p.x / (self.board.cols as f64 * self.board.square_mm))
                                .clamp(0.0, 1.0);
                    let v = a * light as f32;
                    return ([v, v, v * 0.97], t);
                }
            }
        }
        // A wall 1.6 m away with blotchy clutter.
        let t = (1600.0 - origin.z) / dir.z.max(1e-3);
        let p = origin + dir * t;
        let noise = ValueNoise::new(self.seed);
        let v = 0.3 + 0.35 * noise.at(&p, 1.0 / 40.0) as f32;
        ([v * 0.95, v, v * 1.05], t)
    }
}

/// The phantom on a table (world plane z = 0) under `lighting`.
pub struct PhantomScene {
    /// The phantom as scanned, moved as the camera session sees it
    /// (textures move with the tissue).
    pub body: MovedShape,
    /// Pose of the phantom frame in the world (base on z = 0).
    pub phantom_to_world: Isometry3<f64>,
    /// The lamps, ambient light, highlights and shadows.
    pub lighting: Lighting,
    /// Peak-to-peak contrast of the skin's fine texture, as a fraction of
    /// its mean brightness (0.6 for the ideal phantom, 0 for a uniform skin).
    pub skin_texture: f64,
    /// Things beside the phantom (world frame).
    pub props: Vec<Prop>,
    /// Seed of the skin and cloth textures.
    pub seed: u64,
}

/// Skin base colour (linear RGB).
const SKIN: [f32; 3] = [0.92, 0.72, 0.62];
/// Marker face colour: a saturated green, far in hue from skin and cloth.
pub const MARKER_GREEN: [f32; 3] = [0.10, 0.72, 0.20];
const PLASTIC: [f32; 3] = [0.80, 0.80, 0.78];
const CLOTH: [f32; 3] = [0.22, 0.25, 0.32];

impl PhantomScene {
    /// Whether the lamp along unit `l` (world), `distance` mm away, lights
    /// world point `p`: nothing of the phantom lies between (the table
    /// casts no shadow).
    fn lit(&self, p: &Point3<f64>, l: &Vector3<f64>, distance: f64) -> bool {
        let (o, d) = (
            self.phantom_to_world.inverse_transform_point(p),
            self.phantom_to_world.inverse_transform_vector(l),
        );
        // Started a hair off the surface, so it does not find itself.
        self.body
            .intersect(&(o + d * 1e-3), &d, 0.0)
            .is_none_or(|h| h.t >= distance)
            && first_prop(&self.props, &(p + l * 1e-3), l, 0.0).is_none_or(|h| h.1 >= distance)
    }

    /// Light leaving a surface point; the lamps that reach it are found by
    /// shadow rays, or taken from `known` (bit i: lamp i), and recorded in
    /// `reached`.
    fn shade(
        &self,
        albedo: [f32; 3],
        texture: f64,
        (point, normal, dir): (Point3<f64>, Vector3<f64>, &Vector3<f64>),
        glossy: bool,
        (known, reached): (Option<u32>, &Cell<u32>),
    ) -> [f32; 3] {
        let at = SurfacePoint {
            point,
            normal,
            to_eye: -dir,
        };
        self.lighting
            .shade(albedo, texture, &at, glossy, |lamp, l, distance| {
                let lit = match known {
                    Some(mask) => mask & (1 << lamp) != 0,
                    None => self.lit(&point, l, distance),
                };
                if lit {
                    reached.set(reached.get() | 1 << lamp);
                }
                lit
            })
    }

    /// What the ray from `origin` along unit `dir` (world frame) meets
    /// first. `near` is what the rays around it saw, when they all met the
    /// skin, or all the table, lit by the same lamps: then no shadow rays
    /// are cast, the moved body is searched only near the skin's span of
    /// distances, and the table is taken as met.
    fn look(&self, origin: &Point3<f64>, dir: &Vector3<f64>, near: Option<Near>) -> Seen {
        let (o, d) = (
            self.phantom_to_world.inverse_transform_point(origin),
            self.phantom_to_world.inverse_transform_vector(dir),
        );
        let table_t = if dir.z < 0.0 {
            -origin.z / dir.z
        } else {
            f64::INFINITY
        };
        let seen = |rgb, distance_mm, smooth_surface| Seen {
            rgb,
            distance_mm,
            smooth_surface,
        };
        let noise = ValueNoise::new(self.seed);
        let reached = Cell::new(0);
        let known = (near.map(|n| n.lit_lamps), &reached);
        let cast = (None, &reached);
        let on_table = |lamps| {
            let p = origin + dir * table_t;
            let t = noise.fractal(&p, 1.0 / 3.0, 2);
            let rgb = self.shade(CLOTH, 0.6 + 0.5 * t, (p, Vector3::z(), dir), false, lamps);
            seen(rgb, table_t, self.key(Kind::Table, reached.get()))
        };
        let body = match near {
            Some(Near {
                kind: Kind::Table, ..
            }) if table_t.is_finite() => return on_table(known),
            Some(Near {
                kind: Kind::Skin,
                span_mm,
                ..
            }) => self.body.intersect_near(&o, &d, 1e-6, span_mm),
            _ => self.body.intersect(&o, &d, 1e-6),
        }
        .filter(|h| h.t < table_t);
        if let Some((i, t, normal)) = first_prop(&self.props, origin, dir, 1e-6)
            .filter(|h| h.1 < table_t && body.is_none_or(|b| h.1 < b.t))
        {
            let prop = &self.props[i];
            let at = (origin + dir * t, normal, dir);
            return seen(self.shade(prop.colour, 1.0, at, prop.glossy, cast), t, None);
        }
        if let Some(hit) = body {
            let p = hit.scanned;
            let normal = self.phantom_to_world * hit.normal;
            let at = (origin + dir * hit.t, normal, dir);
            let rgb = match hit.surface {
                Surface::Skin => {
                    // Fine random texture: 0.5 mm to 2 mm features, its
                    // contrast as asked (0.55 + 0.6 t for the ideal phantom).
                    let t = noise.fractal(&p, 1.0 / 1.6, 3);
                    let k = self.skin_texture;
                    let rgb = self.shade(SKIN, 0.55 + (0.6 - k) / 2.0 + k * t, at, true, known);
                    return seen(rgb, hit.t, self.key(Kind::Skin, reached.get()));
                }
                Surface::MarkerFace(_) => self.shade(MARKER_GREEN, 1.0, at, true, cast),
                Surface::MarkerSide => self.shade(PLASTIC, 1.0, at, true, cast),
            };
            return seen(rgb, hit.t, None);
        }
        if table_t.is_finite() {
            return on_table(cast);
        }
        seen([0.05, 0.05, 0.06], f64::INFINITY, None)
    }

    /// The key of [`Seen::smooth_surface`]: the kind of surface and the bit
    /// mask of the lamps that reach the point (none where more lamps than
    /// the key holds).
    fn key(&self, kind: Kind, lit_lamps: u32) -> Option<u32> {
        (self.lighting.lamps.len() <= KEYED_LAMPS)
            .then_some(lit_lamps | (kind as u32) << KEYED_LAMPS)
    }
}

/// The lamps a key can tell apart.
const KEYED_LAMPS: usize = 24;

/// The smooth surfaces a ray can be searched near.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Skin = 0,
    Table = 1,
}

/// What the rays around a ray saw: one kind of surface, lit by the lamps of
/// bit mask `lit_lamps`, at distances within `span_mm` (mm).
#[derive(Debug, Clone, Copy)]
struct Near {
    kind: Kind,
    span_mm: (f64, f64),
    lit_lamps: u32,
}

impl Scene for PhantomScene {
    fn radiance_at(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> ([f32; 3], f64) {
        let seen = self.look(origin, dir, None);
        (seen.rgb, seen.distance_mm)
    }

    fn seen(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Seen {
        self.look(origin, dir, None)
    }

    /// `surface` is a key [`PhantomScene::key`] made.
    fn radiance_near(
        &self,
        origin: &Point3<f64>,
        dir: &Vector3<f64>,
        surface: u32,
        span_mm: (f64, f64),
    ) -> [f32; 3] {
        let kind = match surface >> KEYED_LAMPS {
            0 => Kind::Skin,
            1 => Kind::Table,
            _ => return self.radiance(origin, dir),
        };
        let near = Near {
            kind,
            span_mm,
            lit_lamps: surface & ((1 << KEYED_LAMPS) - 1),
        };
        self.look(origin, dir, Some(near)).rgb
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::CameraModel;
    use crate::camera::look_at;
    use crate::phantom::lighting::{Lamp, LampSource};
    use crate::phantom::motion::{MotionField, MotionKind};
    use crate::phantom::render::{RenderParams, Renderer, TextureSamples};
    use crate::phantom::sensor::SensorParams;
    use crate::phantom::{PhantomShape, ShapeParams};
    use rand::SeedableRng;

    /// A scene seen only through `radiance_at`: no surface keys, so the
    /// renderer casts every supersample along the whole ray.
    struct Unhinted<'a>(&'a PhantomScene);

    impl Scene for Unhinted<'_> {
        fn radiance_at(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> ([f32; 3], f64) {
            self.0.radiance_at(origin, dir)
        }
    }

    #[test]
    fn supersamples_searched_near_their_neighbours_render_what_whole_rays_do() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let shape = PhantomShape::build(&ShapeParams::default(), &mut rng).unwrap();
        let field = MotionField::new(MotionKind::Sag, 10.0, 30.0, &shape);
        let mut lighting = Lighting::ideal(Vector3::new(0.45, -0.35, 0.82).normalize());
        lighting.lamps.push(Lamp {
            source: LampSource::At {
                position: Point3::new(-300.0, 200.0, 400.0),
                reference_mm: 500.0,
            },
            intensity: 0.5,
            colour: [1.0, 0.9, 0.8],
        });
        lighting.shadows = true;
        lighting.specular = 0.3;
        let scene = PhantomScene {
            body: MovedShape::new(shape, field),
            phantom_to_world: Isometry3::identity(),
            lighting,
            skin_texture: 0.6,
            props: Vec::new(),
            seed: 4,
        };
        let camera = CameraModel {
            width: 200,
            height: 150,
            fx: 420.0,
            fy: 420.0,
            cx: 99.5,
            cy: 74.5,
            distortion: [-0.1, 0.05, 0.0, 0.0, 0.0],
        };
        let pose = look_at(
            &Point3::new(90.0, -280.0, 260.0),
            &Point3::new(0.0, 0.0, 25.0),
            &Vector3::z(),
        );
        let mut sensor = SensorParams::ideal(0.0, 1);
        sensor.vignetting = 0.0;
        let params = RenderParams {
            supersample: 5,
            texture: TextureSamples::Grid(5),
            blur_sigma_px: 0.0,
            lens: None,
            sensor,
        };
        let renderer = Renderer::new(&camera);
        let hinted = renderer.render(&pose, &scene, &params);
        let whole = renderer.render(&pose, &Unhinted(&scene), &params);
        let diffs: Vec<u8> = hinted
            .iter()
            .zip(&whole)
            .map(|(a, b)| a.abs_diff(*b))
            .collect();
        let changed = diffs.iter().filter(|&&d| d > 0).count();
        let worst = diffs.iter().copied().max().unwrap();
        // Hits a few um apart: at most a grey level of rounding, rarely.
        assert!(worst <= 1, "worst difference {worst} grey levels");
        assert!(
            changed * 200 < diffs.len(),
            "{changed} of {} values differ",
            diffs.len()
        );
    }

    #[test]
    fn board_colours_alternate_from_a_black_first_square() {
        let b = Chessboard {
            cols: 9,
            rows: 6,
            square_mm: 25.0,
            margin_mm: 20.0,
        };
        assert_eq!(b.corners().len(), 54);
        assert_eq!(b.corners()[10], Point3::new(25.0, 25.0, 0.0));
        assert_eq!(b.albedo(-12.0, -12.0), Some(0.07));
        assert_eq!(b.albedo(12.0, -12.0), Some(0.82));
        assert_eq!(b.albedo(12.0, 12.0), Some(0.07));
        // 10 x 7 squares: the last square (9, 6) is white, unlike the first, so
        // the board has no 180-degree symmetry.
        assert_eq!(b.albedo(9.0 * 25.0 - 12.0, 6.0 * 25.0 - 12.0), Some(0.82));
        assert_eq!(b.albedo(-30.0, 0.0), Some(0.82), "margin");
        assert_eq!(b.albedo(-50.0, 0.0), None);
    }
}
