//! `mri.centroids`: the centre of each component.

use super::shape_error;
use crate::mri::{Weighting, centroids};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Labels, Markers, Volume};

/// Centroid of each component, in patient mm
#[derive(Op)]
#[op(name = "mri.centroids", version = 1)]
pub struct Centroids {
    /// intensity (sub-voxel) or binary
    #[param(default = CentroidWeighting::Intensity)]
    pub weighting: CentroidWeighting,
    /// Intensity counting as zero weight
    #[param(default = 0.0)]
    pub background: f64,
    /// Grow components to take in partial-volume voxels
    #[param(default = 1, unit = "voxels", min = 0, max = 5)]
    pub dilate_voxels: usize,
}

/// How voxels weigh in a centroid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Choice)]
pub enum CentroidWeighting {
    /// By intensity above the background: sub-voxel centres.
    Intensity,
    /// Every voxel of the component alike.
    Binary,
}

#[derive(Inputs)]
pub struct CentroidsInputs {
    /// Components (1..n)
    pub labels: Arc<Labels>,
    /// Intensities for weighting (same grid)
    pub volume: Option<Arc<Volume>>,
}

#[derive(Outputs)]
pub struct CentroidsOutputs {
    /// Centres, patient LPS mm (frame mri_lps), ids = labels
    pub markers: Markers,
}

impl RunOp for Centroids {
    type Inputs = CentroidsInputs;
    type Outputs = CentroidsOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let (l, volume) = (inputs.labels, inputs.volume);
        let weighting = match self.weighting {
            CentroidWeighting::Binary => Weighting::Binary,
            CentroidWeighting::Intensity => {
                let v = volume.as_ref().ok_or_else(|| {
                    OpError::invalid(
                        "intensity weighting needs the `volume` input (or weighting = \"binary\")",
                    )
                })?;
                if v.grid.dims != l.grid.dims {
                    return Err(OpError::invalid(format!(
                        "volume is {:?} voxels but labels are {:?}",
                        v.grid.dims, l.grid.dims
                    )));
                }
                Weighting::Intensity {
                    background: self.background as f32,
                    dilate: self.dilate_voxels,
                }
            }
        };
        let count = l.data.iter().copied().max().unwrap_or(0) as usize;
        let centres = centroids(
            &l.data,
            count,
            &l.grid,
            volume.as_ref().map(|v| &v.data[..]),
            weighting,
        );
        ctx.metric("count", count as f64);
        let positions: Vec<f64> = centres.iter().flatten().copied().collect();
        let ids: Vec<u32> = (1..=count as u32).collect();
        Ok(CentroidsOutputs {
            markers: Markers::new(positions, ids, "mri_lps").map_err(shape_error)?,
        })
    }
}
