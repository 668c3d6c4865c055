//! The `io.*` ops: one file per op, each its declaration and thin adapter.

mod path;
mod read_disparity;
mod read_image;
mod read_markers;
mod write_cloud;
mod write_disparity;
mod write_json;
mod write_markers;
mod write_mesh;
mod write_rig;
mod write_stereo_pair;
mod write_table;
mod write_transform;
mod write_volume;

pub use path::{DiskPath, DiskPathInputs, DiskPathOutputs};
pub use read_disparity::{ReadDisparity, ReadDisparityOutputs};
pub use read_image::{ReadImage, ReadImageOutputs};
pub use read_markers::{ReadMarkers, ReadMarkersOutputs};
pub use write_cloud::{WriteCloud, WriteCloudInputs, WriteCloudOutputs};
pub use write_disparity::{WriteDisparity, WriteDisparityInputs, WriteDisparityOutputs};
pub use write_json::{WriteJson, WriteJsonInputs, WriteJsonOutputs};
pub use write_markers::{WriteMarkers, WriteMarkersInputs, WriteMarkersOutputs};
pub use write_mesh::{WriteMesh, WriteMeshInputs, WriteMeshOutputs};
pub use write_rig::{WriteRig, WriteRigInputs, WriteRigOutputs};
pub use write_stereo_pair::{WriteStereoPair, WriteStereoPairInputs, WriteStereoPairOutputs};
pub use write_table::{WriteTable, WriteTableInputs, WriteTableOutputs};
pub use write_transform::{WriteTransform, WriteTransformInputs, WriteTransformOutputs};
pub use write_volume::{NrrdEncoding, WriteVolume, WriteVolumeInputs, WriteVolumeOutputs};
