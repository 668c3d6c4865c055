//! The `hue_deg` parameter read from an untyped op's parameters, for
//! `cloud.remove_colour` (which shares it with `stereo.hsv_markers`) until
//! that op is in the typed form; then this file goes.

use fusegraph_engine::{OpError, Params};

/// The `hue_deg` parameter as (min, max).
pub(crate) fn hue_range(params: &Params) -> Result<(f64, f64), OpError> {
    let hue = params.float_list("hue_deg")?;
    let [h0, h1] = hue[..] else {
        return Err(OpError::invalid(format!(
            "parameter `hue_deg`: expected [min, max], got {} numbers",
            hue.len()
        )));
    };
    Ok((h0, h1))
}
