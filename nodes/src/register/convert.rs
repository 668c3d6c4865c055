//! Conversions between the engine's marker and transform values and the
//! registration algorithms' points and isometries.

use super::{FIELD_COLUMNS, Lattice, Similarity};
use crate::calib::ParameterCovariance;
use crate::camera::{isometry_from_matrix, isometry_to_matrix};
use fusegraph_engine::OpError;
use fusegraph_engine::value::{Markers, Table, Transform};
use nalgebra::{Isometry3, Matrix6, Point3};

pub(crate) use crate::cloud::convert::{marker_points, markers_value};

/// Landmarks in a source frame and their matches in a target frame, mm.
pub(crate) type MatchedLandmarks = (Vec<Point3<f64>>, Vec<Point3<f64>>);

/// The landmark pairs of two optional inputs, checked: both sides or
/// neither, in the clouds' frames (`source_frame`, `target_frame`), one to
/// one.
pub(crate) fn landmark_pairs(
    source: Option<&Markers>,
    target: Option<&Markers>,
    source_frame: &str,
    target_frame: &str,
) -> Result<Option<MatchedLandmarks>, OpError> {
    match (source, target) {
        (None, None) => Ok(None),
        (Some(a), Some(b)) => {
            if a.frame != source_frame || b.frame != target_frame {
                return Err(OpError::invalid(format!(
                    "landmarks are in `{}` and `{}`, the clouds in `{source_frame}` and `{target_frame}`",
                    a.frame, b.frame
                )));
            }
            let (a, b) = (marker_points(a), marker_points(b));
            if a.len() != b.len() {
                return Err(OpError::invalid(format!(
                    "{} source landmarks and {} target landmarks: they pair in order",
                    a.len(),
                    b.len()
                )));
            }
            Ok(Some((a, b)))
        }
        _ => Err(OpError::invalid(
            "connect both landmarks_source and landmarks_target, or neither",
        )),
    }
}

/// A displacement field as a table: one row per lattice node, the columns
/// [`FIELD_COLUMNS`] (register.deformable's `field`).
pub(crate) fn field_table(field: &Lattice) -> Table {
    Table::new(
        FIELD_COLUMNS.iter().map(|c| c.to_string()).collect(),
        field.to_rows().concat(),
    )
    .expect("six values per row")
}

/// The field a [`field_table`] holds, its columns found by name; an error
/// naming a missing column or the first node off a regular lattice.
pub(crate) fn field_from_table(table: &Table) -> Result<Lattice, String> {
    let columns: Vec<Vec<f64>> = FIELD_COLUMNS
        .iter()
        .map(|c| {
            table.column(c).ok_or_else(|| {
                format!(
                    "no column `{c}` (give register.deformable's field: {})",
                    FIELD_COLUMNS.join(", ")
                )
            })
        })
        .collect::<Result<_, _>>()?;
    let rows: Vec<[f64; 6]> = (0..table.row_count())
        .map(|r| std::array::from_fn(|c| columns[c][r]))
        .collect();
    Lattice::from_rows(&rows)
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

/// The names of the pose covariance's rows and columns.
pub(crate) const POSE_COVARIANCE_NAMES: [&str; 6] = [
    "rotation_x_rad",
    "rotation_y_rad",
    "rotation_z_rad",
    "translation_x_mm",
    "translation_y_mm",
    "translation_z_mm",
];

fn pose_covariance_names() -> Vec<String> {
    POSE_COVARIANCE_NAMES
        .iter()
        .map(|n| n.to_string())
        .collect()
}

/// A pose covariance as a table (`register.icp`'s `covariance`).
pub(crate) fn pose_covariance_table(c: &Matrix6<f64>) -> Table {
    ParameterCovariance {
        names: pose_covariance_names(),
        matrix: nalgebra::DMatrix::from_fn(6, 6, |r, k| c[(r, k)]),
    }
    .to_table()
}

/// A pose covariance table without rows: none known.
pub(crate) fn empty_pose_covariance() -> Table {
    Table::new(pose_covariance_names(), Vec::new()).expect("columns")
}

/// A pose covariance from such a table, checked.
pub(crate) fn pose_covariance_from_table(t: &Table) -> Result<Matrix6<f64>, String> {
    let c = ParameterCovariance::from_table(t)?;
    if c.names != POSE_COVARIANCE_NAMES {
        return Err(format!(
            "a pose covariance has the columns {}, not {}",
            POSE_COVARIANCE_NAMES.join(", "),
            c.names.join(", ")
        ));
    }
    Ok(Matrix6::from_fn(|r, k| c.matrix[(r, k)]))
}
