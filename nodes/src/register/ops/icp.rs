//! `register.icp`: iterative closest point between two clouds.

use crate::calib::{
    RigModel, disparity_offset_rigs, perturbed_rigs_from_table, triangulation_shifts,
};
use crate::cloud::Nearest;
use crate::cloud::convert::{cloud_normals, cloud_points};
use crate::register::convert::{
    self, MatchedLandmarks, empty_pose_covariance, pose_covariance_from_table,
    pose_covariance_table, transform_isometry, transform_value,
};
use crate::register::figures::icp_figures;
use crate::register::{
    Anchors, IcpMethod, IcpParams, Kernel, PoseSpread, ShiftField, ShiftedPoint,
    carried_pose_covariance, icp_anchored, normals_near, pose_spread,
};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Markers, PointCloud, StereoRig, Table, Transform};
use nalgebra::{Isometry3, Matrix6, Point3, Vector3};

/// Iterative closest point: source cloud onto target cloud
#[derive(Op)]
// 4: the pose's covariance (surface noise in blocks, and the rig's calibration).
// 5: and the source frame's own spread (`source_covariance`).
// 6: and a disparity offset the source surface's views share
//    (`matcher_bias_sd_px`); every block's residuals corrected for its
//    leverage.
// 7: the calibration's part of the covariance as an output of its own.
#[op(name = "register.icp", version = 7)]
pub struct Icp {
    /// Error metric: point_to_plane (needs the target's normals),
    /// point_to_point, or gicp (generalized ICP, Segal et al. 2009: each
    /// pair weighed by both surfaces' local plane covariances)
    #[param(default = IcpMethod::PointToPlane)]
    pub method: IcpMethod,
    /// Pairs farther apart are ignored
    #[param(default = 5.0, unit = "mm", min = 1e-3)]
    pub max_distance_mm: f64,
    /// Fraction of closest pairs kept
    #[param(default = 0.9, min = 0.05, max = 1.0)]
    pub trim_ratio: f64,
    /// Robust kernel
    #[param(default = IcpKernel::Huber)]
    pub kernel: IcpKernel,
    /// Kernel threshold (Huber k, Tukey c)
    #[param(default = 1.5, unit = "mm", min = 1e-6)]
    pub kernel_mm: f64,
    /// Iterations per scale
    #[param(default = 50, min = 1, max = 10000)]
    pub max_iterations: usize,
    /// Relative change of RMSE and fitness that stops it
    #[param(default = 1e-6, min = 0.0)]
    pub tolerance: f64,
    /// Coarse-to-fine source voxel sizes (0 = full)
    #[param(default = [], unit = "mm", min = 0.0)]
    pub voxel_sizes_mm: Vec<f64>,
    /// Weight of the landmarks, all together, against the surface pairs
    /// (0: they are only checked, not fitted)
    #[param(default = 0.0, min = 0.0)]
    pub landmark_weight: f64,
    /// across_normal: a landmark pins only the two directions across the
    /// target surface's normal there, the surface the third (markers: the
    /// camera sees a face, MRI its gel a few mm deeper); full: all three
    /// (point-to-plane only; point-to-point fits them in full)
    #[param(default = LandmarkFit::AcrossNormal)]
    pub landmark_fit: LandmarkFit,
    /// A note warns when ICP moves the landmarks this much further from
    /// their matches (RMS) than the start had them
    #[param(default = 1.0, unit = "mm", min = 0.0)]
    pub landmark_drift_mm: f64,
    /// For the pose's covariance: the surfaces' errors are taken as
    /// correlated within cubes of this size (target frame) and independent
    /// between them; wider than a reconstructed surface's matching and
    /// smoothing windows (0: every pair independent, the textbook formula)
    #[param(default = 20.0, unit = "mm", min = 0.0)]
    pub error_block_mm: f64,
    /// For the pose's covariance, with a rig: the standard deviation of a
    /// disparity error that every point of the source surface shares (a
    /// dense matcher's bias on curved, weakly textured skin, which no
    /// residual shows); it moves the surface, not the landmarks, as an
    /// error of the right camera's principal point would. 0: none. The
    /// default is what the main job's views share on the built-in phantom
    /// (RMS over seeds 101-110, ideal and lab, 1.5 and 6 DN, against
    /// `phantom.true_disparity`, 8 SGM paths: 0.028 px); measure a real
    /// rig's on a target of known shape
    #[param(default = 0.03, unit = "px", min = 0.0)]
    pub matcher_bias_sd_px: f64,
}

/// How landmarks join the surface pairs (`landmark_fit`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Choice)]
pub enum LandmarkFit {
    /// Only across the target surface's normal.
    AcrossNormal,
    /// In all three directions.
    Full,
}

/// Target points whose normals give the surface's orientation at a landmark.
const LANDMARK_NORMAL_POINTS: usize = 256;

/// The robust kernel, by name (its threshold is `kernel_mm`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Choice)]
pub enum IcpKernel {
    /// Huber.
    Huber,
    /// Tukey's biweight.
    Tukey,
    /// Plain least squares.
    None,
}

impl IcpKernel {
    /// The kernel with threshold `mm`.
    pub fn with_threshold(self, mm: f64) -> Kernel {
        match self {
            IcpKernel::Huber => Kernel::Huber(mm),
            IcpKernel::Tukey => Kernel::Tukey(mm),
            IcpKernel::None => Kernel::None,
        }
    }
}

#[derive(Inputs)]
pub struct IcpInputs {
    /// Cloud to move
    pub source: Arc<PointCloud>,
    /// Cloud to move onto (normals for point-to-plane)
    pub target: Arc<PointCloud>,
    /// Start (source -> target), e.g. from markers
    pub init: Option<Arc<Transform>>,
    /// Landmarks in the source frame (e.g. the markers matched to the
    /// target's), paired in order with `landmarks_target`
    pub landmarks_source: Option<Arc<Markers>>,
    /// The same landmarks in the target frame
    pub landmarks_target: Option<Arc<Markers>>,
    /// The stereo rig that triangulated the source cloud and landmarks (in
    /// its left camera's frame): with `rig_covariance`, its calibration's
    /// spread joins the pose's covariance
    pub rig: Option<Arc<StereoRig>>,
    /// The rig's parameter covariance (calib.stereo_calibrate's `covariance`)
    pub rig_covariance: Option<Arc<Table>>,
    /// How well the source's own frame is known (register.multiview's
    /// `covariance`: a small turn and shift of the whole source, points and
    /// landmarks together, in its frame); the pose follows it, so it joins
    /// the pose's covariance
    pub source_covariance: Option<Arc<Table>>,
}

/// The landmark pairs, checked: both sides or neither, in the clouds' frames,
/// one to one.
fn landmark_pairs(inputs: &IcpInputs) -> Result<Option<MatchedLandmarks>, OpError> {
    convert::landmark_pairs(
        inputs.landmarks_source.as_deref(),
        inputs.landmarks_target.as_deref(),
        &inputs.source.frame,
        &inputs.target.frame,
    )
}

/// RMS distance of landmark pairs under `t`, mm.
fn landmark_rms(source: &[Point3<f64>], target: &[Point3<f64>], t: &Isometry3<f64>) -> f64 {
    let sum: f64 = source
        .iter()
        .zip(target)
        .map(|(s, q)| (t * s - q).norm_squared())
        .sum();
    (sum / source.len().max(1) as f64).sqrt()
}

#[derive(Outputs)]
pub struct IcpOutputs {
    /// Source frame -> target frame
    pub transform: Transform,
    /// iteration, voxel_mm, rmse_mm, fitness, pairs
    pub trace: Table,
    /// The pose's covariance: of a small turn (`rotation_*_rad`, about the
    /// target frame's axes) and shift (`translation_*_mm`) applied after the
    /// transform in the target frame; 6 x 6, one row per column (no rows
    /// where the final pairs do not pin the pose)
    pub covariance: Table,
    /// The part of `covariance` the rig's calibration gives (same layout;
    /// no rows without a rig): with register.map_targets' input of that
    /// name, each target's error budget
    pub calibration_covariance: Table,
}

impl RunOp for Icp {
    type Inputs = IcpInputs;
    type Outputs = IcpOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let landmarks = landmark_pairs(&inputs)?;
        let (s, t) = (inputs.source, inputs.target);
        let init = match inputs.init {
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
        let p = IcpParams {
            method: self.method,
            max_distance_mm: self.max_distance_mm,
            trim_ratio: self.trim_ratio,
            kernel: self.kernel.with_threshold(self.kernel_mm),
            max_iterations: self.max_iterations,
            tolerance: self.tolerance,
            voxel_sizes_mm: self.voxel_sizes_mm.clone(),
        };
        let anchors = landmarks.as_ref().map(|(a, b)| Anchors {
            source: a.clone(),
            target: b.clone(),
            weight: self.landmark_weight,
            normals: match (self.landmark_fit, &tn) {
                (LandmarkFit::AcrossNormal, Some(n)) => {
                    Some(normals_near(&tree, n, b, LANDMARK_NORMAL_POINTS))
                }
                _ => None,
            },
            information: None,
        });
        let r = icp_anchored(&sp, &tp, tn.as_deref(), &tree, &init, &p, anchors.as_ref())
            .map_err(OpError::invalid)?;
        if let Some((a, b)) = &landmarks {
            let (before, after) = (landmark_rms(a, b, &init), landmark_rms(a, b, &r.transform));
            ctx.metric("landmark_rmse_init_mm", before);
            ctx.metric("landmark_rmse_mm", after);
            if after - before > self.landmark_drift_mm {
                ctx.note(format!(
                    "the surfaces pulled the {} landmarks from their matches: RMS {before:.2} mm \
                     at the start, {after:.2} mm after ICP. The surfaces and the markers disagree: \
                     the tissue may have moved between the scans, which a rigid registration \
                     cannot follow; the markers' fit (the start) may be the better one. The \
                     pose's covariance (the targets' error bars) assumes a rigid motion and no \
                     longer holds",
                    a.len()
                ));
            }
        }
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
        let started = std::time::Instant::now();
        let field = source_shift_field(
            ctx,
            inputs.rig.as_deref(),
            inputs.rig_covariance.as_deref(),
            self.matcher_bias_sd_px,
        )?;
        let spread = pose_spread(
            &sp,
            &tp,
            tn.as_deref(),
            &tree,
            &r.transform,
            &p,
            anchors.as_ref(),
            self.error_block_mm,
            field.as_ref().map(|(f, _)| f as &ShiftField),
        );
        let frame_spread = match inputs.source_covariance.as_deref() {
            Some(t) if t.row_count() == 0 => {
                ctx.note(
                    "the source's frame has no covariance (its views did not pin it): its spread \
                     is not in the pose's covariance",
                );
                Matrix6::zeros()
            }
            Some(t) => carried_pose_covariance(
                &r.transform,
                &pose_covariance_from_table(t)
                    .map_err(|e| OpError::invalid(format!("source_covariance: {e}")))?,
            ),
            None => Matrix6::zeros(),
        };
        let (covariance, calibration_covariance) = match spread {
            Ok(spread) => {
                let with_bias = field.as_ref().is_some_and(|(_, bias)| *bias);
                let calibration = report_spread(ctx, &spread, &frame_spread, with_bias);
                (
                    pose_covariance_table(&(spread.covariance + frame_spread)),
                    match field {
                        Some(_) => pose_covariance_table(&calibration),
                        None => empty_pose_covariance(),
                    },
                )
            }
            Err(e) => {
                ctx.note(format!("no pose covariance: {e}"));
                (empty_pose_covariance(), empty_pose_covariance())
            }
        };
        ctx.metric("covariance_ms", started.elapsed().as_secs_f64() * 1e3);
        Ok(IcpOutputs {
            transform: transform_value(&r.transform, &s.frame, &t.frame),
            trace,
            covariance,
            calibration_covariance,
        })
    }
}

/// How each source point moves (first order) along each standard-deviation
/// direction of the rig's calibration and, last, of a disparity offset of
/// `bias_sd_px` that the source surface shares (landmarks, found in the
/// images on their own, do not move with it); and whether that last
/// direction is there. `None` without a rig or with nothing to spread.
#[allow(clippy::type_complexity)]
fn source_shift_field(
    ctx: &mut RunCtx,
    rig: Option<&StereoRig>,
    covariance: Option<&Table>,
    bias_sd_px: f64,
) -> Result<
    Option<(
        impl Fn(&Point3<f64>, ShiftedPoint) -> Option<Vec<Vector3<f64>>> + Sync + use<>,
        bool,
    )>,
    OpError,
> {
    let (rig, covariance) = match (rig, covariance) {
        (None, None) => return Ok(None),
        (Some(r), Some(c)) => (r, c),
        _ => {
            return Err(OpError::invalid(
                "connect both rig and rig_covariance, or neither",
            ));
        }
    };
    let model = RigModel::from_value(rig);
    let mut rigs = if covariance.row_count() == 0 {
        ctx.note(
            "the rig's calibration has no covariance (a parameter undetermined): its spread is \
             not in the pose's covariance",
        );
        Vec::new()
    } else {
        perturbed_rigs_from_table(&model, covariance)
            .map_err(|e| OpError::invalid(format!("rig_covariance: {e}")))?
    };
    let with_bias = bias_sd_px > 0.0;
    if with_bias {
        rigs.push(disparity_offset_rigs(&model, bias_sd_px));
    }
    if rigs.is_empty() {
        return Ok(None);
    }
    let field = move |p: &Point3<f64>, kind: ShiftedPoint| {
        let mut shifts = triangulation_shifts(&model, &rigs, p)?;
        if with_bias && kind == ShiftedPoint::Landmark {
            *shifts.last_mut().expect("the bias's direction is last") = Vector3::zeros();
        }
        Some(shifts)
    };
    Ok(Some((field, with_bias)))
}

/// The pose's standard deviations and what they come from, as metrics:
/// the fit's own spread `s` (its shift field's last direction the matcher's
/// bias when `with_bias`) and the source frame's carried into it. Returns
/// the calibration's part of the covariance.
fn report_spread(
    ctx: &mut RunCtx,
    s: &PoseSpread,
    frame: &Matrix6<f64>,
    with_bias: bool,
) -> Matrix6<f64> {
    let rotation = |c: &Matrix6<f64>| (0..3).map(|i| c[(i, i)]).sum::<f64>().max(0.0).sqrt();
    let translation = |c: &Matrix6<f64>| (3..6).map(|i| c[(i, i)]).sum::<f64>().max(0.0).sqrt();
    let total = s.covariance + frame;
    ctx.metric("rotation_sd_deg", rotation(&total).to_degrees());
    ctx.metric("translation_sd_mm", translation(&total));
    ctx.metric("source_frame_translation_sd_mm", translation(frame));
    ctx.metric("noise_translation_sd_mm", translation(&s.noise));
    ctx.metric("independent_translation_sd_mm", translation(&s.independent));
    let outer = |r: &nalgebra::Vector6<f64>| r * r.transpose();
    let (calibration, bias) = match s.shift_responses.split_last() {
        Some((last, rest)) if with_bias => (rest, Some(outer(last))),
        _ => (s.shift_responses.as_slice(), None),
    };
    let calibration = calibration
        .iter()
        .fold(Matrix6::zeros(), |c, r| c + outer(r));
    ctx.metric("calibration_translation_sd_mm", translation(&calibration));
    if let Some(bias) = bias {
        ctx.metric("matcher_bias_translation_sd_mm", translation(&bias));
    }
    ctx.metric("error_blocks", s.blocks as f64);
    calibration
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud(frame: &str) -> Arc<PointCloud> {
        Arc::new(PointCloud::new(vec![0.0, 0.0, 100.0], None, None, frame).unwrap())
    }

    fn markers(points: Vec<f64>, frame: &str) -> Arc<Markers> {
        let ids = (0..points.len() as u32 / 3).collect::<Vec<u32>>();
        Arc::new(Markers::new(points, ids, frame).unwrap())
    }

    fn inputs(a: Option<Arc<Markers>>, b: Option<Arc<Markers>>) -> IcpInputs {
        IcpInputs {
            source: cloud("camera_left"),
            target: cloud("mri_lps"),
            init: None,
            landmarks_source: a,
            landmarks_target: b,
            rig: None,
            rig_covariance: None,
            source_covariance: None,
        }
    }

    #[test]
    fn landmarks_come_in_pairs_in_the_clouds_frames() {
        let two = |frame| markers(vec![0.0, 0.0, 0.0, 10.0, 0.0, 0.0], frame);
        let one = markers(vec![0.0, 0.0, 0.0], "mri_lps");
        assert!(landmark_pairs(&inputs(None, None)).unwrap().is_none());
        let (a, b) = landmark_pairs(&inputs(Some(two("camera_left")), Some(two("mri_lps"))))
            .unwrap()
            .unwrap();
        assert_eq!((a.len(), b.len()), (2, 2));
        let err = |i: IcpInputs| landmark_pairs(&i).unwrap_err().to_string();
        assert!(err(inputs(Some(two("camera_left")), None)).contains("or neither"));
        assert!(err(inputs(Some(two("world")), Some(two("mri_lps")))).contains("`world`"));
        assert!(err(inputs(Some(two("camera_left")), Some(one))).contains("pair in order"));
    }

    /// An uneven bowl (18 x 18 points, 4 mm apart) with its normals, as a
    /// cloud in `frame`.
    fn bowl(frame: &str) -> Arc<PointCloud> {
        let (points, normals) = crate::register::pose_spread::uneven_bowl(18, 4.0);
        let flat =
            |v: Vec<[f64; 3]>| -> Vec<f32> { v.concat().iter().map(|&x| x as f32).collect() };
        let points = flat(points.iter().map(|p| [p.x, p.y, p.z]).collect());
        let normals = flat(normals.iter().map(|n| [n.x, n.y, n.z]).collect());
        Arc::new(PointCloud::new(points, None, Some(normals.into()), frame).unwrap())
    }

    #[test]
    fn the_source_frames_spread_joins_the_poses() {
        let op: Icp =
            fusegraph_engine::typed::declared_defaults().expect("every parameter has a default");
        let run = |source_covariance: Option<Table>| {
            let mut i = inputs(None, None);
            (i.source, i.target) = (bowl("camera_left"), bowl("mri_lps"));
            i.source_covariance = source_covariance.map(Arc::new);
            let mut ctx = RunCtx::new("icp", &std::env::temp_dir());
            op.run(i, &mut ctx).map(|_| ctx.into_metrics())
        };
        let without = run(None).unwrap();
        // 0.1 mm per axis of shift, no turn: at the identity pose it passes
        // to the pose as it is, adding 0.03 mm^2 to its shift's variance.
        let shift =
            Matrix6::from_diagonal(&nalgebra::Vector6::new(0.0, 0.0, 0.0, 0.01, 0.01, 0.01));
        let with = run(Some(pose_covariance_table(&shift))).unwrap();
        assert!(
            (with["source_frame_translation_sd_mm"] - 0.03f64.sqrt()).abs() < 1e-6,
            "{with:?}"
        );
        let total = without["translation_sd_mm"].powi(2) + 0.03;
        assert!((with["translation_sd_mm"] - total.sqrt()).abs() < 1e-6);
        let wrong = Table::new(vec!["x_mm".into()], vec![1.0]).unwrap();
        let e = run(Some(wrong)).unwrap_err().to_string();
        assert!(e.contains("source_covariance"), "{e}");
    }

    #[test]
    fn without_a_rig_the_calibrations_part_is_empty() {
        let op: Icp =
            fusegraph_engine::typed::declared_defaults().expect("every parameter has a default");
        let mut i = inputs(None, None);
        (i.source, i.target) = (bowl("camera_left"), bowl("mri_lps"));
        let mut ctx = RunCtx::new("icp", &std::env::temp_dir());
        let out = op.run(i, &mut ctx).unwrap();
        assert_eq!(out.covariance.row_count(), 6);
        assert_eq!(out.calibration_covariance.row_count(), 0);
    }

    #[test]
    fn landmark_rms_by_hand() {
        // Two pairs 3 and 4 mm apart after a 1 mm shift: RMS sqrt((9 + 16) / 2).
        let source = [Point3::new(0.0, 0.0, 0.0), Point3::new(10.0, 0.0, 0.0)];
        let target = [Point3::new(4.0, 0.0, 0.0), Point3::new(11.0, 4.0, 0.0)];
        let shift = Isometry3::translation(1.0, 0.0, 0.0);
        let rms = landmark_rms(&source, &target, &shift);
        assert!((rms - (12.5f64).sqrt()).abs() < 1e-12, "{rms}");
    }

    #[test]
    fn a_rig_comes_with_its_covariance() {
        let rig = StereoRig {
            left: fusegraph_engine::value::Camera {
                width: 8,
                height: 6,
                k: [[10.0, 0.0, 4.0], [0.0, 10.0, 3.0], [0.0, 0.0, 1.0]],
                distortion: [0.0; 5],
            },
            right: fusegraph_engine::value::Camera {
                width: 8,
                height: 6,
                k: [[10.0, 0.0, 4.0], [0.0, 10.0, 3.0], [0.0, 0.0, 1.0]],
                distortion: [0.0; 5],
            },
            rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            translation_mm: [-50.0, 0.0, 0.0],
        };
        let mut ctx = RunCtx::new("icp", &std::env::temp_dir());
        let e = source_shift_field(&mut ctx, Some(&rig), None, 0.0)
            .map(|_| ())
            .unwrap_err();
        assert!(e.to_string().contains("rig and rig_covariance"), "{e}");
        let unknown = Table::new(vec!["left_zoom".into()], vec![1.0]).unwrap();
        let e = source_shift_field(&mut ctx, Some(&rig), Some(&unknown), 0.0)
            .map(|_| ())
            .unwrap_err();
        assert!(e.to_string().contains("rig_covariance: `left_zoom`"), "{e}");
        let empty = Table::new(vec!["left_fx_px".into()], Vec::new()).unwrap();
        assert!(
            source_shift_field(&mut ctx, Some(&rig), Some(&empty), 0.0)
                .unwrap()
                .is_none()
        );
        // The matcher's bias alone: 0.1 px at 500 mm with f = 10 px and
        // b = 50 mm moves a surface point 500^2 * 0.1 / (10 * 50) = 50 mm
        // along its ray (first order), and a landmark not at all.
        let (field, with_bias) = source_shift_field(&mut ctx, Some(&rig), Some(&empty), 0.1)
            .unwrap()
            .unwrap();
        assert!(with_bias);
        let p = Point3::new(0.0, 0.0, 500.0);
        let surface = field(&p, ShiftedPoint::Surface).unwrap();
        assert_eq!(surface.len(), 1);
        assert!((surface[0].z.abs() - 50.0).abs() < 1.0, "{}", surface[0]);
        assert_eq!(
            field(&p, ShiftedPoint::Landmark).unwrap(),
            vec![Vector3::zeros()]
        );
        assert!(
            ctx.notes().iter().any(|n| n.contains("no covariance")),
            "{:?}",
            ctx.notes()
        );
    }
}
