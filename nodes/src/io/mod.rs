//! File nodes: sources that read files into the graph and sinks (`io.write_*`)
//! that write values under the run's output folder.

mod disparity;
mod images;
mod path;
mod read_markers;
mod write_json;
mod write_markers;
mod write_mesh;
mod write_registration;
mod write_rig;
mod write_table;
mod write_volume;

pub use disparity::{
    decode_pfm, decode_pgm, disparity_png, encode_pfm, finite_percentiles, read_disparity, viridis,
};
pub use images::{
    DEFAULT_MAX_PIXELS, GreyImage, grey_of, load_grey, load_grey_within, load_image,
    load_image_within, side_by_side,
};
pub(crate) use images::{max_megapixels_param, max_pixels};
pub use read_markers::{parse_markups, parse_points_csv};
pub use write_json::value_to_json;
pub use write_markers::{markers_csv, slicer_markups};
pub use write_mesh::{write_ply, write_stl};
pub use write_registration::{itk_transform_text, read_itk_transform};
pub use write_rig::rig_yaml;
pub use write_table::{table_csv, table_markdown};
pub use write_volume::{
    NiftiVolume, VoxelBuf, Voxels, lps_to_ras, read_nifti, read_nrrd, write_nifti, write_nrrd,
};

use fusegraph_engine::Registry;
use fusegraph_engine::registry::RegisterError;
use std::sync::Arc;

/// Registers the `io.*` ops.
pub fn register(registry: &mut Registry) -> Result<(), RegisterError> {
    registry.register(Arc::new(path::PathOp::new()))?;
    registry.register(Arc::new(images::ReadImageOp::new()))?;
    registry.register(Arc::new(read_markers::ReadMarkersOp::new()))?;
    registry.register(Arc::new(images::WriteStereoPairOp::new()))?;
    registry.register(Arc::new(write_rig::WriteRigOp::new()))?;
    registry.register(Arc::new(write_registration::WriteTransformOp::new()))?;
    registry.register(Arc::new(write_registration::WriteCloudOp::new()))?;
    registry.register(Arc::new(write_json::WriteJsonOp::new()))?;
    registry.register(Arc::new(write_markers::WriteMarkersOp::new()))?;
    registry.register(Arc::new(write_mesh::WriteMeshOp::new()))?;
    registry.register(Arc::new(write_table::WriteTableOp::new()))?;
    registry.register(Arc::new(write_volume::WriteVolumeOp::new()))?;
    registry.register(Arc::new(disparity::ReadDisparityOp::new()))?;
    registry.register(Arc::new(disparity::WriteDisparityOp::new()))?;
    Ok(())
}
