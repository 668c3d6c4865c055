//! `mri.components`: connected components of a mask.

use super::shape_error;
use crate::mri::{Connectivity, label_components};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Labels, Mask};

/// Connected components of a mask
#[derive(Op)]
#[op(name = "mri.components", version = 1)]
pub struct Components {
    /// 6, 18 or 26 neighbours
    #[param(default = 26)]
    pub connectivity: i64,
}

#[derive(Inputs)]
pub struct ComponentsInputs {
    /// Binary mask
    pub mask: Arc<Mask>,
}

#[derive(Outputs)]
pub struct ComponentsOutputs {
    /// 0 background, 1..count components in scan order
    pub labels: Labels,
}

impl RunOp for Components {
    type Inputs = ComponentsInputs;
    type Outputs = ComponentsOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let m = inputs.mask;
        let n = self.connectivity;
        let c = Connectivity::from_count(n)
            .ok_or_else(|| OpError::invalid(format!("connectivity {n}: use 6, 18 or 26")))?;
        let (labels, sizes) = label_components(&m.data, m.grid.dims, c);
        ctx.metric("count", (sizes.len() - 1) as f64);
        Ok(ComponentsOutputs {
            labels: Labels::new(m.grid.clone(), labels).map_err(shape_error)?,
        })
    }
}
