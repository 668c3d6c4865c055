//! The `register.*` ops: one file per op, each its declaration and thin adapter.

mod deformable;
mod evaluate;
mod icp;
mod map_targets;
mod match_markers;
mod multiview;
mod procrustes;

pub use deformable::{DeformMode, Deformable, DeformableInputs, DeformableOutputs};
pub use evaluate::{Evaluate, EvaluateInputs, EvaluateOutputs};
pub use icp::{Icp, IcpInputs, IcpKernel, IcpOutputs};
pub use map_targets::{MapTargets, MapTargetsInputs, MapTargetsOutputs, TargetSource};
pub use match_markers::{MatchMarkers, MatchMarkersInputs, MatchMarkersOutputs};
pub use multiview::{
    MAX_VIEWS, Multiview, MultiviewInputs, MultiviewOutputs, OutputFrame, ViewInputs,
};
pub use procrustes::{Procrustes, ProcrustesInputs, ProcrustesOutputs};
