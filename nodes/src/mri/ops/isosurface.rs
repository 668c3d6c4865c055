//! `mri.isosurface`: marching cubes on a volume or mask.

use super::shape_error;
use crate::mri::marching_cubes;
use fusegraph_engine::Value;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Grid, Mesh};
use std::borrow::Cow;

/// Marching cubes: the surface value = level, in patient mm, closed
#[derive(Op)]
#[op(name = "mri.isosurface", version = 2)]
pub struct Isosurface {
    /// Iso-value (0.5 for a mask)
    #[param(default = 0.5)]
    pub level: f64,
    /// Taubin smoothing passes (0 = none)
    #[param(default = 0, min = 0, max = 200)]
    pub smooth_iterations: usize,
}

#[derive(Inputs)]
pub struct IsosurfaceInputs {
    /// Volume, or a mask (0/1)
    #[input(types(Volume, Mask))]
    pub volume: Value,
    /// Level from another node (e.g. otsu.threshold); overrides `level`
    pub level: Option<f64>,
}

#[derive(Outputs)]
pub struct IsosurfaceOutputs {
    /// Triangle mesh, patient LPS mm, outward normals
    pub mesh: Mesh,
}

impl RunOp for Isosurface {
    type Inputs = IsosurfaceInputs;
    type Outputs = IsosurfaceOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let (grid, values): (Grid, Cow<[f32]>) = match &inputs.volume {
            Value::Volume(v) => (v.grid.clone(), Cow::Borrowed(&v.data[..])),
            Value::Mask(m) => (
                m.grid.clone(),
                Cow::Owned(m.data.iter().map(|&x| x as f32).collect()),
            ),
            _ => {
                return Err(OpError::Input(
                    "volume".into(),
                    "expected a Volume or a Mask".into(),
                ));
            }
        };
        let level = inputs.level.unwrap_or(self.level);
        let mut mesh = marching_cubes(&values, &grid, level as f32);
        if mesh.triangles.is_empty() {
            return Err(OpError::invalid(format!(
                "no surface at level {level}: every voxel is on one side"
            )));
        }
        mesh.smooth(self.smooth_iterations);
        ctx.metric("vertices", mesh.vertices.len() as f64);
        ctx.metric("triangles", mesh.triangles.len() as f64);
        let (area, volume, normals) = mesh.area_volume_normals();
        ctx.metric("area_mm2", area);
        ctx.metric("volume_mm3", volume);
        let normals: Vec<f32> = normals.into_flattened();
        let mesh = Mesh::new(
            mesh.vertices.into_flattened(),
            mesh.triangles.into_flattened(),
            Some(normals.into()),
            "mri_lps",
        )
        .map_err(shape_error)?;
        Ok(IsosurfaceOutputs { mesh })
    }
}
