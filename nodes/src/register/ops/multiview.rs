//! `register.multiview`: several camera clouds into one.

use crate::calib::{
    RigModel, covariances_for_ids, perturbed_rigs_from_table, triangulation_shifts,
};
use crate::cloud::convert::{cloud_normals, cloud_points, make_cloud};
use crate::cloud::estimate_normals;
use crate::register::convert::{
    empty_pose_covariance, marker_points, markers_value, pose_covariance_table, transform_isometry,
};
use crate::register::{
    IcpMethod, IcpParams, Kernel, MarkerAnchoring, MergeParams, View, ViewMarkers,
    carried_pose_covariance, first_view_spread, mapped_point_covariance, markers_frame_spread,
    merge_markers_weighted, poses_from_markers, register_views,
};
use fusegraph_engine::Inputs;
use fusegraph_engine::typed::declaration::{
    InputPort, InputSet, PortDecl, PortProblem, port, read_input,
};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Markers, PointCloud, StereoRig, Table, Transform};
use nalgebra::{Isometry3, Matrix3, Point3, Vector3};

/// The port of the rig that took every view, and of its parameter covariance.
const RIG_PORT: &str = "rig";
const RIG_COVARIANCE_PORT: &str = "rig_covariance";

/// Views `register.multiview` accepts.
pub const MAX_VIEWS: usize = 8;

/// Several camera clouds (and their markers) with rough poses -> one cloud and one marker set: pairwise ICP around the ring, then global adjustment
#[derive(Op)]
// 7: the merged set's frame covariance (`covariance`).
// 8: skipped (an abandoned experiment ran under it; old caches may hold its results)
// 9: every block's residuals corrected for its leverage in that covariance.
// 10: markers weighed by their covariances (`marker_covariance{i}`).
// 11: the frame covariance from the markers' joint adjustment; the rig's
//     calibration spread joins the markers' weights (`rig`, `rig_covariance`).
#[op(name = "register.multiview", version = 11)]
pub struct Multiview {
    /// ICP: pairs farther apart are ignored
    #[param(default = 8.0, unit = "mm", min = 1e-3)]
    pub max_distance_mm: f64,
    /// ICP: fraction of closest pairs kept
    #[param(default = 0.8, min = 0.05, max = 1.0)]
    pub trim_ratio: f64,
    /// ICP: Huber threshold
    #[param(default = 1.0, unit = "mm", min = 1e-6)]
    pub kernel_mm: f64,
    /// ICP: coarse-to-fine voxel sizes (0 = full)
    #[param(default = [4.0, 0.0], unit = "mm", min = 0.0)]
    pub voxel_sizes_mm: Vec<f64>,
    /// Rounds of global adjustment
    #[param(default = 2, min = 1, max = 20)]
    pub rounds: usize,
    /// ICP: relative change of RMSE and fitness that stops it (tighter only slows it: on 100k-point clouds the fitness moves by single pairs)
    #[param(default = 1e-5, min = 0.0)]
    pub tolerance: f64,
    /// Frame of the outputs: world (the poses' frame), or the first view's camera frame (its refined pose taken as the origin)
    #[param(default = OutputFrame::World)]
    pub frame: OutputFrame,
    /// Marker sightings from different views closer than this are one marker
    #[param(default = 4.0, unit = "mm", min = 0.0)]
    pub merge_mm: f64,
    /// A sighting farther than this from the median of the other views' sightings of its marker anchors nothing in the adjustment, and (seen in 3 views or more) is dropped from the merge, as is a marker seen once within twice merge_mm of one seen more often: a marker partly hidden or cut by a highlight is measured off
    #[param(default = 2.5, unit = "mm", min = 0.0)]
    pub outlier_mm: f64,
    /// Neighbours for normals of clouds without them
    #[param(default = 12, min = 3, max = 200)]
    pub normals_k: usize,
    /// Weight of the markers two views share, all together, against their
    /// surface pairs in the registration (0 = surfaces alone)
    #[param(default = 1.0, min = 0.0)]
    pub marker_weight: f64,
    /// The first view's spread: its surface's errors taken as correlated
    /// within cubes of this side (its matching windows and smoothing)
    #[param(default = 20.0, unit = "mm", min = 0.0)]
    pub error_block_mm: f64,
}

/// The frame of `register.multiview`'s outputs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Choice)]
pub enum OutputFrame {
    /// The poses' frame, `world`.
    World,
    /// The first view's camera frame (its refined pose taken as the origin).
    FirstView,
}

/// One view's ports: `cloud{i}`, `pose{i}` and `markers{i}`.
pub struct ViewInputs {
    /// The view's cloud, in its camera frame (always there for views 0 and 1).
    pub cloud: Option<Arc<PointCloud>>,
    /// Its rough camera -> world pose.
    pub pose: Option<Arc<Transform>>,
    /// Its markers, in its cloud's frame.
    pub markers: Option<Arc<Markers>>,
    /// Its markers' covariances (`stereo.hsv_markers`' `localisation_covariance`).
    pub marker_covariance: Option<Arc<Table>>,
}

/// The inputs: [`MAX_VIEWS`] views, each `cloud{i}`, `pose{i}`, `markers{i}`,
/// `marker_covariance{i}` in that order, the first two clouds required. The ports are computed, so
/// this set is written by hand rather than derived.
pub struct MultiviewInputs {
    /// View `i`'s ports at index `i`, for every `i` below [`MAX_VIEWS`].
    pub views: Vec<ViewInputs>,
    /// The rig that took every view.
    pub rig: Option<Arc<StereoRig>>,
    /// Its parameter covariance (`calib.stereo_calibrate`'s `covariance`).
    pub rig_covariance: Option<Arc<Table>>,
}

impl<'a> InputSet<'a, Inputs> for MultiviewInputs {
    fn port_decls() -> Vec<PortDecl> {
        let mut decls = Vec::with_capacity(4 * MAX_VIEWS);
        for i in 0..MAX_VIEWS {
            decls.push(port(
                &format!("cloud{i}"),
                <Arc<PointCloud> as InputPort<'a, Inputs>>::type_names(),
                i >= 2,
                &format!("View {i}'s cloud, in its camera frame"),
            ));
            decls.push(port(
                &format!("pose{i}"),
                <Arc<Transform> as InputPort<'a, Inputs>>::type_names(),
                true,
                &format!(
                    "View {i}'s rough camera -> world pose (e.g. the robot's reading); without poses, they come from the markers"
                ),
            ));
            decls.push(port(
                &format!("markers{i}"),
                <Arc<Markers> as InputPort<'a, Inputs>>::type_names(),
                true,
                &format!("View {i}'s markers, in its cloud's frame"),
            ));
            decls.push(port(
                &format!("marker_covariance{i}"),
                <Arc<Table> as InputPort<'a, Inputs>>::type_names(),
                true,
                &format!(
                    "View {i}'s markers' covariances from their sightings' own noise (stereo.hsv_markers' `localisation_covariance`: `id`, `cov_{{xx,xy,xz,yy,yz,zz}}_mm2`, the cloud's frame): the markers then pin each direction by how well they are measured in it (a stereo marker's depth is about ten times less certain than its place across the line of sight), and the merged set's frame covariance comes from them; given for every view with markers or for none"
                ),
            ));
        }
        decls.push(port(
            RIG_PORT,
            <Arc<StereoRig> as InputPort<'a, Inputs>>::type_names(),
            true,
            "The rig that took every view: with rig_covariance, the calibration's spread joins each marker's weight (it makes one marker's sightings from different views disagree), not the frame's error (register.icp counts it)",
        ));
        decls.push(port(
            RIG_COVARIANCE_PORT,
            <Arc<Table> as InputPort<'a, Inputs>>::type_names(),
            true,
            "The rig's parameter covariance (calib.stereo_calibrate's `covariance`)",
        ));
        decls
    }

    fn from_inputs(source: &'a Inputs) -> Result<Self, PortProblem> {
        let views = (0..MAX_VIEWS)
            .map(|i| {
                let cloud = format!("cloud{i}");
                Ok(ViewInputs {
                    cloud: if i < 2 {
                        Some(read_input::<_, Arc<PointCloud>>(source, &cloud)?)
                    } else {
                        read_input(source, &cloud)?
                    },
                    pose: read_input(source, &format!("pose{i}"))?,
                    markers: read_input(source, &format!("markers{i}"))?,
                    marker_covariance: read_input(source, &format!("marker_covariance{i}"))?,
                })
            })
            .collect::<Result<_, PortProblem>>()?;
        Ok(MultiviewInputs {
            views,
            rig: read_input(source, RIG_PORT)?,
            rig_covariance: read_input(source, RIG_COVARIANCE_PORT)?,
        })
    }
}

#[derive(Outputs)]
pub struct MultiviewOutputs {
    /// All views in the output frame, coloured by view
    pub cloud: PointCloud,
    /// view, then the 3 x 4 camera -> output frame matrix row by row (mm)
    pub poses: Table,
    /// Every view's markers in the output frame, sightings of one marker merged (empty without marker inputs)
    pub markers: Markers,
    /// How well the views pin the merged set against the first view's true
    /// camera frame: the covariance of a small turn (`rotation_*_rad`) and
    /// shift (`translation_*_mm`) of the whole output in the output frame.
    /// With every sighting's covariance, from the markers' noise through
    /// their joint adjustment (every other view's pose and every marker's
    /// position; the first view held, so its sightings' errors move the
    /// rest); otherwise from the first view's fit onto the others. 6 x 6,
    /// one row per column (no rows where nothing pins it). `register.icp`
    /// takes it as `source_covariance`
    pub covariance: Table,
}

/// The colour of each view in the merged cloud.
const PALETTE: [[u8; 3]; MAX_VIEWS] = [
    [230, 90, 60],
    [60, 160, 230],
    [90, 200, 90],
    [230, 200, 60],
    [180, 90, 220],
    [60, 210, 200],
    [240, 140, 190],
    [150, 150, 150],
];

/// Each view's markers' covariances with the calibration's spread added
/// (each view's frame, mm^2): the outer products of each marker's
/// triangulation shifts along the rig's standard-deviation directions. A
/// marker the rig cannot triangulate keeps its own.
fn with_calibration_spread(
    markers: &[Option<Vec<Point3<f64>>>],
    covariances: &[Option<Vec<Matrix3<f64>>>],
    rig: &RigModel,
    perturbed: &[(RigModel, RigModel)],
) -> Vec<Option<Vec<Matrix3<f64>>>> {
    markers
        .iter()
        .zip(covariances)
        .map(|(seen, own)| {
            let (seen, own) = (seen.as_ref()?, own.as_ref()?);
            Some(
                seen.iter()
                    .zip(own)
                    .map(|(p, c)| {
                        triangulation_shifts(rig, perturbed, p)
                            .map(|shifts| shifts.iter().fold(*c, |c, s| c + s * s.transpose()))
                            .unwrap_or(*c)
                    })
                    .collect(),
            )
        })
        .collect()
}

impl RunOp for Multiview {
    type Inputs = MultiviewInputs;
    type Outputs = MultiviewOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let k = self.normals_k;
        let (mut views, mut rough, mut markers) = (Vec::new(), Vec::new(), Vec::new());
        // Each view's input port and its markers' ids, for notes.
        let (mut ports, mut marker_ids) = (Vec::new(), Vec::new());
        let mut frame = String::new();
        let mut covariances = Vec::new();
        for (i, view) in inputs.views.into_iter().enumerate() {
            let seen = view.markers;
            let covariance_table = view.marker_covariance;
            match (view.cloud, view.pose) {
                (Some(c), pose) => {
                    if let Some(m) = &seen
                        && m.frame != c.frame
                    {
                        return Err(OpError::invalid(format!(
                            "markers{i} are in `{}` but cloud{i} in `{}`",
                            m.frame, c.frame
                        )));
                    }
                    covariances.push(match (&seen, &covariance_table) {
                        (Some(m), Some(t)) if t.row_count() > 0 => Some(
                            covariances_for_ids(t, &m.ids)
                                .map_err(|e| OpError::invalid(format!("marker_covariance{i}: {e}")))?,
                        ),
                        (Some(_), Some(_)) => {
                            ctx.note(format!(
                                "marker_covariance{i} has no rows (too few markers to measure their noise): every view's markers weigh alike in every direction"
                            ));
                            None
                        }
                        (None, Some(_)) => {
                            return Err(OpError::invalid(format!(
                                "marker_covariance{i} without markers{i}"
                            )));
                        }
                        (_, None) => None,
                    });
                    ports.push(i);
                    marker_ids.push(seen.as_ref().map(|m| m.ids.to_vec()).unwrap_or_default());
                    markers.push(seen.map(|m| marker_points(&m)));
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
                (None, None) if seen.is_none() && covariance_table.is_none() => {}
                _ => {
                    return Err(OpError::invalid(format!(
                        "view {i}: pose{i}, markers{i} or marker_covariance{i} without cloud{i}"
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
            poses_from_markers(&sets, self.merge_mm).map_err(OpError::invalid)?
        } else {
            return Err(OpError::invalid(
                "connect a pose for every view or for none (then they come from the markers)",
            ));
        };
        let p = IcpParams {
            method: IcpMethod::PointToPlane,
            max_distance_mm: self.max_distance_mm,
            trim_ratio: self.trim_ratio,
            kernel: Kernel::Huber(self.kernel_mm),
            max_iterations: 40,
            tolerance: self.tolerance,
            voxel_sizes_mm: self.voxel_sizes_mm.clone(),
        };
        // Weights from covariances only where every view with markers has
        // them: a view weighed otherwise would pull harder or softer than
        // its noise says.
        let with_markers = || {
            markers
                .iter()
                .zip(&covariances)
                .filter(|(m, _)| m.is_some())
        };
        let covariances = if with_markers().all(|(_, c)| c.is_some()) {
            covariances
        } else {
            if with_markers().any(|(_, c)| c.is_some()) {
                ctx.note(
                    "some views' markers have covariances and some not: every marker weighs alike in every direction",
                );
            }
            Vec::new()
        };
        // The weights: the sightings' own noise and, with the rig's
        // parameter covariance, the calibration's spread, which makes one
        // marker's sightings from different views disagree too (it moves
        // each view's markers alike in that view's frame, so differently in
        // the world).
        let weights = match (&inputs.rig, &inputs.rig_covariance) {
            (None, None) => covariances.clone(),
            (Some(rig), Some(table)) if table.row_count() > 0 && !covariances.is_empty() => {
                let model = RigModel::from_value(rig);
                let perturbed = perturbed_rigs_from_table(&model, table)
                    .map_err(|e| OpError::invalid(format!("rig_covariance: {e}")))?;
                with_calibration_spread(&markers, &covariances, &model, &perturbed)
            }
            (Some(_), Some(table)) => {
                if table.row_count() == 0 {
                    ctx.note(
                        "rig_covariance has no rows (a parameter undetermined): the markers weigh by their own noise alone",
                    );
                }
                covariances.clone()
            }
            _ => {
                return Err(OpError::invalid(
                    "connect both rig and rig_covariance, or neither",
                ));
            }
        };
        let anchoring = (self.marker_weight > 0.0).then(|| MarkerAnchoring {
            markers: markers
                .iter()
                .map(|m| m.clone().unwrap_or_default())
                .collect(),
            tolerance_mm: self.merge_mm,
            weight: self.marker_weight,
            outlier_mm: self.outlier_mm,
            covariances: weights.clone(),
        });
        let mut m = register_views(&views, &rough, &p, self.rounds, anchoring.as_ref())
            .map_err(OpError::invalid)?;
        let to_output = match self.frame {
            OutputFrame::FirstView => m.poses[0].inverse(),
            OutputFrame::World => Isometry3::identity(),
        };
        let first_view_poses = m.poses.clone();
        let out_frame = match self.frame {
            OutputFrame::FirstView => {
                for pose in &mut m.poses {
                    *pose = to_output * *pose;
                }
                frame
            }
            OutputFrame::World => "world".to_string(),
        };
        let (seen_in, sightings): (Vec<usize>, Vec<ViewMarkers>) = markers
            .into_iter()
            .zip(&m.poses)
            .enumerate()
            .filter_map(|(v, (seen, pose))| seen.map(|s| (v, (s, *pose))))
            .unzip();
        let params = MergeParams {
            merge_mm: self.merge_mm,
            outlier_mm: self.outlier_mm,
        };
        let of_sightings = |table: &[Option<Vec<Matrix3<f64>>>]| -> Vec<Option<Vec<Matrix3<f64>>>> {
            seen_in
                .iter()
                .map(|&v| table.get(v).cloned().flatten())
                .collect()
        };
        let (sighting_noise, sighting_weights) =
            (of_sightings(&covariances), of_sightings(&weights));
        let (merged, dropped) = merge_markers_weighted(&sightings, &sighting_weights, &params);
        // The markers' noise pins the frame where they anchor the views and
        // every sighting has a covariance; the surfaces' fit otherwise.
        let from_markers = match anchoring.as_ref().filter(|a| !a.covariances.is_empty()) {
            Some(_) => match markers_frame_spread(
                &merged,
                &sightings,
                &sighting_noise,
                &sighting_weights,
                &seen_in,
                views.len(),
            ) {
                Ok(c) => Some(c),
                Err(e) => {
                    ctx.note(format!(
                        "the merged set's frame error from the surfaces' fit, not the markers' noise: {e}"
                    ));
                    None
                }
            },
            None => None,
        };
        // 1 when the frame's covariance is the markers' joint adjustment's.
        ctx.metric(
            "frame_from_markers",
            f64::from(u8::from(from_markers.is_some())),
        );
        let frame_covariance = match from_markers {
            Some(c) => Ok(c),
            None => first_view_spread(
                &views,
                &first_view_poses,
                &p,
                anchoring.as_ref(),
                self.error_block_mm,
            )
            .map(|c| carried_pose_covariance(&to_output, &c)),
        };
        let covariance = match frame_covariance {
            Ok(c) => {
                let turn = (0..3).map(|i| c[(i, i)]).sum::<f64>().sqrt();
                ctx.metric("frame_rotation_sd_deg", turn.to_degrees());
                // Where it matters: how far the middle of the first view's
                // surface may move (RMS over the axes, mm).
                let n = views[0].points.len() as f64;
                let middle = views[0]
                    .points
                    .iter()
                    .map(|x| x.coords)
                    .sum::<Vector3<f64>>()
                    / n;
                let middle = m.poses[0] * Point3::from(middle);
                let moved = mapped_point_covariance(&Isometry3::identity(), &c, &middle);
                ctx.metric("frame_shift_sd_mm", moved.trace().sqrt());
                pose_covariance_table(&c)
            }
            Err(e) => {
                ctx.note(format!(
                    "no covariance of the merged set: the first view against the others: {e}"
                ));
                empty_pose_covariance()
            }
        };
        for d in &dropped {
            ctx.note(format!(
                "view {}: marker {} dropped, {:.1} mm from where the other views put it \
                 (partly hidden, or cut by a highlight?)",
                ports[seen_in[d.set]], marker_ids[seen_in[d.set]][d.marker], d.off_mm
            ));
        }
        ctx.metric("sightings_dropped", dropped.len() as f64);
        ctx.metric("markers", merged.len() as f64);
        ctx.metric(
            "marker_spread_max_mm",
            merged.iter().map(|m| m.spread_mm).fold(0.0, f64::max),
        );
        let merged_positions: Vec<Point3<f64>> = merged.iter().map(|m| m.position).collect();
        let merged_markers = markers_value(
            &merged_positions,
            (0..merged.len() as u32).collect(),
            &out_frame,
        )?;
        let rmse = m.view_rmse_mm.iter().sum::<f64>() / m.view_rmse_mm.len() as f64;
        ctx.metric("rmse_mm", rmse);
        ctx.metric("views", views.len() as f64);
        for (i, r) in m.pairwise_rmse_mm.iter().enumerate() {
            ctx.metric(&format!("pair_{i}_rmse_mm"), *r);
        }
        let (mut pts, mut colors) = (Vec::new(), Vec::new());
        let mut table = Vec::new();
        for (i, (view, pose)) in views.iter().zip(&m.poses).enumerate() {
            pts.extend(view.points.iter().map(|p| pose * p));
            colors.extend(std::iter::repeat_n(PALETTE[i], view.points.len()).flatten());
            let h = pose.to_homogeneous();
            table.push(i as f64);
            table.extend((0..3).flat_map(|r| (0..4).map(move |c| h[(r, c)])));
        }
        let columns: Vec<String> = std::iter::once("view".to_string())
            .chain((0..3).flat_map(|r| (0..4).map(move |c| format!("m{r}{c}"))))
            .collect();
        let poses = Table::new(columns, table).map_err(|e| OpError::invalid(e.0))?;
        Ok(MultiviewOutputs {
            cloud: make_cloud(&pts, None, Some(colors.into()), &out_frame)?,
            poses,
            markers: merged_markers,
            covariance,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fusegraph_engine::Value;

    fn cloud(frame: &str) -> Value {
        PointCloud::new(vec![0.0, 0.0, 100.0], None, None, frame)
            .unwrap()
            .into()
    }

    fn op() -> Multiview {
        fusegraph_engine::typed::declared_defaults().expect("every parameter has a default")
    }

    /// The error the op refuses `views` with.
    fn run(views: Vec<ViewInputs>) -> String {
        run_with_rig(views, None, None)
    }

    /// The error the op refuses `views` and the rig's ports with.
    fn run_with_rig(
        views: Vec<ViewInputs>,
        rig: Option<StereoRig>,
        rig_covariance: Option<Table>,
    ) -> String {
        let mut ctx = RunCtx::new("views", &std::env::temp_dir());
        let inputs = MultiviewInputs {
            views,
            rig: rig.map(Arc::new),
            rig_covariance: rig_covariance.map(Arc::new),
        };
        op().run(inputs, &mut ctx)
            .map(|_| ())
            .unwrap_err()
            .to_string()
    }

    #[test]
    fn ports_are_read_by_view_and_the_first_two_clouds_are_required() {
        let decls = <MultiviewInputs as InputSet<'_, Inputs>>::port_decls();
        let names: Vec<&str> = decls.iter().map(|d| d.name.as_str()).collect();
        assert_eq!(names.len(), 4 * MAX_VIEWS + 2);
        assert_eq!(names[4 * MAX_VIEWS..], ["rig", "rig_covariance"]);
        assert_eq!(
            names[..6],
            [
                "cloud0",
                "pose0",
                "markers0",
                "marker_covariance0",
                "cloud1",
                "pose1"
            ]
        );
        assert_eq!(names[4 * MAX_VIEWS - 1], "marker_covariance7");
        assert!(!decls[0].optional && !decls[4].optional && decls[8].optional);

        let mut inputs = Inputs::default();
        inputs.0.insert("cloud0".into(), cloud("camera_a"));
        let e = MultiviewInputs::from_inputs(&inputs).err().unwrap();
        assert_eq!(e.port, "cloud1");
        inputs.0.insert("cloud1".into(), cloud("camera_b"));
        inputs.0.insert("cloud3".into(), cloud("camera_d"));
        let read = MultiviewInputs::from_inputs(&inputs).unwrap();
        assert_eq!(read.views.len(), MAX_VIEWS);
        let frames: Vec<Option<&str>> = read
            .views
            .iter()
            .map(|v| v.cloud.as_ref().map(|c| c.frame.as_str()))
            .collect();
        assert_eq!(
            frames[..4],
            [Some("camera_a"), Some("camera_b"), None, Some("camera_d")]
        );
        assert!(
            read.views
                .iter()
                .all(|v| v.pose.is_none() && v.markers.is_none())
        );
    }

    #[test]
    fn a_pose_without_its_cloud_and_poses_for_some_views_only_are_refused() {
        let view = |frame: Option<&str>, pose: bool| ViewInputs {
            cloud: frame.map(|f| Arc::new(PointCloud::new(vec![0.0; 3], None, None, f).unwrap())),
            pose: pose.then(|| {
                Arc::new(Transform {
                    matrix: crate::camera::isometry_to_matrix(&Isometry3::identity()),
                    from: frame.unwrap_or("camera").into(),
                    to: "world".into(),
                })
            }),
            markers: None,
            marker_covariance: None,
        };
        let e = run(vec![
            view(Some("a"), true),
            view(Some("b"), true),
            view(None, true),
        ]);
        assert!(
            e.contains("view 2: pose2, markers2 or marker_covariance2 without cloud2"),
            "{e}"
        );
        let e = run(vec![view(Some("a"), true), view(Some("b"), false)]);
        assert!(
            e.contains("connect a pose for every view or for none"),
            "{e}"
        );
        let e = run(vec![view(Some("a"), false), view(Some("b"), false)]);
        assert!(
            e.contains("without poses, connect every view's markers"),
            "{e}"
        );
    }

    #[test]
    fn a_marker_covariance_table_that_does_not_fit_its_markers_is_named() {
        let view = |frame: &str, ids: &[u32], table: Option<Table>| ViewInputs {
            cloud: Some(Arc::new(
                PointCloud::new(vec![0.0; 3], None, None, frame).unwrap(),
            )),
            pose: None,
            markers: Some(Arc::new(
                Markers::new(vec![0.0; 3 * ids.len()], ids.to_vec(), frame).unwrap(),
            )),
            marker_covariance: table.map(Arc::new),
        };
        let table = |ids: &[u32]| {
            let rows: Vec<f64> = ids
                .iter()
                .flat_map(|&id| [id as f64, 1.0, 0.0, 0.0, 1.0, 0.0, 1.0])
                .collect();
            Table::new(crate::calib::columns_with_covariance(&["id"]), rows).unwrap()
        };
        let e = run(vec![
            view("a", &[0, 1, 2], Some(table(&[0, 1, 2]))),
            view("a", &[1, 3], Some(table(&[1, 2]))),
        ]);
        assert!(e.contains("marker_covariance1: no row for marker 3"), "{e}");
        let wrong = Table::new(vec!["id".into(), "cov_xx_mm2".into()], vec![0.0, 1.0]).unwrap();
        let e = run(vec![view("a", &[0], Some(wrong)), view("a", &[0], None)]);
        assert!(
            e.contains("marker_covariance0: no column `cov_xy_mm2`"),
            "{e}"
        );
    }

    #[test]
    fn the_rig_comes_with_its_covariance_and_a_bad_one_is_named() {
        let rig = crate::calib::parallel_test_rig();
        let view = || {
            let positions = vec![0.0, 0.0, 500.0, 30.0, 0.0, 500.0, 0.0, 30.0, 510.0];
            let points: Vec<f32> = positions.iter().map(|&x| x as f32).collect();
            let covariance: Vec<f64> = (0..3)
                .flat_map(|id| [id as f64, 0.01, 0.0, 0.0, 0.01, 0.0, 0.1])
                .collect();
            ViewInputs {
                cloud: Some(Arc::new(
                    PointCloud::new(points, None, None, "camera").unwrap(),
                )),
                pose: Some(Arc::new(Transform {
                    matrix: crate::camera::isometry_to_matrix(&Isometry3::identity()),
                    from: "camera".into(),
                    to: "world".into(),
                })),
                markers: Some(Arc::new(
                    Markers::new(positions, vec![0, 1, 2], "camera").unwrap(),
                )),
                marker_covariance: Some(Arc::new(
                    Table::new(crate::calib::columns_with_covariance(&["id"]), covariance).unwrap(),
                )),
            }
        };
        let e = run_with_rig(vec![view(), view()], Some(rig.clone()), None);
        assert!(e.contains("connect both rig and rig_covariance"), "{e}");
        let unknown = Table::new(vec!["left_zoom".into()], vec![1.0]).unwrap();
        let e = run_with_rig(vec![view(), view()], Some(rig), Some(unknown));
        assert!(e.contains("rig_covariance: `left_zoom`"), "{e}");
    }
}
