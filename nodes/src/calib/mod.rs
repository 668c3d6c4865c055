//! Camera calibration: chessboard corners to sub-pixel accuracy (so far).

mod subpixel;

pub use subpixel::{refine_corner, window_for_square};
