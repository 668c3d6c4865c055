//! Acquisition conditions of the camera session: how far it is from the
//! ideal phantom (tissue that moved since the scan, and more as they are
//! added). Declared once here, flattened into `phantom.generate`; every
//! default reproduces the ideal phantom byte for byte.

use super::motion::MotionKind;
use fusegraph_engine::typed::declared_defaults;
use fusegraph_plugin_api::derive::Params;

/// The conditions of the camera session (the MRI is always as scanned).
#[derive(Debug, Clone, PartialEq, Params)]
pub struct Conditions {
    /// How the tissue moved between the MRI and the camera session: none,
    /// sag (gravity), compression (a plate from above), squeeze (two
    /// paddles across motion_direction_deg) or shift (lateral)
    #[param(default = MotionKind::None)]
    pub motion: MotionKind,
    /// Largest displacement of the tissue over the dome (0 = none); zero on
    /// the table
    #[param(default = 0.0, unit = "mm", min = 0.0, max = 30.0)]
    pub motion_peak_mm: f64,
    /// Horizontal direction of the motion, phantom frame, from +x
    #[param(default = 0.0, unit = "deg", min = -360.0, max = 360.0)]
    pub motion_direction_deg: f64,
}

impl Default for Conditions {
    /// The ideal phantom: every condition at its declared default.
    fn default() -> Self {
        declared_defaults().expect("every condition has a default")
    }
}
