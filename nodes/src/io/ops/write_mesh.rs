//! `io.write_mesh`: a mesh as binary PLY or STL, by the file's extension.

use crate::io::{write_ply, write_stl};
use fusegraph_engine::path_value;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Mesh, PathValue};

/// Write a mesh as binary PLY or STL (by extension) under the output folder
#[derive(Op)]
#[op(name = "io.write_mesh", version = 1, writes_output)]
pub struct WriteMesh {
    /// File name (.ply or .stl), relative to the output folder
    #[param(default = "surface.ply")]
    pub file: String,
}

#[derive(Inputs)]
pub struct WriteMeshInputs {
    /// The mesh
    pub mesh: Arc<Mesh>,
}

#[derive(Outputs)]
pub struct WriteMeshOutputs {
    /// The written file
    pub file: PathValue,
}

impl RunOp for WriteMesh {
    type Inputs = WriteMeshInputs;
    type Outputs = WriteMeshOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let (mesh, file) = (inputs.mesh, &self.file);
        let path = ctx.output_path(file)?;
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        match ext.as_deref() {
            Some("ply") => write_ply(
                &path,
                &mesh.vertices,
                mesh.normals.as_deref(),
                None,
                &mesh.triangles,
                &format!("fusegraph mesh, mm, frame {}", mesh.frame),
            ),
            Some("stl") => write_stl(&path, &mesh),
            _ => {
                return Err(OpError::invalid(format!(
                    "file {file:?}: use a .ply or .stl extension"
                )));
            }
        }
        .map_err(|e| OpError::io(&path, e))?;
        Ok(WriteMeshOutputs {
            file: path_value(&path)?,
        })
    }
}
