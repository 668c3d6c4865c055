//! What the simulated cameras look at: a printed chessboard in front of a
//! cluttered wall (calibration), and the phantom on a cloth-covered table
//! under its [`Lighting`] (phantom views).

use super::board_rays::{
    BLACK_ALBEDO, BoardPattern, BoardSample, WHITE_ALBEDO, board_grey_rgb, board_light, board_row,
};
use super::footprint::{Polygon, pieces};
use super::lighting::{Lighting, SurfacePoint};
use super::moved_shape::MovedShape;
use super::props::{Prop, first_prop};
use super::render::{Scene, Seen};
use super::shape::{RaysFrom, Surface};
use super::texture::{RecentCell, ValueNoise};
use crate::numeric::floor_i64;
use nalgebra::{Isometry3, Matrix3, Point3, Vector3};
use std::cell::{Cell, RefCell};

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

    /// The board's outer edge in board coordinates: [x0, y0, x1, y1], mm.
    fn extent(&self) -> [f64; 4] {
        let s = self.square_mm;
        [
            -s - self.margin_mm,
            -s - self.margin_mm,
            self.cols as f64 * s + self.margin_mm,
            self.rows as f64 * s + self.margin_mm,
        ]
    }

    /// Board reflectance at board coordinates (x, y) mm, or `None` off the board.
    fn albedo(&self, x: f64, y: f64) -> Option<f32> {
        let s = self.square_mm;
        let [x0, y0, x1, y1] = self.extent();
        if x < x0 || y < y0 || x > x1 || y > y1 {
            return None;
        }
        let (ix, iy) = (floor_i64(x / s), floor_i64(y / s));
        let in_squares = ix >= -1 && iy >= -1 && ix < self.cols as i64 && iy < self.rows as i64;
        let black = in_squares && (ix + iy).rem_euclid(2) == 0;
        Some(if black { BLACK_ALBEDO } else { WHITE_ALBEDO })
    }
}

/// The most lines of squares a pixel's footprint is cut along, per axis,
/// before [`ChessboardScene::pixel_mean`] leaves the pixel to supersampling.
const MAX_FOOTPRINT_CUTS: i64 = 64;

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

impl ChessboardScene {
    /// The board seen at board point x (mm along the columns) where its
    /// reflectance is `albedo`: the light falls off across the board
    /// (uneven lighting), linearly between its first and last columns.
    fn board_rgb(&self, albedo: f32, x: f64) -> [f32; 3] {
        let light = board_light(x, self.board.cols as f64 * self.board.square_mm);
        board_grey_rgb(albedo * light as f32)
    }

    /// `origin` (world frame) in board coordinates, mm.
    fn to_board(&self, origin: &Point3<f64>) -> Vector3<f64> {
        let (r, t) = &self.world_to_board;
        r * origin.coords + t
    }

    /// Where the ray from `board_origin` (its origin in board coordinates,
    /// [`ChessboardScene::to_board`]) along `dir` (world frame) meets the
    /// board's plane, in board coordinates (mm), and how far along it, mm;
    /// `None` for a ray parallel to the plane or pointing away from it.
    fn on_board_plane(
        &self,
        board_origin: &Vector3<f64>,
        dir: &Vector3<f64>,
    ) -> Option<(Vector3<f64>, f64)> {
        let d = self.world_to_board.0 * dir;
        if d.z.abs() <= 1e-12 {
            return None;
        }
        let t = -board_origin.z / d.z;
        (t > 0.0).then(|| (board_origin + d * t, t))
    }

    /// What the ray from `origin` along `dir` sees, its origin given in
    /// board coordinates too (`board_origin`): the board, or the wall
    /// (`recent`: the clutter's last cell).
    fn board_or_wall(
        &self,
        origin: &Point3<f64>,
        board_origin: &Vector3<f64>,
        dir: &Vector3<f64>,
        recent: &mut RecentCell,
    ) -> ([f32; 3], f64) {
        if let Some((p, t)) = self.on_board_plane(board_origin, dir)
            && let Some(a) = self.board.albedo(p.x, p.y)
        {
            return (self.board_rgb(a, p.x), t);
        }
        self.wall_near(origin, dir, recent)
    }

    /// The wall 1.6 m away, with blotchy clutter, along the ray.
    fn wall(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> ([f32; 3], f64) {
        self.wall_near(origin, dir, &mut RecentCell::default())
    }

    /// [`ChessboardScene::wall`] for a ray near the last one that met it
    /// (`recent`: the clutter's last cell).
    fn wall_near(
        &self,
        origin: &Point3<f64>,
        dir: &Vector3<f64>,
        recent: &mut RecentCell,
    ) -> ([f32; 3], f64) {
        let t = (1600.0 - origin.z) / dir.z.max(1e-3);
        let p = origin + dir * t;
        let noise = ValueNoise::new(self.seed);
        let v = 0.3 + 0.35 * noise.at_near(&p, 1.0 / 40.0, recent) as f32;
        ([v * 0.95, v, v * 1.05], t)
    }
}

impl Scene for ChessboardScene {
    fn radiance_at(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> ([f32; 3], f64) {
        self.board_or_wall(
            origin,
            &self.to_board(origin),
            dir,
            &mut RecentCell::default(),
        )
    }

    /// The origin goes to board coordinates once for all the rays, the
    /// board is met in a loop that vectorises ([`board_row`]), and the
    /// wall's clutter is hashed once a cell along the row.
    fn seen_all(
        &self,
        origin: &Point3<f64>,
        dirs: &[Vector3<f64>],
        rgb: &mut [[f32; 3]],
        hits: &mut [(f64, Option<u32>)],
    ) {
        let board_origin = self.to_board(origin);
        let pattern = BoardPattern {
            square_mm: self.board.square_mm,
            extent_mm: self.board.extent(),
            cols: self.board.cols,
            rows: self.board.rows,
        };
        let samples = board_row(&self.world_to_board.0, &board_origin, dirs, &pattern);
        let mut recent = RecentCell::default();
        // Each arm stores its own answer: a colour built on the stack in
        // one arm and copied out after the match was read back with wider
        // loads than its stores (a store-forwarding stall a pixel).
        for (((dir, sample), rgb), hit) in dirs.iter().zip(samples).zip(rgb).zip(hits) {
            let mut store = |(seen, distance_mm): ([f32; 3], f64)| {
                *rgb = seen;
                *hit = (distance_mm, None);
            };
            match sample {
                BoardSample::Board { distance_mm, grey } => {
                    store((board_grey_rgb(grey), distance_mm))
                }
                BoardSample::Off => store(self.wall_near(origin, dir, &mut recent)),
                BoardSample::Undecided => {
                    store(self.board_or_wall(origin, &board_origin, dir, &mut recent))
                }
            }
        }
    }

    /// The pixel's footprint on the board's plane, cut along the squares'
    /// edges and the board's outer edge: each piece's area times the board
    /// at its centroid (exact: the reflectance is constant on a piece and
    /// the light linear), the pieces off the board the wall at the pixel's
    /// centre (the clutter varies over 40 mm, not within a pixel). The
    /// footprint's sides are straight between the corner rays: lens
    /// distortion bends them by about 1e-4 px within a pixel.
    fn pixel_mean(
        &self,
        origin: &Point3<f64>,
        corners: &[Vector3<f64>; 4],
        centre: &Vector3<f64>,
    ) -> Option<[f32; 3]> {
        let board_origin = self.to_board(origin);
        let quad = Polygon(
            corners
                .iter()
                .map(|dir| {
                    self.on_board_plane(&board_origin, dir)
                        .map(|(p, _)| [p.x, p.y])
                })
                .collect::<Option<_>>()?,
        );
        let s = self.board.square_mm;
        let [x0, y0, x1, y1] = self.board.extent();
        let cuts = |axis: usize, edges: [f64; 2]| -> Option<Vec<f64>> {
            let (lo, hi) = quad.range(axis);
            let (first, last) = (floor_i64(lo / s).saturating_add(1), floor_i64(hi / s));
            // A pixel's footprint crosses a few squares' edges; one at
            // grazing incidence can reach across the whole plane, and is
            // supersampled instead.
            if last.saturating_sub(first) >= MAX_FOOTPRINT_CUTS {
                return None;
            }
            let mut cuts: Vec<f64> = (first..=last).map(|k| k as f64 * s).collect();
            cuts.extend(edges.into_iter().filter(|&e| e > lo && e < hi));
            Some(cuts)
        };
        let (cuts_x, cuts_y) = (cuts(0, [x0, x1])?, cuts(1, [y0, y1])?);
        let parts = pieces(quad, &cuts_x, &cuts_y);
        let total: f64 = parts.iter().map(|p| p.0).sum();
        if !(total > 0.0 && total.is_finite()) {
            return None;
        }
        let mut wall = None;
        let mut sum = [0.0f64; 3];
        for (area, [x, y]) in parts {
            let rgb = match self.board.albedo(x, y) {
                Some(a) => self.board_rgb(a, x),
                None => *wall.get_or_insert_with(|| self.wall(origin, centre).0),
            };
            for (acc, v) in sum.iter_mut().zip(rgb) {
                *acc += area * v as f64;
            }
        }
        Some(sum.map(|v| (v / total) as f32))
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
        self.look_from(origin, dir, near, None)
    }

    /// [`PhantomScene::look`], given the body's rays from the origin
    /// (phantom frame) when the body can share them
    /// ([`MovedShape::rays_from`]).
    fn look_from(
        &self,
        origin: &Point3<f64>,
        dir: &Vector3<f64>,
        near: Option<Near>,
        rays: Option<&RaysFrom>,
    ) -> Seen {
        let (o, d) = (
            rays.map_or_else(
                || self.phantom_to_world.inverse_transform_point(origin),
                |rays| *rays.origin(),
            ),
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
            let t = with_recent_cells(|recent| noise.fractal_near(&p, 1.0 / 3.0, &mut recent[..2]));
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
            _ => match rays {
                Some(rays) => self.body.intersect_from(rays, &d, 1e-6),
                None => self.body.intersect(&o, &d, 1e-6),
            },
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
                    let t = with_recent_cells(|recent| {
                        noise.fractal_near(&p, 1.0 / 1.6, &mut recent[..3])
                    });
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

thread_local! {
    /// The skin's and the table's noise cells met last on this thread, one
    /// an octave: a row's rays (and a row's corner rays) meet one coarse
    /// cell several times running. The cells hold their noise's seed, so
    /// any scene or image may share them.
    static RECENT_CELLS: RefCell<[RecentCell; 3]> =
        const { RefCell::new([RecentCell::EMPTY, RecentCell::EMPTY, RecentCell::EMPTY]) };
}

/// `f` with this thread's [`RECENT_CELLS`].
fn with_recent_cells<T>(f: impl FnOnce(&mut [RecentCell; 3]) -> T) -> T {
    RECENT_CELLS.with_borrow_mut(f)
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

    /// The body's rays share what depends on the origin alone.
    fn seen_all(
        &self,
        origin: &Point3<f64>,
        dirs: &[Vector3<f64>],
        rgb: &mut [[f32; 3]],
        hits: &mut [(f64, Option<u32>)],
    ) {
        let rays = self
            .body
            .rays_from(&self.phantom_to_world.inverse_transform_point(origin));
        for ((dir, rgb), hit) in dirs.iter().zip(rgb).zip(hits) {
            let look = self.look_from(origin, dir, None, rays.as_ref());
            *rgb = look.rgb;
            *hit = (look.distance_mm, look.smooth_surface);
        }
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
    use crate::phantom::render::{Renderer, TextureSamples, sharp_params};
    use crate::phantom::{PhantomShape, ShapeParams};
    use rand::{Rng, SeedableRng};

    /// The calibration board 500 mm in front of a camera at the origin,
    /// turned so that its edges cross pixels at every angle.
    fn tilted_board() -> (Chessboard, Isometry3<f64>) {
        let board = Chessboard {
            cols: 9,
            rows: 6,
            square_mm: 25.0,
            margin_mm: 20.0,
        };
        let pose = Isometry3::new(
            Vector3::new(-110.0, -70.0, 500.0),
            Vector3::new(0.17, 0.44, 0.05),
        );
        (board, pose)
    }

    /// The unit ray through pixel (u, v) of a pinhole camera at the origin
    /// (f = 1333 px, principal point (400, 300)).
    fn pinhole_ray(u: f64, v: f64) -> Vector3<f64> {
        Vector3::new((u - 400.0) / 1333.0, (v - 300.0) / 1333.0, 1.0).normalize()
    }

    /// The mean of n x n rays over pixel (u, v).
    fn supersampled(scene: &ChessboardScene, u: f64, v: f64, n: usize) -> [f64; 3] {
        let mut sum = [0.0; 3];
        for i in 0..n {
            for j in 0..n {
                let at = |k: usize| (k as f64 + 0.5) / n as f64 - 0.5;
                let rgb = scene.radiance(&Point3::origin(), &pinhole_ray(u + at(i), v + at(j)));
                for (s, c) in sum.iter_mut().zip(rgb) {
                    *s += c as f64;
                }
            }
        }
        sum.map(|s| s / (n * n) as f64)
    }

    #[test]
    fn a_footprint_at_grazing_incidence_is_left_to_supersampling() {
        // The board's plane 500 mm ahead, facing the camera; the pixel's
        // corner rays nearly along it meet it hundreds of kilometres away,
        // across about 10^10 squares.
        let board = tilted_board().0;
        let scene = ChessboardScene::new(board, &Isometry3::translation(-100.0, -60.0, 500.0), 7);
        let corner = |y: f64, z: f64| Vector3::new(1.0, y, z).normalize();
        let corners = [
            corner(0.0, 1e-9),
            corner(1e-3, 1e-9),
            corner(1e-3, 2e-9),
            corner(0.0, 2e-9),
        ];
        let centre = corner(5e-4, 1.5e-9);
        assert_eq!(scene.pixel_mean(&Point3::origin(), &corners, &centre), None);
        // A pixel near the board's middle still gets its exact mean.
        let (u, v) = (400.0, 300.0);
        let near = [
            pinhole_ray(u - 0.5, v - 0.5),
            pinhole_ray(u + 0.5, v - 0.5),
            pinhole_ray(u + 0.5, v + 0.5),
            pinhole_ray(u - 0.5, v + 0.5),
        ];
        assert!(
            scene
                .pixel_mean(&Point3::origin(), &near, &pinhole_ray(u, v))
                .is_some()
        );
    }

    #[test]
    fn a_row_of_rays_sees_what_each_ray_sees_alone() {
        let (board, pose) = tilted_board();
        let scene = ChessboardScene::new(board, &pose, 7);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        // A fan over the board, its edges and the wall, from two origins
        // (the left and a right camera), with rays along the board's plane,
        // away from it, and NaN among them.
        let mut dirs: Vec<Vector3<f64>> = (0..4000)
            .map(|_| {
                let (u, v) = (
                    rng.random_range(-150.0..950.0),
                    rng.random_range(-150.0..750.0),
                );
                pinhole_ray(u, v)
            })
            .collect();
        let in_plane = pose.rotation * Vector3::new(0.6, 0.8, 0.0);
        dirs.extend([in_plane, -in_plane, -(pose.rotation * Vector3::z())]);
        dirs.push(Vector3::new(f64::NAN, 0.0, 1.0));
        dirs.push(Vector3::new(0.0, f64::NAN, 1.0));
        let (mut board_rays, mut wall_rays) = (0, 0);
        for origin in [Point3::origin(), Point3::new(55.0, 0.4, -1.0)] {
            let mut rgb = vec![[0.0f32; 3]; dirs.len()];
            let mut hits = vec![(0.0, None); dirs.len()];
            scene.seen_all(&origin, &dirs, &mut rgb, &mut hits);
            for (i, dir) in dirs.iter().enumerate() {
                let alone = scene.seen(&origin, dir);
                let bits = |c: [f32; 3]| c.map(f32::to_bits);
                assert_eq!(bits(rgb[i]), bits(alone.rgb), "ray {i}: {dir}");
                assert_eq!(hits[i].0.to_bits(), alone.distance_mm.to_bits(), "ray {i}");
                if alone.distance_mm < 1000.0 {
                    board_rays += 1;
                } else {
                    wall_rays += 1;
                }
            }
        }
        assert!(
            board_rays > 2000 && wall_rays > 2000,
            "{board_rays} on the board, {wall_rays} off"
        );
    }

    #[test]
    fn a_boards_pixel_mean_is_its_finely_supersampled_mean() {
        let (board, pose) = tilted_board();
        let [x0, y0, x1, y1] = board.extent();
        // Pixels at and around the inner corners (where two edges cross),
        // the board's outer corners (board, margin and wall) and the middle
        // of its outer edges.
        let mut marks: Vec<Point3<f64>> = board.corners().into_iter().step_by(3).collect();
        marks.extend([
            Point3::new(x0, y0, 0.0),
            Point3::new(x1, y1, 0.0),
            Point3::new(x0, 0.5 * (y0 + y1), 0.0),
            Point3::new(0.5 * (x0 + x1), y1, 0.0),
        ]);
        let scene = ChessboardScene::new(board, &pose, 7);
        let (mut mixed, mut worst, mut worst_4x4) = (0, 0.0f64, 0.0f64);
        for mark in marks {
            let p = pose * mark;
            let (u, v) = (400.0 + 1333.0 * p.x / p.z, 300.0 + 1333.0 * p.y / p.z);
            for (du, dv) in (-1..=1).flat_map(|du| (-1..=1).map(move |dv| (du, dv))) {
                let (u, v) = (u.round() + du as f64, v.round() + dv as f64);
                let corners = [(-0.5, -0.5), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)]
                    .map(|(a, b)| pinhole_ray(u + a, v + b));
                let exact = scene
                    .pixel_mean(&Point3::origin(), &corners, &pinhole_ray(u, v))
                    .expect("every corner ray meets the board's plane");
                let reference = supersampled(&scene, u, v, 64);
                let coarse = supersampled(&scene, u, v, 4);
                for ch in 0..3 {
                    worst = worst.max((exact[ch] as f64 - reference[ch]).abs());
                    worst_4x4 = worst_4x4.max((coarse[ch] - reference[ch]).abs());
                }
                let seen: Vec<f32> = corners
                    .iter()
                    .map(|d| scene.radiance(&Point3::origin(), d)[1])
                    .collect();
                let spread = seen.iter().fold(0.0f32, |m, v| m.max(*v))
                    - seen.iter().fold(1.0f32, |m, v| m.min(*v));
                mixed += usize::from(spread > 0.3);
            }
        }
        assert!(mixed >= 30, "only {mixed} pixels straddle an edge");
        // 64 x 64 samples measure an edge's coverage to about 1/128 of the
        // 0.75 contrast; 4 x 4 only to 1/8 of it.
        assert!(worst < 6e-3, "exact against 64 x 64 samples: {worst}");
        assert!(
            worst_4x4 > 3.0 * worst,
            "4 x 4 samples {worst_4x4}, exact {worst}"
        );
    }

    /// The board seen through `radiance_at` alone: every pixel an edge
    /// crosses is supersampled. Counts the rays.
    struct Sampled<'a> {
        scene: &'a ChessboardScene,
        rays: std::sync::atomic::AtomicUsize,
    }

    impl Scene for Sampled<'_> {
        fn radiance_at(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> ([f32; 3], f64) {
            self.rays.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            self.scene.radiance_at(origin, dir)
        }

        fn pixel_mean(
            &self,
            origin: &Point3<f64>,
            corners: &[Vector3<f64>; 4],
            centre: &Vector3<f64>,
        ) -> Option<[f32; 3]> {
            self.rays
                .fetch_add(1_000_000, std::sync::atomic::Ordering::Relaxed);
            self.scene.pixel_mean(origin, corners, centre)
        }
    }

    #[test]
    fn the_renderer_takes_the_boards_pixel_mean_instead_of_supersampling() {
        let (board, pose) = tilted_board();
        let scene = ChessboardScene::new(board, &pose, 7);
        let camera = CameraModel {
            width: 400,
            height: 300,
            fx: 666.5,
            fy: 666.5,
            cx: 199.75,
            cy: 149.75,
            distortion: [-0.1, 0.05, 0.0, 0.0, 0.0],
        };
        let params = sharp_params(4, TextureSamples::Grid(4));
        let counted = Sampled {
            scene: &scene,
            rays: Default::default(),
        };
        let renderer = Renderer::new(&camera);
        let exact = renderer.render(&Isometry3::identity(), &counted, &params);
        let calls = counted.rays.load(std::sync::atomic::Ordering::Relaxed);
        let (means, rays) = (calls / 1_000_000, calls % 1_000_000);
        // One ray a pixel; the edge pixels took a mean, not 16 rays.
        assert_eq!(rays, camera.width * camera.height);
        assert!(means > 1000, "{means} pixels straddle an edge");
        let supersampled = renderer.render(&Isometry3::identity(), &Unsampled(&scene), &params);
        // The two differ only at the edge pixels (the accuracy of each is
        // the test above's), and there by 4 x 4 samples' coverage steps.
        let differing = exact
            .chunks(3)
            .zip(supersampled.chunks(3))
            .filter(|(a, b)| a != b)
            .count();
        assert!(
            differing > means / 4 && differing <= means,
            "{differing} of {means}"
        );
    }

    /// The board through `radiance_at` alone: no pixel means.
    struct Unsampled<'a>(&'a ChessboardScene);

    impl Scene for Unsampled<'_> {
        fn radiance_at(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> ([f32; 3], f64) {
            self.0.radiance_at(origin, dir)
        }
    }

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
        let params = sharp_params(5, TextureSamples::Grid(5));
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
