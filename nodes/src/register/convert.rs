//! Conversions between the engine's marker and transform values and the
//! registration algorithms' points and isometries.

use super::Similarity;
use crate::camera::{isometry_from_matrix, isometry_to_matrix};
use fusegraph_engine::value::Transform;
use nalgebra::Isometry3;

pub(crate) use crate::cloud::convert::{marker_points, markers_value};

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
