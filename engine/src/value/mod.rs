//! Typed, immutable values that flow along graph edges.
//!
//! Every value is cheap to clone (`Arc`) and keeps its data as a shape plus one
//! contiguous buffer, so it can be hashed, cached on disk and (later) handed to a
//! plugin over a C ABI without copying. Units and coordinate frames are part of
//! each type's documentation; frames that vary are carried as a `frame` string.

mod codec;
mod geometry;
mod grid;
mod image;
mod optics;
mod path;
mod table;

pub use codec::{CodecError, decode_value, encode_value};
pub(crate) use codec::{Reader, Writer};
pub use geometry::{Markers, Matches, Mesh, PointCloud};
pub use grid::{Grid, Labels, Mask, Volume};
pub use image::{Disparity, Image, Pixels};
pub use optics::{Camera, Rectification, StereoRig, Transform};
pub use path::PathValue;
pub use table::Table;

use serde::Serialize;
use std::fmt;
use std::sync::Arc;

/// A value's shape or content does not fit its type.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct ValueError(pub String);

macro_rules! value_types {
    ($( $(#[$doc:meta])* $name:ident => $ty:ty ),+ $(,)?) => {
        /// The type of a value, as declared by op ports.
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
        pub enum ValueType { $( $(#[$doc])* $name ),+ }

        impl ValueType {
            /// Every value type, in declaration order.
            pub const ALL: &'static [ValueType] = &[$(ValueType::$name),+];

            /// The type's name as written in docs and error messages.
            pub fn name(self) -> &'static str {
                match self { $(ValueType::$name => stringify!($name)),+ }
            }

            /// Parses a type name (exact, case-sensitive), e.g. `"Volume"`.
            pub fn from_name(name: &str) -> Option<Self> {
                match name { $(stringify!($name) => Some(ValueType::$name),)+ _ => None }
            }
        }

        /// A value flowing along a graph edge.
        #[derive(Debug, Clone, PartialEq, Serialize)]
        #[serde(tag = "type", content = "value")]
        pub enum Value { $( $(#[$doc])* $name(Arc<$ty>) ),+ }

        impl Value {
            /// This value's type.
            pub fn value_type(&self) -> ValueType {
                match self { $(Value::$name(_) => ValueType::$name),+ }
            }
        }

        $(
            impl From<$ty> for Value {
                fn from(v: $ty) -> Value { Value::$name(Arc::new(v)) }
            }
            impl From<Arc<$ty>> for Value {
                fn from(v: Arc<$ty>) -> Value { Value::$name(v) }
            }
            impl FromValue for $ty {
                const TYPE: ValueType = ValueType::$name;
                fn from_value(value: &Value) -> Option<&Arc<Self>> {
                    match value { Value::$name(v) => Some(v), _ => None }
                }
            }
        )+
    };
}

value_types! {
    /// f32 voxels on a grid with a voxel->patient affine (LPS, mm).
    Volume => Volume,
    /// u8 voxels (0 or 1) on a grid.
    Mask => Mask,
    /// u32 component labels (0 = background) on a grid.
    Labels => Labels,
    /// A 2D image, u8 or f32, 1 or 3 channels.
    Image => Image,
    /// A dense disparity map in pixels (NaN = no match).
    Disparity => Disparity,
    /// A triangle mesh (mm).
    Mesh => Mesh,
    /// A point cloud (mm), optional colours and normals.
    PointCloud => PointCloud,
    /// Marker centres (mm) with ids.
    Markers => Markers,
    /// Corresponding keypoint pairs (px).
    Matches => Matches,
    /// A pinhole camera with lens distortion.
    Camera => Camera,
    /// Two cameras and the rig extrinsics.
    StereoRig => StereoRig,
    /// Stereo rectification (R1, R2, P1, P2, Q).
    Rectification => Rectification,
    /// A 4x4 homogeneous transform (rigid or similarity) between named frames.
    Transform => Transform,
    /// Rows of named numbers.
    Table => Table,
    /// One number.
    Scalar => f64,
    /// A file or folder, identified by its content hash.
    Path => PathValue,
}

impl Value {
    /// Where a value that must hold finite numbers does not: a NaN or an
    /// infinity in a scalar, transform, camera, rig, rectification or marker
    /// position (large arrays such as disparities mark "unknown" with NaN,
    /// and are not checked). A NaN pose downstream would hang iterative
    /// solvers or poison every result silently.
    pub fn non_finite(&self) -> Option<&'static str> {
        let flat3 = |m: &[[f64; 3]; 3]| m.iter().flatten().copied().collect::<Vec<_>>();
        let camera = |c: &Camera| {
            let mut v = flat3(&c.k);
            v.extend(c.distortion);
            v
        };
        let (numbers, what): (Vec<f64>, &'static str) = match self {
            Value::Scalar(v) => (vec![**v], "the value"),
            Value::Transform(t) => (t.matrix.iter().flatten().copied().collect(), "the matrix"),
            Value::Camera(c) => (camera(c), "the intrinsics"),
            Value::StereoRig(r) => {
                let mut v = camera(&r.left);
                v.extend(camera(&r.right));
                v.extend(flat3(&r.rotation));
                v.extend(r.translation_mm);
                (v, "the cameras or extrinsics")
            }
            Value::Rectification(r) => {
                let mut v = flat3(&r.r1);
                v.extend(flat3(&r.r2));
                v.extend(r.p1.iter().flatten());
                v.extend(r.p2.iter().flatten());
                v.extend(r.q.iter().flatten());
                (v, "the rotations or projections")
            }
            Value::Markers(m) => (m.positions_mm.to_vec(), "a marker position"),
            _ => return None,
        };
        numbers.iter().any(|x| !x.is_finite()).then_some(what)
    }
}

/// Typed access to a [`Value`]'s payload.
pub trait FromValue: Sized {
    /// The value type this Rust type is carried as.
    const TYPE: ValueType;
    /// The payload, if `value` has this type.
    fn from_value(value: &Value) -> Option<&Arc<Self>>;
}

impl fmt::Display for ValueType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Checks that `buffer` holds exactly `expected` elements.
pub(crate) fn check_len(what: &str, buffer_len: usize, expected: usize) -> Result<(), ValueError> {
    if buffer_len == expected {
        Ok(())
    } else {
        Err(ValueError(format!(
            "{what}: buffer holds {buffer_len} elements, shape needs {expected}"
        )))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn type_names_round_trip() {
        for &t in ValueType::ALL {
            assert_eq!(ValueType::from_name(t.name()), Some(t));
        }
        assert_eq!(ValueType::from_name("volume"), None);
    }

    #[test]
    fn typed_access_checks_the_type() {
        let v = Value::from(2.5f64);
        assert_eq!(v.value_type(), ValueType::Scalar);
        assert_eq!(f64::from_value(&v).map(|x| **x), Some(2.5));
        assert!(Table::from_value(&v).is_none());
    }
}
