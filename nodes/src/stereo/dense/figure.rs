//! The disparity map as a figure for the report.

use fusegraph_engine::value::Disparity;

/// `disparity` as a PNG, coloured over its 1st to 99th percentiles (black:
/// invalid); `None` when no pixel is valid or the image cannot be encoded.
pub(crate) fn disparity_figure_png(disparity: &Disparity) -> Option<Vec<u8>> {
    let range = crate::io::finite_percentiles(&disparity.data, 1.0, 99.0)?;
    let (rgb, w, h) = crate::io::disparity_png(disparity, range).ok()?;
    crate::plot::png_bytes(&rgb, w, h).ok()
}
