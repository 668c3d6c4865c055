//! The calibration board's pixel-centre rays, a row at a time: where each
//! meets the board's plane and the grey it sees there, in a loop without
//! branches that vectorises (and is compiled for AVX2 too). The arithmetic
//! is the scalar path's (`ChessboardScene::board_or_wall`), operation for
//! operation, so the answers have the same bits; rays the loop cannot
//! decide exactly (a NaN, or a coordinate too large for its floor) are
//! left to the scalar path.

use crate::numeric::{EXACT_FLOOR_LIMIT, floor_small};
use crate::simd::{Isa, kernels};
use nalgebra::{Matrix3, Vector3};

/// The board's pattern, board frame (mm; x along the columns, y along the
/// rows, origin at the first inner corner).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct BoardPattern {
    /// Square side, mm.
    pub square_mm: f64,
    /// The board's outer edge: [x0, y0, x1, y1], mm.
    pub extent_mm: [f64; 4],
    /// Inner corners per row.
    pub cols: usize,
    /// Inner corners per column.
    pub rows: usize,
}

/// Reflectance of the board's black squares (linear, 0..1).
pub(super) const BLACK_ALBEDO: f32 = 0.07;
/// Reflectance of its white squares and border.
pub(super) const WHITE_ALBEDO: f32 = 0.82;

/// The light on the board at x mm along its `width_mm` of squares: it
/// falls off across the board (uneven lighting), linearly between its first
/// and last columns. Shared by the scalar path and the row kernel, so both
/// give the same bits.
#[inline(always)]
pub(super) fn board_light(x: f64, width_mm: f64) -> f64 {
    0.8 + 0.2 * (x / width_mm).clamp(0.0, 1.0)
}

/// A grey of the board (linear) as RGB: the board is a touch yellow.
#[inline(always)]
pub(super) fn board_grey_rgb(v: f32) -> [f32; 3] {
    [v, v, v * 0.97]
}

/// What a ray of the row saw ([`board_row`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum BoardSample {
    /// The board, at this distance (mm), in this grey (linear, 0..1).
    Board { distance_mm: f64, grey: f32 },
    /// Not the board (the ray misses its plane or its edge).
    Off,
    /// For the scalar path to decide.
    Undecided,
}

/// The rays from `board_origin` (board frame) along each of `dirs` (world
/// frame; `world_to_board` turns them into the board's).
pub(super) fn board_row(
    world_to_board: &Matrix3<f64>,
    board_origin: &Vector3<f64>,
    dirs: &[Vector3<f64>],
    pattern: &BoardPattern,
) -> Vec<BoardSample> {
    let n = dirs.len();
    let axis = |i: usize| -> Vec<f64> { dirs.iter().map(|d| d[i]).collect() };
    let (x, y, z) = (axis(0), axis(1), axis(2));
    let mut distance_mm = vec![0.0; n];
    let mut grey = vec![0.0f32; n];
    let mut code = vec![0u8; n];
    let geometry = RowGeometry {
        rotation: std::array::from_fn(|k| world_to_board[(k / 3, k % 3)]),
        origin: [board_origin.x, board_origin.y, board_origin.z],
        pattern: *pattern,
    };
    Isa::detect().board_samples(
        &geometry,
        [&x, &y, &z],
        &mut distance_mm,
        &mut grey,
        &mut code,
    );
    (0..n)
        .map(|i| match code[i] {
            ON_BOARD => BoardSample::Board {
                distance_mm: distance_mm[i],
                grey: grey[i],
            },
            OFF_BOARD => BoardSample::Off,
            _ => BoardSample::Undecided,
        })
        .collect()
}

/// The kernel's inputs besides the rays.
#[derive(Debug, Clone, Copy)]
pub(crate) struct RowGeometry {
    /// `world_to_board`'s rotation, row-major.
    rotation: [f64; 9],
    /// The rays' origin, board frame, mm.
    origin: [f64; 3],
    pattern: BoardPattern,
}

const OFF_BOARD: u8 = 0;
const ON_BOARD: u8 = 1;
const UNDECIDED: u8 = 2;

kernels! {
    /// For each ray (direction components `dirs[0..3][i]`, world frame):
    /// its distance to the board's plane and the grey it sees there, with
    /// `code` ON_BOARD, OFF_BOARD or UNDECIDED.
    fn board_samples(
        g: &RowGeometry,
        dirs: [&[f64]; 3],
        distance_mm: &mut [f64],
        grey: &mut [f32],
        code: &mut [u8],
    ) {
        let n = code.len();
        let (dx, dy, dz) = (&dirs[0][..n], &dirs[1][..n], &dirs[2][..n]);
        let (distance_mm, grey) = (&mut distance_mm[..n], &mut grey[..n]);
        let m = g.rotation;
        let [ox, oy, oz] = g.origin;
        let p = g.pattern;
        let s = p.square_mm;
        let [x0, y0, x1, y1] = p.extent_mm;
        let (cols, rows) = (p.cols as f64, p.rows as f64);
        let width_mm = p.cols as f64 * s;
        for i in 0..n {
            let (a, b, c) = (dx[i], dy[i], dz[i]);
            // The matrix product in nalgebra's order.
            let d0 = m[0] * a + m[1] * b + m[2] * c;
            let d1 = m[3] * a + m[4] * b + m[5] * c;
            let d2 = m[6] * a + m[7] * b + m[8] * c;
            let t = -oz / d2;
            // The scalar path refuses |d2| <= 1e-12, then t <= 0; a NaN d2
            // gives a NaN t, refused by the second test in both.
            let meets_plane = (d2.abs() > 1e-12) & (t > 0.0);
            let (x, y) = (ox + d0 * t, oy + d1 * t);
            let on_board = meets_plane & !((x < x0) | (y < y0) | (x > x1) | (y > y1));
            let (qx, qy) = (x / s, y / s);
            let decidable = (qx.abs() < EXACT_FLOOR_LIMIT) & (qy.abs() < EXACT_FLOOR_LIMIT);
            let (fx, fy) = (floor_small(qx), floor_small(qy));
            let in_squares = (fx >= -1.0) & (fy >= -1.0) & (fx < cols) & (fy < rows);
            let half = (fx + fy) * 0.5;
            let black = in_squares & (floor_small(half) == half);
            let albedo = if black { BLACK_ALBEDO } else { WHITE_ALBEDO };
            let light = board_light(x, width_mm);
            distance_mm[i] = t;
            grey[i] = albedo * light as f32;
            code[i] = if !on_board {
                OFF_BOARD
            } else if decidable {
                ON_BOARD
            } else {
                UNDECIDED
            };
        }
    }
}
