//! `register.icp`: iterative closest point between two clouds.

use crate::cloud::Nearest;
use crate::cloud::convert::{cloud_normals, cloud_points};
use crate::register::convert::{transform_isometry, transform_value};
use crate::register::figures::icp_figures;
use crate::register::{IcpMethod, IcpParams, Kernel, icp};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{PointCloud, Table, Transform};
use nalgebra::Isometry3;

/// Iterative closest point: source cloud onto target cloud
#[derive(Op)]
#[op(name = "register.icp", version = 2)]
pub struct Icp {
    /// Error metric
    #[param(default = IcpMethod::PointToPlane)]
    pub method: IcpMethod,
    /// Pairs farther apart are ignored
    #[param(default = 5.0, unit = "mm", min = 1e-3)]
    pub max_distance_mm: f64,
    /// Fraction of closest pairs kept
    #[param(default = 0.9, min = 0.05, max = 1.0)]
    pub trim_ratio: f64,
    /// Robust kernel
    #[param(default = IcpKernel::Huber)]
    pub kernel: IcpKernel,
    /// Kernel threshold (Huber k, Tukey c)
    #[param(default = 1.5, unit = "mm", min = 1e-6)]
    pub kernel_mm: f64,
    /// Iterations per scale
    #[param(default = 50, min = 1, max = 10000)]
    pub max_iterations: usize,
    /// Relative change of RMSE and fitness that stops it
    #[param(default = 1e-6, min = 0.0)]
    pub tolerance: f64,
    /// Coarse-to-fine source voxel sizes (0 = full)
    #[param(default = [], unit = "mm", min = 0.0)]
    pub voxel_sizes_mm: Vec<f64>,
}

/// The robust kernel, by name (its threshold is `kernel_mm`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Choice)]
pub enum IcpKernel {
    /// Huber.
    Huber,
    /// Tukey's biweight.
    Tukey,
    /// Plain least squares.
    None,
}

impl IcpKernel {
    /// The kernel with threshold `mm`.
    pub fn with_threshold(self, mm: f64) -> Kernel {
        match self {
            IcpKernel::Huber => Kernel::Huber(mm),
            IcpKernel::Tukey => Kernel::Tukey(mm),
            IcpKernel::None => Kernel::None,
        }
    }
}

#[derive(Inputs)]
pub struct IcpInputs {
    /// Cloud to move
    pub source: Arc<PointCloud>,
    /// Cloud to move onto (normals for point-to-plane)
    pub target: Arc<PointCloud>,
    /// Start (source -> target), e.g. from markers
    pub init: Option<Arc<Transform>>,
}

#[derive(Outputs)]
pub struct IcpOutputs {
    /// Source frame -> target frame
    pub transform: Transform,
    /// iteration, voxel_mm, rmse_mm, fitness, pairs
    pub trace: Table,
}

impl RunOp for Icp {
    type Inputs = IcpInputs;
    type Outputs = IcpOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let (s, t) = (inputs.source, inputs.target);
        let init = match inputs.init {
            Some(tr) => {
                if tr.from != s.frame || tr.to != t.frame {
                    return Err(OpError::invalid(format!(
                        "init maps `{}` -> `{}`, but the clouds are `{}` -> `{}`",
                        tr.from, tr.to, s.frame, t.frame
                    )));
                }
                transform_isometry(&tr)
            }
            None => Isometry3::identity(),
        };
        let (sp, tp) = (cloud_points(&s), cloud_points(&t));
        let tn = cloud_normals(&t);
        let tree =
            Nearest::new(&tp).ok_or_else(|| OpError::invalid("the target cloud is empty"))?;
        let p = IcpParams {
            method: self.method,
            max_distance_mm: self.max_distance_mm,
            trim_ratio: self.trim_ratio,
            kernel: self.kernel.with_threshold(self.kernel_mm),
            max_iterations: self.max_iterations,
            tolerance: self.tolerance,
            voxel_sizes_mm: self.voxel_sizes_mm.clone(),
        };
        let r = icp(&sp, &tp, tn.as_deref(), &tree, &init, &p).map_err(OpError::invalid)?;
        ctx.metric("rmse_mm", r.rmse_mm);
        ctx.metric("fitness", r.fitness);
        ctx.metric("iterations", r.iterations as f64);
        let trace: Vec<f64> = r
            .trace
            .iter()
            .enumerate()
            .flat_map(|(i, st)| {
                [
                    i as f64,
                    st.voxel_mm,
                    st.rmse_mm,
                    st.fitness,
                    st.pairs as f64,
                ]
            })
            .collect();
        let trace = Table::new(
            ["iteration", "voxel_mm", "rmse_mm", "fitness", "pairs"]
                .iter()
                .map(|c| c.to_string())
                .collect(),
            trace,
        )
        .map_err(|e| OpError::invalid(e.0))?;
        icp_figures(ctx, &trace, &sp, &tp, &init, &r.transform)?;
        Ok(IcpOutputs {
            transform: transform_value(&r.transform, &s.frame, &t.frame),
            trace,
        })
    }
}
