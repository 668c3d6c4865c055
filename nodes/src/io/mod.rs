//! File nodes: sources that read files into the graph and sinks (`io.write_*`)
//! that write values under the run's output folder. The file formats are plain
//! functions here (images, disparity maps, volumes, meshes, markers, tables,
//! rigs, transforms, JSON); the ops, one file each, are in [`ops`].

mod deshear;
mod disk_size;
mod disparity;
mod images;
mod itk_transform;
mod json;
mod markers;
mod meshes;
mod opencv_yaml;
pub mod ops;
mod source_file;
mod tables;
mod volumes;

pub use deshear::{Shear, deshear, grid_shear, orthogonal_grid};
pub use disparity::{
    decode_pfm, decode_pgm, disparity_png, encode_pfm, finite_percentiles, read_disparity, viridis,
};
pub use images::{
    DEFAULT_MAX_PIXELS, GreyImage, ImageSizeLimit, grey_of, load_grey, load_grey_within,
    load_image, load_image_within, max_megapixels_param, max_pixels, side_by_side,
};
pub use itk_transform::{itk_transform_text, read_itk_transform};
pub use json::value_to_json;
pub use markers::{
    MarkerNotes, ReadPoints, SlicerMarkups, markers_csv, parse_markups, parse_points_csv,
    read_markups, slicer_markups, write_markers_csv,
};
pub use meshes::{write_ply, write_stl};
pub use opencv_yaml::rig_yaml;
pub use source_file::{SourceDir, SourceFile};
pub use tables::{table_csv, table_markdown};
pub use volumes::{
    NiftiVolume, VoxelBuf, Voxels, lps_to_ras, read_nifti, read_nrrd, write_nifti, write_nrrd,
};

use fusegraph_engine::Registry;
use fusegraph_engine::registry::RegisterError;

/// Registers the `io.*` ops.
pub fn register(registry: &mut Registry) -> Result<(), RegisterError> {
    registry.add::<ops::DiskPath>()?;
    registry.add::<ops::ReadImage>()?;
    registry.add::<ops::ReadMarkers>()?;
    registry.add::<ops::WriteStereoPair>()?;
    registry.add::<ops::WriteRig>()?;
    registry.add::<ops::WriteTransform>()?;
    registry.add::<ops::WriteCloud>()?;
    registry.add::<ops::WriteJson>()?;
    registry.add::<ops::WriteMarkers>()?;
    registry.add::<ops::WriteMesh>()?;
    registry.add::<ops::WriteTable>()?;
    registry.add::<ops::WriteVolume>()?;
    registry.add::<ops::ReadDisparity>()?;
    registry.add::<ops::WriteDisparity>()?;
    Ok(())
}
