//! Figures a node attaches to its run (a disparity map, detections drawn on a
//! photo, a plot), kept in the cache with its outputs so a cached node's
//! figures are in the report too, and written beside `report.json` for
//! `report.html`.

use serde::Serialize;

/// The encoded picture.
#[derive(Debug, Clone, PartialEq)]
pub enum FigureData {
    /// A PNG file's bytes.
    Png(Vec<u8>),
    /// An SVG document.
    Svg(String),
    /// Points to draw in the report's 3D view: x, y, z (mm) and r, g, b per
    /// point.
    Points3d {
        /// x, y, z of each point, mm.
        xyz: Vec<f32>,
        /// r, g, b of each point.
        rgb: Vec<u8>,
    },
}

/// One figure of a node.
#[derive(Debug, Clone, PartialEq)]
pub struct Figure {
    /// Short name, unique within the node (letters, digits, `_`, `-`): the
    /// file name.
    pub name: String,
    /// What it shows, in a sentence.
    pub caption: String,
    /// The picture.
    pub data: FigureData,
}

impl Figure {
    /// The file extension of its data.
    pub fn extension(&self) -> &'static str {
        match self.data {
            FigureData::Png(_) => "png",
            FigureData::Svg(_) => "svg",
            FigureData::Points3d { .. } => "points",
        }
    }

    /// The file name of node `node`'s figure: `node.name.ext`.
    pub fn file_name(&self, node: &str) -> String {
        format!("{node}.{}.{}", self.name, self.extension())
    }
}

/// A figure as `report.json` lists it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FigureRef {
    /// Name within the node.
    pub name: String,
    /// Caption.
    pub caption: String,
    /// File under the output folder (`figures/node.name.ext`).
    pub file: String,
}

/// Checks a figure name: non-empty, letters, digits, `_` and `-` only.
pub fn check_figure_name(name: &str) -> Result<(), String> {
    if name.is_empty()
        || !name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
    {
        return Err(format!(
            "figure name {name:?}: use letters, digits, '_' and '-'"
        ));
    }
    Ok(())
}
