//! `cloud.from_mesh`: a point cloud from a mesh.

use crate::cloud::convert::{make_cloud, mesh_normals, mesh_triangles, mesh_vertices};
use crate::cloud::sample_mesh_with_normals;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Mesh, PointCloud};

/// A point cloud from a mesh: its vertices, or points spread uniformly by area
#[derive(Op)]
#[op(name = "cloud.from_mesh", version = 1)]
pub struct FromMesh {
    /// area: uniform sampling; vertices: the vertices
    #[param(default = SampleMode::Area)]
    pub mode: SampleMode,
    /// Points to sample (area mode)
    #[param(default = 50_000, min = 1, max = 1e8)]
    pub points: usize,
    /// Sampling seed
    #[param(default = 1, min = 0)]
    pub seed: i64,
}

/// Which points of the mesh make the cloud.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Choice)]
pub enum SampleMode {
    /// Points spread uniformly by area, each with its triangle's normal.
    Area,
    /// The mesh's vertices (with its normals, if any).
    Vertices,
}

#[derive(Inputs)]
pub struct FromMeshInputs {
    /// The mesh
    pub mesh: Arc<Mesh>,
}

#[derive(Outputs)]
pub struct FromMeshOutputs {
    /// Points (with normals), in the mesh's frame
    pub cloud: PointCloud,
}

impl RunOp for FromMesh {
    type Inputs = FromMeshInputs;
    type Outputs = FromMeshOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let mesh = inputs.mesh;
        let vertices = mesh_vertices(&mesh);
        let cloud = match self.mode {
            SampleMode::Vertices => {
                make_cloud(&vertices, mesh_normals(&mesh).as_deref(), None, &mesh.frame)?
            }
            SampleMode::Area => {
                let (points, normals) = sample_mesh_with_normals(
                    &vertices,
                    &mesh_triangles(&mesh),
                    self.points,
                    self.seed as u64,
                );
                make_cloud(&points, Some(&normals), None, &mesh.frame)?
            }
        };
        ctx.metric("points", cloud.len() as f64);
        Ok(FromMeshOutputs { cloud })
    }
}
