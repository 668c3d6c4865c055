//! `mri.detect_lesions`: lesions found in the scan alone.

use super::shape_error;
use crate::mri::{LesionParams, Polarity, detect_lesions};
use fusegraph_engine::figure::FigureData;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Markers, Mask, Volume};

/// Lesions inside the tissue found from the scan alone (scale-normalised LoG blobs, measured on the volume) -> Markers
#[derive(Op)]
#[op(name = "mri.detect_lesions", version = 1)]
pub struct DetectLesions {
    /// Whether lesions are darker (T1 without contrast agent) or brighter (enhancing) than the tissue
    #[param(default = LesionPolarity::Darker)]
    pub polarity: LesionPolarity,
    /// Smallest lesion diameter kept
    #[param(default = 2.0, unit = "mm", min = 0.5, max = 100.0)]
    pub min_diameter_mm: f64,
    /// Largest lesion diameter kept
    #[param(default = 20.0, unit = "mm", min = 0.5, max = 100.0)]
    pub max_diameter_mm: f64,
    /// Smallest contrast kept, in SDs of the tissue's noise (contrast-to-noise ratio)
    #[param(default = 3.0, unit = "sd", min = 0.0)]
    pub min_contrast_sigma: f64,
    /// How far beyond its radius a lesion's centre must lie from the tissue's outside (skin, chest wall, markers)
    #[param(default = 1.0, unit = "mm", min = 0.0)]
    pub margin_mm: f64,
}

/// Darker or brighter than the tissue.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Choice)]
pub enum LesionPolarity {
    /// Darker than the tissue.
    Darker,
    /// Brighter than the tissue.
    Brighter,
}

#[derive(Inputs)]
pub struct DetectLesionsInputs {
    /// The MRI volume as loaded (any units: contrast is measured in its tissue's noise; a stretch that clips would cut a bright lesion's contrast)
    pub volume: Arc<Volume>,
    /// Foreground mask of the tissue (e.g. mri.otsu's), same grid; enclosed holes count as tissue
    pub mask: Arc<Mask>,
}

#[derive(Outputs)]
pub struct DetectLesionsOutputs {
    /// Lesion centres, patient LPS mm (frame mri_lps), ids 1..n by falling contrast
    pub markers: Markers,
    /// Number of lesions found
    pub count: f64,
}

impl RunOp for DetectLesions {
    type Inputs = DetectLesionsInputs;
    type Outputs = DetectLesionsOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let (v, m) = (inputs.volume, inputs.mask);
        if v.grid.dims != m.grid.dims {
            return Err(OpError::invalid(format!(
                "volume is {:?} voxels but mask is {:?}",
                v.grid.dims, m.grid.dims
            )));
        }
        let params = LesionParams {
            polarity: match self.polarity {
                LesionPolarity::Darker => Polarity::Darker,
                LesionPolarity::Brighter => Polarity::Brighter,
            },
            min_diameter_mm: self.min_diameter_mm,
            max_diameter_mm: self.max_diameter_mm,
            min_contrast_sigma: self.min_contrast_sigma,
            margin_mm: self.margin_mm,
        };
        let spacing = v.grid.spacing_mm();
        let search = detect_lesions(&v.data, &m.data, v.grid.dims, spacing, &params)
            .map_err(OpError::invalid)?;
        ctx.metric("count", search.lesions.len() as f64);
        ctx.metric("noise_sigma", search.noise_sigma);
        ctx.metric("tissue_level", search.tissue_level);
        ctx.metric("candidates", search.candidates as f64);
        let mut positions = Vec::with_capacity(3 * search.lesions.len());
        for (n, l) in search.lesions.iter().enumerate() {
            let id = n + 1;
            ctx.metric(&format!("lesion_{id}_diameter_mm"), l.diameter_mm);
            ctx.metric(&format!("lesion_{id}_volume_mm3"), l.volume_mm3);
            ctx.metric(&format!("lesion_{id}_contrast"), l.contrast);
            ctx.metric(&format!("lesion_{id}_contrast_sigma"), l.contrast_sigma);
            positions.extend(v.grid.to_patient(l.centre_voxel));
        }
        let panels: Vec<(usize, [f64; 2], f64)> = search
            .lesions
            .iter()
            .map(|l| {
                let k = (l.centre_voxel[2].round().max(0.0) as usize).min(v.grid.dims[2] - 1);
                let radius_px = 0.5 * l.diameter_mm / spacing[0];
                (k, [l.centre_voxel[0], l.centre_voxel[1]], radius_px)
            })
            .collect();
        if let Some((rgb, w, h)) = crate::plot::circles_over_slices(&v.data, v.grid.dims, &panels)
            && let Ok(png) = crate::plot::png_bytes(&rgb, w, h)
        {
            ctx.figure(
                "lesions",
                &format!(
                    "The {} lesions found, each on the slice through its centre (green: its equivalent diameter)",
                    panels.len()
                ),
                FigureData::Png(png),
            )?;
        }
        let ids: Vec<u32> = (1..=search.lesions.len() as u32).collect();
        Ok(DetectLesionsOutputs {
            count: search.lesions.len() as f64,
            markers: Markers::new(positions, ids, "mri_lps").map_err(shape_error)?,
        })
    }
}
