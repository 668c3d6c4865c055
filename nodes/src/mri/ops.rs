//! Node adapters of the MRI branch: unpack values, call the functions, report.

use super::*;
use fusegraph_engine::value::{Grid, Labels, Markers, Mask, Mesh, Volume};
use fusegraph_engine::{
    Inputs, Op, OpError, OpSpec, Outputs, ParamSpec, Params, RunCtx, Value, ValueType,
};
use rayon::prelude::*;
use std::sync::Arc;

fn shape_error(e: fusegraph_engine::value::ValueError) -> OpError {
    OpError::invalid(e.0)
}

macro_rules! op_struct {
    ($name:ident) => {
        pub(crate) struct $name(OpSpec);
    };
}

op_struct!(StretchOp);
op_struct!(OtsuOp);
op_struct!(IsosurfaceOp);
op_struct!(ComponentsOp);
op_struct!(SelectMarkersOp);
op_struct!(CentroidsOp);

impl StretchOp {
    pub(crate) fn new() -> Self {
        StretchOp(
            OpSpec::new(
                "mri.bright_stretch",
                1,
                "Percentile contrast stretch to [0, 1] (imadjust(V, stretchlim(V)))",
            )
            .input("volume", &[ValueType::Volume], "MR volume")
            .param(
                ParamSpec::float("low_percentile", 1.0, "%", "Percentile mapped to 0")
                    .range(0.0, 100.0),
            )
            .param(
                ParamSpec::float("high_percentile", 99.0, "%", "Percentile mapped to 1")
                    .range(0.0, 100.0),
            )
            .output(
                "volume",
                ValueType::Volume,
                "Stretched volume, values in [0, 1]",
            ),
        )
    }
}

impl Op for StretchOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let v = inputs.get::<Volume>("volume")?;
        let (low, high) = (
            params.float("low_percentile")?,
            params.float("high_percentile")?,
        );
        if low >= high {
            return Err(OpError::invalid(format!(
                "low_percentile {low} must be below high_percentile {high}"
            )));
        }
        let (lo, hi) = percentiles(&v.data, low, high)
            .ok_or_else(|| OpError::invalid("the volume has no numbers"))?;
        if hi <= lo {
            return Err(OpError::invalid(format!(
                "the volume is flat between the {low} and {high} percentiles (both {lo}); nothing to stretch"
            )));
        }
        ctx.metric("low_value", lo as f64);
        ctx.metric("high_value", hi as f64);
        let out = Volume::new(v.grid.clone(), stretch(&v.data, lo, hi)).map_err(shape_error)?;
        Ok(Outputs::new().with("volume", out))
    }
}

impl OtsuOp {
    pub(crate) fn new() -> Self {
        OtsuOp(
            OpSpec::new(
                "mri.otsu",
                2,
                "Otsu's threshold over the whole volume -> foreground mask",
            )
            .input("volume", &[ValueType::Volume], "Volume")
            .param(ParamSpec::int("bins", 256, "", "Histogram bins").range(2.0, 65536.0))
            .output(
                "mask",
                ValueType::Mask,
                "1 where the value is above the threshold",
            )
            .output(
                "threshold",
                ValueType::Scalar,
                "The threshold, in the volume's units",
            ),
        )
    }
}

impl Op for OtsuOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let v = inputs.get::<Volume>("volume")?;
        let t = otsu_threshold(&v.data, params.count("bins")?).ok_or_else(|| {
            OpError::invalid("the volume is flat: no threshold separates anything")
        })?;
        let mask: Vec<u8> = v.data.iter().map(|&x| (x > t) as u8).collect();
        let fraction = mask.iter().filter(|&&m| m == 1).count() as f64 / mask.len() as f64;
        ctx.metric("threshold", t as f64);
        ctx.metric("foreground_fraction", fraction);
        // The middle slice for the report, foreground tinted.
        let dims = v.grid.dims;
        let rgb = crate::plot::mask_over_slice(&v.data, &mask, dims, dims[2] / 2);
        if let Ok(png) = crate::plot::png_bytes(&rgb, dims[0], dims[1]) {
            ctx.figure(
                "mask",
                &format!(
                    "Otsu foreground (red) over the middle slice {} of {}",
                    dims[2] / 2,
                    dims[2]
                ),
                fusegraph_engine::figure::FigureData::Png(png),
            )?;
        }
        Ok(Outputs::new()
            .with(
                "mask",
                Mask::new(v.grid.clone(), mask).map_err(shape_error)?,
            )
            .with("threshold", t as f64))
    }
}

impl IsosurfaceOp {
    pub(crate) fn new() -> Self {
        IsosurfaceOp(
            OpSpec::new(
                "mri.isosurface",
                2,
                "Marching cubes: the surface value = level, in patient mm, closed",
            )
            .input(
                "volume",
                &[ValueType::Volume, ValueType::Mask],
                "Volume, or a mask (0/1)",
            )
            .optional_input(
                "level",
                &[ValueType::Scalar],
                "Level from another node (e.g. otsu.threshold); overrides `level`",
            )
            .param(ParamSpec::float(
                "level",
                0.5,
                "",
                "Iso-value (0.5 for a mask)",
            ))
            .param(
                ParamSpec::int(
                    "smooth_iterations",
                    0,
                    "",
                    "Taubin smoothing passes (0 = none)",
                )
                .range(0.0, 200.0),
            )
            .output(
                "mesh",
                ValueType::Mesh,
                "Triangle mesh, patient LPS mm, outward normals",
            ),
        )
    }
}

impl Op for IsosurfaceOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let (grid, values): (Grid, std::borrow::Cow<[f32]>) = match inputs.value("volume") {
            Some(Value::Volume(v)) => (v.grid.clone(), std::borrow::Cow::Borrowed(&v.data[..])),
            Some(Value::Mask(m)) => (
                m.grid.clone(),
                std::borrow::Cow::Owned(m.data.iter().map(|&x| x as f32).collect()),
            ),
            _ => {
                return Err(OpError::Input(
                    "volume".into(),
                    "expected a Volume or a Mask".into(),
                ));
            }
        };
        let level = match inputs.optional::<f64>("level")? {
            Some(l) => *l,
            None => params.float("level")?,
        };
        let mut mesh = marching_cubes(&values, &grid, level as f32);
        if mesh.triangles.is_empty() {
            return Err(OpError::invalid(format!(
                "no surface at level {level}: every voxel is on one side"
            )));
        }
        mesh.smooth(params.count("smooth_iterations")?);
        ctx.metric("vertices", mesh.vertices.len() as f64);
        ctx.metric("triangles", mesh.triangles.len() as f64);
        let (area, volume, normals) = mesh.area_volume_normals();
        ctx.metric("area_mm2", area);
        ctx.metric("volume_mm3", volume);
        let normals: Vec<f32> = normals.into_flattened();
        let out = Mesh::new(
            mesh.vertices.into_flattened(),
            mesh.triangles.into_flattened(),
            Some(normals.into()),
            "mri_lps",
        )
        .map_err(shape_error)?;
        Ok(Outputs::new().with("mesh", out))
    }
}

impl ComponentsOp {
    pub(crate) fn new() -> Self {
        ComponentsOp(
            OpSpec::new("mri.components", 1, "Connected components of a mask")
                .input("mask", &[ValueType::Mask], "Binary mask")
                .param(ParamSpec::int(
                    "connectivity",
                    26,
                    "",
                    "6, 18 or 26 neighbours",
                ))
                .output(
                    "labels",
                    ValueType::Labels,
                    "0 background, 1..count components in scan order",
                ),
        )
    }
}

impl Op for ComponentsOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let m = inputs.get::<Mask>("mask")?;
        let n = params.int("connectivity")?;
        let c = Connectivity::from_count(n)
            .ok_or_else(|| OpError::invalid(format!("connectivity {n}: use 6, 18 or 26")))?;
        let (labels, sizes) = label_components(&m.data, m.grid.dims, c);
        ctx.metric("count", (sizes.len() - 1) as f64);
        Ok(Outputs::new().with(
            "labels",
            Labels::new(m.grid.clone(), labels).map_err(shape_error)?,
        ))
    }
}

impl SelectMarkersOp {
    pub(crate) fn new() -> Self {
        SelectMarkersOp(
            OpSpec::new(
                "mri.select_markers",
                1,
                "Keep the components whose size fits a marker",
            )
            .input("labels", &[ValueType::Labels], "Components")
            .param(ParamSpec::float("min_volume_mm3", 10.0, "mm3", "Smallest kept").at_least(0.0))
            .param(ParamSpec::float("max_volume_mm3", 1000.0, "mm3", "Largest kept").at_least(0.0))
            .param(
                ParamSpec::int(
                    "expected",
                    0,
                    "",
                    "Keep at most this many, closest to target (0 = all)",
                )
                .at_least(0.0),
            )
            .param(
                ParamSpec::float(
                    "target_volume_mm3",
                    56.5,
                    "mm3",
                    "Expected marker (gel) volume",
                )
                .at_least(0.0),
            )
            .output(
                "labels",
                ValueType::Labels,
                "Kept components, renumbered 1..found",
            ),
        )
    }
}

impl Op for SelectMarkersOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let l = inputs.get::<Labels>("labels")?;
        let count = l.data.par_iter().copied().max().unwrap_or(0) as usize;
        // Integer counts: any split of the work gives the same sums.
        let sizes = l
            .data
            .par_chunks(1 << 16)
            .map(|chunk| {
                let mut sizes = vec![0usize; count + 1];
                chunk.iter().for_each(|&x| sizes[x as usize] += 1);
                sizes
            })
            .reduce(
                || vec![0usize; count + 1],
                |mut a, b| {
                    a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
                    a
                },
            );
        let s = l.grid.spacing_mm();
        let selection = MarkerSelection {
            min_volume_mm3: params.float("min_volume_mm3")?,
            max_volume_mm3: params.float("max_volume_mm3")?,
            expected: params.count("expected")?,
            target_volume_mm3: params.float("target_volume_mm3")?,
        };
        let kept = select_components(&sizes, s[0] * s[1] * s[2], &selection);
        let mut renumber = vec![0u32; count + 1];
        for (new, &old) in kept.iter().enumerate() {
            renumber[old as usize] = new as u32 + 1;
        }
        ctx.metric("found", kept.len() as f64);
        let labels: Vec<u32> = l.data.par_iter().map(|&x| renumber[x as usize]).collect();
        Ok(Outputs::new().with(
            "labels",
            Labels::new(l.grid.clone(), labels).map_err(shape_error)?,
        ))
    }
}

impl CentroidsOp {
    pub(crate) fn new() -> Self {
        CentroidsOp(
            OpSpec::new(
                "mri.centroids",
                1,
                "Centroid of each component, in patient mm",
            )
            .input("labels", &[ValueType::Labels], "Components (1..n)")
            .optional_input(
                "volume",
                &[ValueType::Volume],
                "Intensities for weighting (same grid)",
            )
            .param(ParamSpec::choice(
                "weighting",
                &["intensity", "binary"],
                "intensity (sub-voxel) or binary",
            ))
            .param(ParamSpec::float(
                "background",
                0.0,
                "",
                "Intensity counting as zero weight",
            ))
            .param(
                ParamSpec::int(
                    "dilate_voxels",
                    1,
                    "voxels",
                    "Grow components to take in partial-volume voxels",
                )
                .range(0.0, 5.0),
            )
            .output(
                "markers",
                ValueType::Markers,
                "Centres, patient LPS mm (frame mri_lps), ids = labels",
            ),
        )
    }
}

impl Op for CentroidsOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let l = inputs.get::<Labels>("labels")?;
        let volume: Option<Arc<Volume>> = inputs.optional("volume")?;
        let weighting = match params.string("weighting")?.as_str() {
            "binary" => Weighting::Binary,
            _ => {
                let v = volume.as_ref().ok_or_else(|| {
                    OpError::invalid(
                        "intensity weighting needs the `volume` input (or weighting = \"binary\")",
                    )
                })?;
                if v.grid.dims != l.grid.dims {
                    return Err(OpError::invalid(format!(
                        "volume is {:?} voxels but labels are {:?}",
                        v.grid.dims, l.grid.dims
                    )));
                }
                Weighting::Intensity {
                    background: params.float("background")? as f32,
                    dilate: params.count("dilate_voxels")?,
                }
            }
        };
        let count = l.data.iter().copied().max().unwrap_or(0) as usize;
        let centres = centroids(
            &l.data,
            count,
            &l.grid,
            volume.as_ref().map(|v| &v.data[..]),
            weighting,
        );
        ctx.metric("count", count as f64);
        let positions: Vec<f64> = centres.iter().flatten().copied().collect();
        let ids: Vec<u32> = (1..=count as u32).collect();
        Ok(Outputs::new().with(
            "markers",
            Markers::new(positions, ids, "mri_lps").map_err(shape_error)?,
        ))
    }
}
