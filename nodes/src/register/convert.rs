//! Conversions between the engine's marker and transform values and the
//! registration algorithms' points and isometries.

use super::Similarity;
use crate::camera::{isometry_from_matrix, isometry_to_matrix};
use fusegraph_engine::OpError;
use fusegraph_engine::value::{Markers, Transform};
use nalgebra::{Isometry3, Point3};

/// Markers' positions, mm, in their frame.
pub(crate) fn marker_points(m: &Markers) -> Vec<Point3<f64>> {
    m.positions_mm
        .chunks(3)
        .map(|c| Point3::new(c[0], c[1], c[2]))
        .collect()
}

/// A markers value of `points` (mm, in `frame`) with `ids`, one each.
pub(crate) fn markers_value(
    points: &[Point3<f64>],
    ids: Vec<u32>,
    frame: &str,
) -> Result<Markers, OpError> {
    let positions: Vec<f64> = points.iter().flat_map(|p| [p.x, p.y, p.z]).collect();
    Markers::new(positions, ids, frame).map_err(|e| OpError::invalid(e.0))
}

/// A Transform value's rigid part (its `from` frame -> its `to` frame).
pub(crate) fn transform_isometry(t: &Transform) -> Isometry3<f64> {
    isometry_from_matrix(&t.matrix)
}

/// An isometry as a Transform value from frame `from` to frame `to`.
pub(crate) fn transform_value(iso: &Isometry3<f64>, from: &str, to: &str) -> Transform {
    Transform {
        matrix: isometry_to_matrix(iso),
        from: from.into(),
        to: to.into(),
    }
}

/// A similarity (scale included) as a Transform value from frame `from` to
/// frame `to`.
pub(crate) fn similarity_value(sim: &Similarity, from: &str, to: &str) -> Transform {
    let m = sim.matrix();
    Transform {
        matrix: std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)])),
        from: from.into(),
        to: to.into(),
    }
}
