//! Node adapters of the registration stage and the point cloud helpers.

use super::*;
use crate::camera::{isometry_from_matrix, isometry_to_matrix};
use crate::phantom::GroundTruth;
use fusegraph_engine::figure::FigureData;
use fusegraph_engine::value::{Markers, Mesh, PointCloud, Table, Transform};
use fusegraph_engine::{
    Inputs, Op, OpError, OpSpec, Outputs, ParamSpec, Params, RunCtx, ValueType,
};
use nalgebra::{Isometry3, Point3, Vector3};
use std::sync::Arc;

fn points3(flat: &[f64]) -> Vec<Point3<f64>> {
    flat.chunks(3)
        .map(|c| Point3::new(c[0], c[1], c[2]))
        .collect()
}

fn cloud_points(c: &PointCloud) -> Vec<Point3<f64>> {
    c.points
        .chunks(3)
        .map(|p| Point3::new(p[0] as f64, p[1] as f64, p[2] as f64))
        .collect()
}

fn cloud_normals(c: &PointCloud) -> Option<Vec<Vector3<f64>>> {
    c.normals.as_ref().map(|n| {
        n.chunks(3)
            .map(|v| Vector3::new(v[0] as f64, v[1] as f64, v[2] as f64))
            .collect()
    })
}

fn make_cloud(
    points: &[Point3<f64>],
    normals: Option<&[Vector3<f64>]>,
    colors: Option<Arc<[u8]>>,
    frame: &str,
) -> Result<PointCloud, OpError> {
    let p: Vec<f32> = points
        .iter()
        .flat_map(|q| [q.x as f32, q.y as f32, q.z as f32])
        .collect();
    let n = normals.map(|n| {
        n.iter()
            .flat_map(|v| [v.x as f32, v.y as f32, v.z as f32])
            .collect::<Vec<f32>>()
            .into()
    });
    PointCloud::new(p, colors, n, frame).map_err(|e| OpError::invalid(e.0))
}

/// The `source` and `target` markers and their positions.
type MarkerInputs = (
    Arc<Markers>,
    Arc<Markers>,
    Vec<Point3<f64>>,
    Vec<Point3<f64>>,
);

fn marker_inputs(inputs: &Inputs) -> Result<MarkerInputs, OpError> {
    let (s, t) = (
        inputs.get::<Markers>("source")?,
        inputs.get::<Markers>("target")?,
    );
    let (sp, tp) = (points3(&s.positions_mm), points3(&t.positions_mm));
    Ok((s, t, sp, tp))
}

/// A Transform value's isometry and frames.
pub(crate) fn transform_isometry(t: &Transform) -> Isometry3<f64> {
    isometry_from_matrix(&t.matrix)
}

fn transform_value(iso: &Isometry3<f64>, from: &str, to: &str) -> Transform {
    Transform {
        matrix: isometry_to_matrix(iso),
        from: from.into(),
        to: to.into(),
    }
}

macro_rules! op_struct {
    ($($name:ident),*) => { $(pub(crate) struct $name(OpSpec);)* };
}
op_struct!(
    MatchMarkersOp,
    ProcrustesOp,
    FromMeshOp,
    DownsampleOp,
    NormalsOp,
    TransformCloudOp,
    IcpOp,
    EvaluateOp,
    MultiviewOp
);

/// Views `register.multiview` accepts.
const MAX_VIEWS: usize = 8;

impl MatchMarkersOp {
    pub(crate) fn new() -> Self {
        MatchMarkersOp(
            OpSpec::new(
                "register.match_markers",
                1,
                "Marker correspondences without assumed order (triplet consensus)",
            )
            .input("source", &[ValueType::Markers], "Markers to map")
            .input("target", &[ValueType::Markers], "Markers to map onto")
            .param(
                ParamSpec::float(
                    "tolerance_mm",
                    3.0,
                    "mm",
                    "Largest distance of a matched pair after the fit",
                )
                .at_least(0.01),
            )
            .param(ParamSpec::bool(
                "scale",
                false,
                "Allow a uniform scale between the sets",
            ))
            .output(
                "source",
                ValueType::Markers,
                "Matched source markers, in pair order",
            )
            .output(
                "target",
                ValueType::Markers,
                "Matched target markers, in the same order",
            ),
        )
    }
}

impl Op for MatchMarkersOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let (s, t, sp, tp) = marker_inputs(inputs)?;
        let m = match_markers(&sp, &tp, params.float("tolerance_mm")?, params.bool("scale")?).ok_or_else(|| {
            OpError::invalid(format!(
                "fewer than 3 of the {} source and {} target markers can be matched within the tolerance",
                sp.len(),
                tp.len()
            ))
        })?;
        ctx.metric("inliers", m.pairs.len() as f64);
        ctx.metric("rmse_mm", m.rmse_mm);
        let pick = |pts: &[Point3<f64>],
                    ids: &[u32],
                    which: &dyn Fn(&(usize, usize)) -> usize,
                    frame: &str| {
            let pos: Vec<f64> = m
                .pairs
                .iter()
                .flat_map(|p| {
                    let q = pts[which(p)];
                    [q.x, q.y, q.z]
                })
                .collect();
            let id: Vec<u32> = m.pairs.iter().map(|p| ids[which(p)]).collect();
            Markers::new(pos, id, frame).map_err(|e| OpError::invalid(e.0))
        };
        Ok(Outputs::new()
            .with("source", pick(&sp, &s.ids, &|p| p.0, &s.frame)?)
            .with("target", pick(&tp, &t.ids, &|p| p.1, &t.frame)?))
    }
}

impl ProcrustesOp {
    pub(crate) fn new() -> Self {
        ProcrustesOp(
            OpSpec::new(
                "register.procrustes",
                1,
                "Least-squares similarity (Umeyama) between corresponding markers",
            )
            .input("source", &[ValueType::Markers], "Source markers")
            .input(
                "target",
                &[ValueType::Markers],
                "Target markers, same order",
            )
            .param(ParamSpec::bool(
                "scale",
                false,
                "Estimate a uniform scale (false: exactly 1)",
            ))
            .output(
                "transform",
                ValueType::Transform,
                "Source frame -> target frame",
            ),
        )
    }
}

impl Op for ProcrustesOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let (s, t, sp, tp) = marker_inputs(inputs)?;
        if sp.len() != tp.len() {
            return Err(OpError::invalid(format!(
                "{} source vs {} target markers: they must correspond one to one",
                sp.len(),
                tp.len()
            )));
        }
        let sim = umeyama(&sp, &tp, None, params.bool("scale")?)
            .ok_or_else(|| OpError::invalid("fewer than 3 markers, or all on one line"))?;
        ctx.metric("rmse_mm", sim.rmse(&sp, &tp));
        ctx.metric("scale", sim.scale);
        let m = sim.matrix();
        Ok(Outputs::new().with(
            "transform",
            Transform {
                matrix: std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)])),
                from: s.frame.clone(),
                to: t.frame.clone(),
            },
        ))
    }
}

impl FromMeshOp {
    pub(crate) fn new() -> Self {
        FromMeshOp(
            OpSpec::new(
                "cloud.from_mesh",
                1,
                "A point cloud from a mesh: its vertices, or points spread uniformly by area",
            )
            .input("mesh", &[ValueType::Mesh], "The mesh")
            .param(ParamSpec::choice(
                "mode",
                &["area", "vertices"],
                "area: uniform sampling; vertices: the vertices",
            ))
            .param(
                ParamSpec::int("points", 50_000, "", "Points to sample (area mode)")
                    .range(1.0, 1e8),
            )
            .param(ParamSpec::int("seed", 1, "", "Sampling seed").at_least(0.0))
            .output(
                "cloud",
                ValueType::PointCloud,
                "Points (with normals), in the mesh's frame",
            ),
        )
    }
}

impl Op for FromMeshOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let mesh = inputs.get::<Mesh>("mesh")?;
        let vertices: Vec<Point3<f64>> = mesh
            .vertices
            .chunks(3)
            .map(|v| Point3::new(v[0] as f64, v[1] as f64, v[2] as f64))
            .collect();
        let triangles: Vec<[u32; 3]> = mesh
            .triangles
            .chunks(3)
            .map(|t| [t[0], t[1], t[2]])
            .collect();
        let cloud = if params.string("mode")? == "vertices" {
            let normals: Option<Vec<Vector3<f64>>> = mesh.normals.as_ref().map(|n| {
                n.chunks(3)
                    .map(|v| Vector3::new(v[0] as f64, v[1] as f64, v[2] as f64))
                    .collect()
            });
            make_cloud(&vertices, normals.as_deref(), None, &mesh.frame)?
        } else {
            let (points, normals) = sample_mesh_with_normals(
                &vertices,
                &triangles,
                params.count("points")?,
                params.int("seed")? as u64,
            );
            make_cloud(&points, Some(&normals), None, &mesh.frame)?
        };
        ctx.metric("points", cloud.len() as f64);
        Ok(Outputs::new().with("cloud", cloud))
    }
}

/// Area-uniform samples with the normal of the triangle each lies on.
fn sample_mesh_with_normals(
    vertices: &[Point3<f64>],
    triangles: &[[u32; 3]],
    n: usize,
    seed: u64,
) -> (Vec<Point3<f64>>, Vec<Vector3<f64>>) {
    let points = sample_mesh(vertices, triangles, n, seed);
    // The sampled triangle is not returned; take the normal of the nearest
    // vertex's surroundings by PCA-free means: the nearest triangle centroid.
    let centroids: Vec<Point3<f64>> = triangles
        .iter()
        .map(|t| {
            Point3::from(
                (vertices[t[0] as usize].coords
                    + vertices[t[1] as usize].coords
                    + vertices[t[2] as usize].coords)
                    / 3.0,
            )
        })
        .collect();
    let tree = Nearest::new(&centroids);
    let normals = points
        .iter()
        .map(|p| {
            let Some(tree) = &tree else {
                return Vector3::z();
            };
            let t = triangles[tree.nearest(p).0];
            let [a, b, c] = t.map(|i| vertices[i as usize]);
            (b - a)
                .cross(&(c - a))
                .try_normalize(1e-30)
                .unwrap_or(Vector3::z())
        })
        .collect();
    (points, normals)
}

impl DownsampleOp {
    pub(crate) fn new() -> Self {
        DownsampleOp(
            OpSpec::new(
                "cloud.downsample",
                1,
                "Voxel-grid downsampling: one mean point per occupied cube",
            )
            .input("cloud", &[ValueType::PointCloud], "The cloud")
            .param(ParamSpec::float("voxel_mm", 2.0, "mm", "Cube side").at_least(1e-6))
            .output(
                "cloud",
                ValueType::PointCloud,
                "Downsampled cloud (no normals or colours)",
            ),
        )
    }
}

impl Op for DownsampleOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let c = inputs.get::<PointCloud>("cloud")?;
        let pts = voxel_downsample(&cloud_points(&c), params.float("voxel_mm")?);
        ctx.metric("points", pts.len() as f64);
        Ok(Outputs::new().with("cloud", make_cloud(&pts, None, None, &c.frame)?))
    }
}

pub(crate) struct RemovePlaneOp(OpSpec);

impl RemovePlaneOp {
    pub(crate) fn new() -> Self {
        RemovePlaneOp(
            OpSpec::new(
                "cloud.remove_plane",
                1,
                "Removes the dominant plane (the table under the object) and what lies beyond it, by RANSAC",
            )
            .input("cloud", &[ValueType::PointCloud], "The cloud (camera frame: the camera is at the origin)")
            .param(
                ParamSpec::float("threshold_mm", 3.0, "mm", "Points this close to the plane are on it")
                    .at_least(1e-3),
            )
            .param(
                ParamSpec::float(
                    "min_fraction",
                    0.2,
                    "",
                    "Remove the plane only if it holds at least this fraction of the points (else there is no table)",
                )
                .range(0.0, 1.0),
            )
            .param(ParamSpec::int("iterations", 300, "", "RANSAC trials").range(1.0, 100000.0))
            .param(ParamSpec::int("seed", 1, "", "RANSAC seed").at_least(0.0))
            .output(
                "cloud",
                ValueType::PointCloud,
                "The points off the plane on the camera's side (normals and colours kept)",
            ),
        )
    }
}

impl Op for RemovePlaneOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let c = inputs.get::<PointCloud>("cloud")?;
        let pts = cloud_points(&c);
        let threshold = params.float("threshold_mm")?;
        let found = dominant_plane(
            &pts,
            threshold,
            params.count("iterations")?,
            params.int("seed")? as u64,
        );
        let keep: Vec<bool> = match found {
            Some((plane, held))
                if held as f64 >= params.float("min_fraction")? * pts.len() as f64 =>
            {
                // The camera's side of the plane is where the origin is.
                let side = -plane.distance(&Point3::origin()).signum();
                ctx.metric("plane_fraction", held as f64 / pts.len() as f64);
                pts.iter()
                    .map(|p| side * plane.distance(p) < -threshold)
                    .collect()
            }
            _ => {
                ctx.metric("plane_fraction", 0.0);
                vec![true; pts.len()]
            }
        };
        let kept = keep.iter().filter(|k| **k).count();
        ctx.metric("points", kept as f64);
        Ok(Outputs::new().with("cloud", c.select(&keep).map_err(|e| OpError::invalid(e.0))?))
    }
}

pub(crate) struct RemoveColourOp(OpSpec);

impl RemoveColourOp {
    pub(crate) fn new() -> Self {
        let b = crate::stereo::BlobParams::default();
        RemoveColourOp(
            OpSpec::new(
                "cloud.remove_colour",
                1,
                "Removes the points of a colour (markers' faces) and every point within a radius of them (their walls)",
            )
            .input("cloud", &[ValueType::PointCloud], "A cloud with colours")
            .param(
                ParamSpec::float_list(
                    "hue_deg",
                    &[b.hue_deg.0, b.hue_deg.1],
                    "deg",
                    "Hue range [min, max]; min > max wraps through 0 (default: the markers' green, as stereo.hsv_markers)",
                )
                .range(0.0, 360.0)
                .length(2),
            )
            .param(
                ParamSpec::float("min_saturation", b.min_saturation, "", "Smallest saturation (0..1)")
                    .range(0.0, 1.0),
            )
            .param(ParamSpec::float("min_value", b.min_value, "", "Smallest value (0..1)").range(0.0, 1.0))
            .param(
                ParamSpec::float(
                    "radius_mm",
                    6.0,
                    "mm",
                    "Points this close to a coloured one go too (a marker's 5 mm wall)",
                )
                .at_least(0.0),
            )
            .output("cloud", ValueType::PointCloud, "The cloud without them"),
        )
    }
}

impl Op for RemoveColourOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let c = inputs.get::<PointCloud>("cloud")?;
        let Some(colors) = &c.colors else {
            return Err(OpError::invalid("the cloud has no colours to select by"));
        };
        let colour = crate::stereo::BlobParams {
            hue_deg: crate::stereo::hue_range(params)?,
            min_saturation: params.float("min_saturation")?,
            min_value: params.float("min_value")?,
            ..Default::default()
        };
        let keep = away_from_colour(
            &cloud_points(&c),
            colors,
            &colour,
            params.float("radius_mm")?,
        );
        let kept = keep.iter().filter(|k| **k).count();
        ctx.metric("removed", (keep.len() - kept) as f64);
        ctx.metric("points", kept as f64);
        Ok(Outputs::new().with("cloud", c.select(&keep).map_err(|e| OpError::invalid(e.0))?))
    }
}

impl NormalsOp {
    pub(crate) fn new() -> Self {
        NormalsOp(
            OpSpec::new(
                "cloud.normals",
                1,
                "Normals by PCA over the k nearest neighbours, oriented consistently",
            )
            .input("cloud", &[ValueType::PointCloud], "The cloud")
            .param(ParamSpec::int("k", 16, "", "Neighbours").range(3.0, 1000.0))
            .param(ParamSpec::choice(
                "orient",
                &["viewpoint", "outward"],
                "Towards the viewpoint, or away from the centroid",
            ))
            .param(
                ParamSpec::float_list(
                    "viewpoint_mm",
                    &[0.0, 0.0, 0.0],
                    "mm",
                    "Viewpoint (the camera centre is the origin of camera frames)",
                )
                .length(3),
            )
            .output(
                "cloud",
                ValueType::PointCloud,
                "The cloud with unit normals",
            ),
        )
    }
}

impl Op for NormalsOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, _: &mut RunCtx) -> Result<Outputs, OpError> {
        let c = inputs.get::<PointCloud>("cloud")?;
        let v = params.float_list("viewpoint_mm")?;
        let viewpoint = match (params.string("orient")?.as_str(), v.as_slice()) {
            ("viewpoint", &[x, y, z]) => Some(Point3::new(x, y, z)),
            ("viewpoint", _) => return Err(OpError::invalid("viewpoint_mm takes x, y, z")),
            _ => None,
        };
        let pts = cloud_points(&c);
        let normals = estimate_normals(&pts, params.count("k")?, viewpoint);
        Ok(Outputs::new().with(
            "cloud",
            make_cloud(&pts, Some(&normals), c.colors.clone(), &c.frame)?,
        ))
    }
}

impl TransformCloudOp {
    pub(crate) fn new() -> Self {
        TransformCloudOp(
            OpSpec::new(
                "cloud.transform",
                1,
                "Move a cloud by a transform (or its inverse) into another frame",
            )
            .input("cloud", &[ValueType::PointCloud], "The cloud")
            .input("transform", &[ValueType::Transform], "The transform")
            .param(ParamSpec::bool(
                "invert",
                false,
                "Apply the inverse (to -> from)",
            ))
            .output(
                "cloud",
                ValueType::PointCloud,
                "The moved cloud, in the transform's other frame",
            ),
        )
    }
}

impl Op for TransformCloudOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, _: &mut RunCtx) -> Result<Outputs, OpError> {
        let c = inputs.get::<PointCloud>("cloud")?;
        let t = inputs.get::<Transform>("transform")?;
        let invert = params.bool("invert")?;
        let (iso, from, to) = if invert {
            (transform_isometry(&t).inverse(), &t.to, &t.from)
        } else {
            (transform_isometry(&t), &t.from, &t.to)
        };
        if &c.frame != from {
            return Err(OpError::invalid(format!(
                "the cloud is in frame `{}`, the transform maps from `{from}`",
                c.frame
            )));
        }
        let pts: Vec<Point3<f64>> = cloud_points(&c).iter().map(|p| iso * p).collect();
        let normals =
            cloud_normals(&c).map(|n| n.iter().map(|v| iso.rotation * v).collect::<Vec<_>>());
        Ok(Outputs::new().with(
            "cloud",
            make_cloud(&pts, normals.as_deref(), c.colors.clone(), to)?,
        ))
    }
}

impl IcpOp {
    pub(crate) fn new() -> Self {
        IcpOp(
            OpSpec::new(
                "register.icp",
                2,
                "Iterative closest point: source cloud onto target cloud",
            )
            .input("source", &[ValueType::PointCloud], "Cloud to move")
            .input(
                "target",
                &[ValueType::PointCloud],
                "Cloud to move onto (normals for point-to-plane)",
            )
            .optional_input(
                "init",
                &[ValueType::Transform],
                "Start (source -> target), e.g. from markers",
            )
            .param(ParamSpec::choice(
                "method",
                &["point_to_plane", "point_to_point"],
                "Error metric",
            ))
            .param(
                ParamSpec::float(
                    "max_distance_mm",
                    5.0,
                    "mm",
                    "Pairs farther apart are ignored",
                )
                .at_least(1e-3),
            )
            .param(
                ParamSpec::float("trim_ratio", 0.9, "", "Fraction of closest pairs kept")
                    .range(0.05, 1.0),
            )
            .param(ParamSpec::choice(
                "kernel",
                &["huber", "tukey", "none"],
                "Robust kernel",
            ))
            .param(
                ParamSpec::float(
                    "kernel_mm",
                    1.5,
                    "mm",
                    "Kernel threshold (Huber k, Tukey c)",
                )
                .at_least(1e-6),
            )
            .param(
                ParamSpec::int("max_iterations", 50, "", "Iterations per scale")
                    .range(1.0, 10000.0),
            )
            .param(
                ParamSpec::float(
                    "tolerance",
                    1e-6,
                    "",
                    "Relative change of RMSE and fitness that stops it",
                )
                .at_least(0.0),
            )
            .param(
                ParamSpec::float_list(
                    "voxel_sizes_mm",
                    &[],
                    "mm",
                    "Coarse-to-fine source voxel sizes (0 = full)",
                )
                .at_least(0.0),
            )
            .output(
                "transform",
                ValueType::Transform,
                "Source frame -> target frame",
            )
            .output(
                "trace",
                ValueType::Table,
                "iteration, voxel_mm, rmse_mm, fitness, pairs",
            ),
        )
    }
}

impl Op for IcpOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let (s, t) = (
            inputs.get::<PointCloud>("source")?,
            inputs.get::<PointCloud>("target")?,
        );
        let init = match inputs.optional::<Transform>("init")? {
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
        let k = params.float("kernel_mm")?;
        let p = IcpParams {
            method: if params.string("method")? == "point_to_point" {
                IcpMethod::PointToPoint
            } else {
                IcpMethod::PointToPlane
            },
            max_distance_mm: params.float("max_distance_mm")?,
            trim_ratio: params.float("trim_ratio")?,
            kernel: match params.string("kernel")?.as_str() {
                "huber" => Kernel::Huber(k),
                "tukey" => Kernel::Tukey(k),
                _ => Kernel::None,
            },
            max_iterations: params.count("max_iterations")?,
            tolerance: params.float("tolerance")?,
            voxel_sizes_mm: params.float_list("voxel_sizes_mm")?,
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
        Ok(Outputs::new()
            .with(
                "transform",
                transform_value(&r.transform, &s.frame, &t.frame),
            )
            .with("trace", trace))
    }
}

impl EvaluateOp {
    pub(crate) fn new() -> Self {
        EvaluateOp(
            OpSpec::new("register.evaluate", 2, "Registration quality: RMSE over the overlap, and with the truth, TRE at the lesions; a 3D view of the fused clouds for the report")
                .input("transform", &[ValueType::Transform], "Source -> target")
                .input("source", &[ValueType::PointCloud], "Source cloud")
                .input("target", &[ValueType::PointCloud], "Target cloud")
                .optional_input("truth", &[ValueType::Path], "ground_truth.json (frames mri_lps and camera_left of `view`)")
                .optional_input("targets", &[ValueType::Markers], "Targets to mark in the 3D view (in the source's or the target's frame)")
                .param(ParamSpec::float("overlap_mm", 10.0, "mm", "Source points farther than this from the target are not overlap").at_least(0.0))
                .param(ParamSpec::float("inlier_mm", 2.0, "mm", "Pairs closer than this are inliers").at_least(0.0))
                .param(ParamSpec::int("view", 0, "", "Phantom view whose left camera is camera_left").at_least(0.0))
                .output("rmse_mm", ValueType::Scalar, "RMSE of the inliers, mm"),
        )
    }
}

/// The true MRI -> left camera transform of phantom view `view`.
pub(crate) fn true_mri_to_camera(
    truth: &GroundTruth,
    view: usize,
) -> Result<Isometry3<f64>, OpError> {
    let v = truth.views.get(view).ok_or_else(|| {
        OpError::invalid(format!(
            "view {view} does not exist ({} views)",
            truth.views.len()
        ))
    })?;
    Ok(isometry_from_matrix(&v.left_camera_to_world).inverse()
        * isometry_from_matrix(&truth.mri_to_world))
}

impl Op for EvaluateOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let t = inputs.get::<Transform>("transform")?;
        let (s, g) = (
            inputs.get::<PointCloud>("source")?,
            inputs.get::<PointCloud>("target")?,
        );
        let iso = transform_isometry(&t);
        let tree = Nearest::new(&cloud_points(&g))
            .ok_or_else(|| OpError::invalid("the target cloud is empty"))?;
        let d: Vec<f64> = cloud_points(&s)
            .iter()
            .map(|p| tree.nearest(&(iso * p)).1.sqrt())
            .collect();
        let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
        let (overlap_mm, inlier_mm) = (params.float("overlap_mm")?, params.float("inlier_mm")?);
        let overlap: Vec<f64> = d.iter().copied().filter(|&x| x <= overlap_mm).collect();
        let inliers: Vec<f64> = overlap
            .iter()
            .copied()
            .filter(|&x| x <= inlier_mm)
            .collect();
        fused_view(
            ctx,
            &s,
            &g,
            &iso,
            inputs.optional::<Markers>("targets")?.as_deref(),
        )?;
        ctx.metric("rmse_all_mm", rms(&overlap));
        ctx.metric("rmse_mm", rms(&inliers));
        ctx.metric(
            "inlier_fraction",
            inliers.len() as f64 / d.len().max(1) as f64,
        );
        if let Some(truth) = crate::phantom::optional_truth_input(inputs)? {
            let truth_mc = true_mri_to_camera(&truth, params.count("view")?)?;
            let est_mc = match (t.from.as_str(), t.to.as_str()) {
                ("mri_lps", "camera_left") => iso,
                ("camera_left", "mri_lps") => iso.inverse(),
                (a, b) => {
                    return Err(OpError::invalid(format!(
                        "transform maps `{a}` -> `{b}`; the truth knows mri_lps <-> camera_left"
                    )));
                }
            };
            // Errors where the robot acts: positions in camera space.
            let errors: Vec<f64> = truth
                .lesions
                .iter()
                .map(|l| {
                    (est_mc * Point3::from(l.center_mri_mm)
                        - truth_mc * Point3::from(l.center_mri_mm))
                    .norm()
                })
                .collect();
            ctx.metric(
                "tre_mm",
                errors.iter().sum::<f64>() / errors.len().max(1) as f64,
            );
            ctx.metric("tre_max_mm", errors.iter().copied().fold(0.0, f64::max));
            ctx.metric(
                "rotation_error_deg",
                est_mc.rotation.angle_to(&truth_mc.rotation).to_degrees(),
            );
            let centre = isometry_from_matrix(&truth.phantom_to_mri) * Point3::new(0.0, 0.0, 25.0);
            ctx.metric(
                "translation_error_mm",
                (est_mc * centre - truth_mc * centre).norm(),
            );
        }
        Ok(Outputs::new().with("rmse_mm", rms(&inliers)))
    }
}

/// The fused result in the source's frame (the camera's, for MRI onto camera)
/// as a 3D view for the report: the source cloud in its colours (grey
/// without), the target mapped into it in blue, targets as red balls.
fn fused_view(
    ctx: &mut RunCtx,
    source: &PointCloud,
    target: &PointCloud,
    source_to_target: &Isometry3<f64>,
    targets: Option<&Markers>,
) -> Result<(), OpError> {
    const MAX_POINTS: usize = 40_000;
    let (mut xyz, mut rgb) = (Vec::new(), Vec::new());
    let mut push = |p: &Point3<f64>, c: [u8; 3]| {
        xyz.extend([p.x as f32, p.y as f32, p.z as f32]);
        rgb.extend(c);
    };
    let step = (source.len() / MAX_POINTS).max(1);
    for (i, p) in cloud_points(source).iter().enumerate().step_by(step) {
        let c = source
            .colors
            .as_ref()
            .map_or([200, 200, 200], |c| [c[3 * i], c[3 * i + 1], c[3 * i + 2]]);
        push(p, c);
    }
    let back = source_to_target.inverse();
    let step = (target.len() / MAX_POINTS).max(1);
    for p in cloud_points(target).iter().step_by(step) {
        push(&(back * p), [70, 130, 255]);
    }
    if let Some(t) = targets {
        let into_source = if t.frame == target.frame {
            back
        } else {
            Isometry3::identity()
        };
        for c in t.positions_mm.chunks(3) {
            let centre = into_source * Point3::new(c[0], c[1], c[2]);
            // A ball of 2 mm radius on a 0.5 mm grid.
            for i in -4..=4 {
                for j in -4..=4 {
                    for k in -4..=4 {
                        let d = Vector3::new(i as f64, j as f64, k as f64) * 0.5;
                        if d.norm() <= 2.0 {
                            push(&(centre + d), [255, 40, 40]);
                        }
                    }
                }
            }
        }
    }
    ctx.figure(
        "fused",
        "The fused result in the source's frame: source cloud (its colours), target mapped onto it (blue), targets (red)",
        FigureData::Points3d { xyz, rgb },
    )
}

/// The ICP trace plot and the clouds before and after, for the report.
fn icp_figures(
    ctx: &mut RunCtx,
    trace: &Table,
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    init: &Isometry3<f64>,
    fin: &Isometry3<f64>,
) -> Result<(), OpError> {
    let plot = crate::plot::LinePlot {
        x: "iteration".into(),
        y: vec!["rmse_mm".into()],
        title: "ICP: RMSE of the kept pairs".into(),
        x_label: "iteration (all voxel stages)".into(),
        y_label: "RMSE, mm".into(),
        log_x: false,
        log_y: false,
        size_px: (700, 380),
    };
    if let Ok(png) = crate::plot::lines_png(trace, &plot) {
        ctx.figure(
            "trace",
            "ICP: RMSE of the kept pairs by iteration",
            FigureData::Png(png),
        )?;
    }
    // At most 20,000 points of each cloud: enough to see the fit.
    let thin = |pts: &[Point3<f64>], iso: &Isometry3<f64>| -> Vec<Point3<f64>> {
        let step = (pts.len() / 20_000).max(1);
        pts.iter().step_by(step).map(|p| iso * p).collect()
    };
    let (before, after) = (thin(source, init), thin(source, fin));
    let target = thin(target, &Isometry3::identity());
    if let Some((rgb, w, h)) = crate::plot::overlay_panels(&target, &[&before, &after], 420)
        && let Ok(png) = crate::plot::png_bytes(&rgb, w, h)
    {
        ctx.figure(
            "before_after",
            "Side view: source (orange) over target (grey), from the initial transform (left) and after ICP (right)",
            FigureData::Png(png),
        )?;
    }
    Ok(())
}

impl MultiviewOp {
    pub(crate) fn new() -> Self {
        let mut spec = OpSpec::new(
            "register.multiview",
            3,
            "Several camera clouds (and their markers) with rough poses -> one cloud and one marker set: pairwise ICP around the ring, then global adjustment",
        );
        for i in 0..MAX_VIEWS {
            let doc = format!("View {i}'s cloud, in its camera frame");
            let pose_doc = format!(
                "View {i}'s rough camera -> world pose (e.g. the robot's reading); without poses, they come from the markers"
            );
            spec = if i < 2 {
                spec.input(&format!("cloud{i}"), &[ValueType::PointCloud], &doc)
            } else {
                spec.optional_input(&format!("cloud{i}"), &[ValueType::PointCloud], &doc)
            }
            .optional_input(&format!("pose{i}"), &[ValueType::Transform], &pose_doc);
            spec = spec.optional_input(
                &format!("markers{i}"),
                &[ValueType::Markers],
                &format!("View {i}'s markers, in its cloud's frame"),
            );
        }
        MultiviewOp(
            spec.param(
                ParamSpec::float(
                    "max_distance_mm",
                    8.0,
                    "mm",
                    "ICP: pairs farther apart are ignored",
                )
                .at_least(1e-3),
            )
            .param(
                ParamSpec::float("trim_ratio", 0.8, "", "ICP: fraction of closest pairs kept")
                    .range(0.05, 1.0),
            )
            .param(ParamSpec::float("kernel_mm", 1.0, "mm", "ICP: Huber threshold").at_least(1e-6))
            .param(
                ParamSpec::float_list(
                    "voxel_sizes_mm",
                    &[4.0, 0.0],
                    "mm",
                    "ICP: coarse-to-fine voxel sizes (0 = full)",
                )
                .at_least(0.0),
            )
            .param(ParamSpec::int("rounds", 2, "", "Rounds of global adjustment").range(1.0, 20.0))
            .param(
                ParamSpec::float(
                    "tolerance",
                    1e-5,
                    "",
                    "ICP: relative change of RMSE and fitness that stops it (tighter only slows it: on 100k-point clouds the fitness moves by single pairs)",
                )
                .at_least(0.0),
            )
            .param(ParamSpec::choice(
                "frame",
                &["world", "first_view"],
                "Frame of the outputs: world (the poses' frame), or the first view's camera frame (its refined pose taken as the origin)",
            ))
            .param(
                ParamSpec::float(
                    "merge_mm",
                    4.0,
                    "mm",
                    "Marker sightings from different views closer than this are one marker",
                )
                .at_least(0.0),
            )
            .param(
                ParamSpec::int(
                    "normals_k",
                    12,
                    "",
                    "Neighbours for normals of clouds without them",
                )
                .range(3.0, 200.0),
            )
            .output(
                "cloud",
                ValueType::PointCloud,
                "All views in the output frame, coloured by view",
            )
            .output(
                "poses",
                ValueType::Table,
                "view, then the 3 x 4 camera -> output frame matrix row by row (mm)",
            )
            .output(
                "markers",
                ValueType::Markers,
                "Every view's markers in the output frame, sightings of one marker merged (empty without marker inputs)",
            ),
        )
    }
}

impl Op for MultiviewOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let k = params.count("normals_k")?;
        let (mut views, mut rough, mut markers) = (Vec::new(), Vec::new(), Vec::new());
        let mut frame = String::new();
        for i in 0..MAX_VIEWS {
            let cloud = inputs.optional::<PointCloud>(&format!("cloud{i}"))?;
            let pose = inputs.optional::<Transform>(&format!("pose{i}"))?;
            let seen = inputs.optional::<Markers>(&format!("markers{i}"))?;
            match (cloud, pose) {
                (Some(c), pose) => {
                    if let Some(m) = &seen
                        && m.frame != c.frame
                    {
                        return Err(OpError::invalid(format!(
                            "markers{i} are in `{}` but cloud{i} in `{}`",
                            m.frame, c.frame
                        )));
                    }
                    markers.push(seen.map(|m| {
                        m.positions_mm
                            .chunks(3)
                            .map(|p| Point3::new(p[0], p[1], p[2]))
                            .collect::<Vec<_>>()
                    }));
                    if frame.is_empty() {
                        frame = c.frame.clone();
                    }
                    if let Some(t) = &pose
                        && (t.from != c.frame || t.to != "world")
                    {
                        return Err(OpError::invalid(format!(
                            "pose{i} maps `{}` -> `{}`; it must map the cloud's frame `{}` -> `world`",
                            t.from, t.to, c.frame
                        )));
                    }
                    let points = cloud_points(&c);
                    let normals = match cloud_normals(&c) {
                        Some(n) => n,
                        None => estimate_normals(&points, k, Some(Point3::origin())),
                    };
                    views.push(View { points, normals });
                    rough.push(pose.map(|t| transform_isometry(&t)));
                }
                (None, None) if seen.is_none() => {}
                _ => {
                    return Err(OpError::invalid(format!(
                        "view {i}: pose{i} or markers{i} without cloud{i}"
                    )));
                }
            }
        }
        // Rough poses: all given, or none (then from the markers).
        let rough: Vec<Isometry3<f64>> = if rough.iter().all(Option::is_some) {
            rough.into_iter().flatten().collect()
        } else if rough.iter().all(Option::is_none) {
            let sets: Option<Vec<Vec<Point3<f64>>>> = markers.iter().cloned().collect();
            let sets = sets.ok_or_else(|| {
                OpError::invalid("without poses, connect every view's markers (markers0 ...)")
            })?;
            poses_from_markers(&sets, params.float("merge_mm")?).map_err(OpError::invalid)?
        } else {
            return Err(OpError::invalid(
                "connect a pose for every view or for none (then they come from the markers)",
            ));
        };
        let p = IcpParams {
            method: IcpMethod::PointToPlane,
            max_distance_mm: params.float("max_distance_mm")?,
            trim_ratio: params.float("trim_ratio")?,
            kernel: Kernel::Huber(params.float("kernel_mm")?),
            max_iterations: 40,
            tolerance: params.float("tolerance")?,
            voxel_sizes_mm: params.float_list("voxel_sizes_mm")?,
        };
        let mut m = register_views(&views, &rough, &p, params.count("rounds")?)
            .map_err(OpError::invalid)?;
        let out_frame = if params.string("frame")? == "first_view" {
            let origin = m.poses[0].inverse();
            for pose in &mut m.poses {
                *pose = origin * *pose;
            }
            frame
        } else {
            "world".to_string()
        };
        let sightings: Vec<(Vec<Point3<f64>>, Isometry3<f64>)> = markers
            .into_iter()
            .zip(&m.poses)
            .filter_map(|(seen, pose)| seen.map(|s| (s, *pose)))
            .collect();
        let merged = merge_markers(&sightings, params.float("merge_mm")?);
        ctx.metric("markers", merged.len() as f64);
        ctx.metric(
            "marker_spread_max_mm",
            merged.iter().map(|m| m.spread_mm).fold(0.0, f64::max),
        );
        let merged_markers = Markers::new(
            merged
                .iter()
                .flat_map(|m| [m.position.x, m.position.y, m.position.z])
                .collect::<Vec<f64>>(),
            (0..merged.len() as u32).collect::<Vec<u32>>(),
            &out_frame,
        )
        .map_err(|e| OpError::invalid(e.0))?;
        let rmse = m.view_rmse_mm.iter().sum::<f64>() / m.view_rmse_mm.len() as f64;
        ctx.metric("rmse_mm", rmse);
        ctx.metric("views", views.len() as f64);
        for (i, r) in m.pairwise_rmse_mm.iter().enumerate() {
            ctx.metric(&format!("pair_{i}_rmse_mm"), *r);
        }
        let palette: [[u8; 3]; MAX_VIEWS] = [
            [230, 90, 60],
            [60, 160, 230],
            [90, 200, 90],
            [230, 200, 60],
            [180, 90, 220],
            [60, 210, 200],
            [240, 140, 190],
            [150, 150, 150],
        ];
        let (mut pts, mut colors) = (Vec::new(), Vec::new());
        let mut table = Vec::new();
        for (i, (view, pose)) in views.iter().zip(&m.poses).enumerate() {
            pts.extend(view.points.iter().map(|p| pose * p));
            colors.extend(std::iter::repeat_n(palette[i], view.points.len()).flatten());
            let h = pose.to_homogeneous();
            table.push(i as f64);
            table.extend((0..3).flat_map(|r| (0..4).map(move |c| h[(r, c)])));
        }
        let columns: Vec<String> = std::iter::once("view".to_string())
            .chain((0..3).flat_map(|r| (0..4).map(move |c| format!("m{r}{c}"))))
            .collect();
        let poses = Table::new(columns, table).map_err(|e| OpError::invalid(e.0))?;
        Ok(Outputs::new()
            .with(
                "cloud",
                make_cloud(&pts, None, Some(colors.into()), &out_frame)?,
            )
            .with("poses", poses)
            .with("markers", merged_markers))
    }
}

pub(crate) struct MapTargetsOp(OpSpec);

impl MapTargetsOp {
    pub(crate) fn new() -> Self {
        MapTargetsOp(
            OpSpec::new(
                "register.map_targets",
                1,
                "Targets marked in MRI (lesions) mapped into camera (robot) space with a registration",
            )
            .input(
                "targets",
                &[ValueType::Markers],
                "Targets, mm, in one frame of the transform (e.g. mri_lps)",
            )
            .input(
                "transform",
                &[ValueType::Transform],
                "The registration, either way between the targets' frame and the camera's",
            )
            .optional_input(
                "truth",
                &[ValueType::Path],
                "ground_truth.json: the targets' true camera positions (targets in mri_lps, camera_left of `view`)",
            )
            .param(ParamSpec::int("view", 0, "", "Phantom view whose left camera is camera_left").at_least(0.0))
            .output(
                "targets",
                ValueType::Markers,
                "The targets in the transform's other frame (camera_left), same ids",
            ),
        )
    }
}

/// `targets` (frame `from`) through `transform` in whichever direction starts
/// at `from`: the mapped points and the frame they are in.
pub fn map_targets(
    targets: &[Point3<f64>],
    from: &str,
    transform: &Transform,
) -> Result<(Vec<Point3<f64>>, String), String> {
    let iso = transform_isometry(transform);
    let (iso, to) = if transform.from == from {
        (iso, transform.to.clone())
    } else if transform.to == from {
        (iso.inverse(), transform.from.clone())
    } else {
        return Err(format!(
            "the targets are in `{from}` but the transform maps `{}` -> `{}`",
            transform.from, transform.to
        ));
    };
    Ok((targets.iter().map(|p| iso * p).collect(), to))
}

impl Op for MapTargetsOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let targets = inputs.get::<Markers>("targets")?;
        let transform = inputs.get::<Transform>("transform")?;
        let points: Vec<Point3<f64>> = targets
            .positions_mm
            .chunks(3)
            .map(|p| Point3::new(p[0], p[1], p[2]))
            .collect();
        let (mapped, frame) =
            map_targets(&points, &targets.frame, &transform).map_err(OpError::invalid)?;
        ctx.metric("targets", mapped.len() as f64);
        if let Some(truth) = crate::phantom::optional_truth_input(inputs)? {
            if targets.frame != "mri_lps" || frame != "camera_left" {
                return Err(OpError::invalid(format!(
                    "with a truth, targets map mri_lps -> camera_left, not `{}` -> `{frame}`",
                    targets.frame
                )));
            }
            let truth_mc = true_mri_to_camera(&truth, params.count("view")?)?;
            let errors: Vec<f64> = points
                .iter()
                .zip(&mapped)
                .map(|(p, m)| (truth_mc * p - m).norm())
                .collect();
            ctx.metric(
                "target_error_mm",
                errors.iter().sum::<f64>() / errors.len().max(1) as f64,
            );
            ctx.metric(
                "target_error_max_mm",
                errors.iter().copied().fold(0.0, f64::max),
            );
        }
        let out = Markers::new(
            mapped
                .iter()
                .flat_map(|p| [p.x, p.y, p.z])
                .collect::<Vec<f64>>(),
            targets.ids.to_vec(),
            &frame,
        )
        .map_err(|e| OpError::invalid(e.0))?;
        Ok(Outputs::new().with("targets", out))
    }
}

#[cfg(test)]
mod map_targets_tests {
    use super::*;

    #[test]
    fn targets_go_through_the_transform_either_way() {
        let iso = Isometry3::new(Vector3::new(10.0, -5.0, 400.0), Vector3::new(0.0, 0.2, 0.0));
        let t = Transform {
            matrix: isometry_to_matrix(&iso),
            from: "mri_lps".into(),
            to: "camera_left".into(),
        };
        let p = [Point3::new(1.0, 2.0, 3.0)];
        let (m, frame) = map_targets(&p, "mri_lps", &t).unwrap();
        assert_eq!(frame, "camera_left");
        assert!((m[0] - iso * p[0]).norm() < 1e-12);
        let (back, frame) = map_targets(&m, "camera_left", &t).unwrap();
        assert_eq!(frame, "mri_lps");
        assert!((back[0] - p[0]).norm() < 1e-9);
        let e = map_targets(&p, "world", &t).unwrap_err();
        assert!(e.contains("`world`"), "{e}");
    }
}
