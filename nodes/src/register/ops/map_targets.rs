//! `register.map_targets`: MRI targets into camera space.

use crate::calib::{columns_with_covariance, covariance_entries};
use crate::eval::convert::load_truth;
use crate::eval::{target_errors, true_mri_to_camera};
use crate::register::convert::{
    field_from_table, marker_points, markers_value, pose_covariance_from_table,
};
use crate::register::figures::error_ellipses_svg;
use crate::register::{error_bound_mm, map_targets, mapped_target_covariances, predict_marker_tre};
use fusegraph_engine::figure::FigureData;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Markers, PathValue, Table, Transform};
use nalgebra::{Matrix3, Point3};

/// Targets marked in MRI (lesions) mapped into camera (robot) space with a registration
#[derive(Op)]
// 3: each target's predicted error from the registration's covariance.
// 5: the targets given or detected in the scan.
// 6: targets moved by a deformation.
// 7: each target's calibration part (calibration_covariance).
// 8: the truth file's numbers read exactly as written (they were read to within
// an ulp or so).
#[op(name = "register.map_targets", version = 8)]
pub struct MapTargets {
    /// Phantom view whose left camera is camera_left
    #[param(default = 0, min = 0)]
    pub view: usize,
    /// Which targets are mapped: those given (input `targets`, e.g. marked by a radiologist) or those detected in the scan (input `detected`, mri.detect_lesions' markers); the report's notes say which
    #[param(default = TargetSource::Given)]
    pub source: TargetSource,
}

/// Where the mapped targets come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Choice)]
pub enum TargetSource {
    /// Given: the `targets` input.
    Given,
    /// Found in the scan: the `detected` input.
    Detected,
}

#[derive(Inputs)]
pub struct MapTargetsInputs {
    /// Targets given, mm, in one frame of the transform (e.g. mri_lps): mapped when source = given
    pub targets: Option<Arc<Markers>>,
    /// Targets detected in the scan (mri.detect_lesions' markers): mapped when source = detected
    pub detected: Option<Arc<Markers>>,
    /// The registration, either way between the targets' frame and the camera's
    pub transform: Arc<Transform>,
    /// ground_truth.json: the targets' true camera positions (targets in mri_lps, camera_left of `view`)
    pub truth: Option<Arc<PathValue>>,
    /// Markers matched between the two frames (e.g. match_markers.source),
    /// with `landmarks_target` in the same order: the predicted error of a
    /// markers-only registration at each target (Fitzpatrick's formula, FLE
    /// from the markers' own residual)
    pub landmarks_source: Option<Arc<Markers>>,
    /// The same markers in the other frame
    pub landmarks_target: Option<Arc<Markers>>,
    /// The registration's pose covariance (register.icp's `covariance`):
    /// each target's predicted error, its covariance and 95 % bound
    pub covariance: Option<Arc<Table>>,
    /// The part of `covariance` the calibration gives (register.icp's
    /// `calibration_covariance`): each target's predicted RMS error from
    /// the calibration alone, `target_<id>_calibration_tre_mm` (the rest is
    /// the surfaces', markers' and matcher's)
    pub calibration_covariance: Option<Arc<Table>>,
    /// A displacement field in the targets' frame (register.deformable's
    /// `field`): each target moves by it before the transform maps it; its
    /// truth is still taken from where it was scanned
    pub deformation: Option<Arc<Table>>,
}

#[derive(Outputs)]
pub struct MapTargetsOutputs {
    /// The targets in the transform's other frame (camera_left), same ids
    pub targets: Markers,
    /// Each target's predicted error in that frame, given a covariance
    /// (otherwise no rows): `id`, `predicted_tre_mm` (RMS), `bound95_mm`
    /// (95 % of errors are shorter), `sd_{x,y,z}_mm` and the covariance
    /// `cov_{xx,xy,xz,yy,yz,zz}_mm2`
    pub errors: Table,
}

/// The columns of [`MapTargetsOutputs::errors`] before the covariance's.
const ERROR_COLUMNS: [&str; 6] = [
    "id",
    "predicted_tre_mm",
    "bound95_mm",
    "sd_x_mm",
    "sd_y_mm",
    "sd_z_mm",
];

/// One row of the errors table for a target's covariance.
fn error_row(id: u32, c: &Matrix3<f64>) -> Vec<f64> {
    let mut row = vec![
        id as f64,
        c.trace().max(0.0).sqrt(),
        error_bound_mm(c, 0.95),
        c[(0, 0)].max(0.0).sqrt(),
        c[(1, 1)].max(0.0).sqrt(),
        c[(2, 2)].max(0.0).sqrt(),
    ];
    row.extend(covariance_entries(c));
    row
}

impl RunOp for MapTargets {
    type Inputs = MapTargetsInputs;
    type Outputs = MapTargetsOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let transform = inputs.transform;
        let (targets, port, what) = match self.source {
            TargetSource::Given => (inputs.targets, "targets", "given"),
            TargetSource::Detected => (inputs.detected, "detected", "detected in the scan"),
        };
        let targets = targets.ok_or_else(|| {
            let hint = match self.source {
                TargetSource::Detected => " (e.g. in.detected = \"detect_lesions.markers\")",
                TargetSource::Given => "",
            };
            OpError::invalid(format!(
                "source = \"{}\" maps the `{port}` input, which is not connected{hint}",
                self.source.name()
            ))
        })?;
        ctx.note(format!(
            "{} targets {what} (input `{port}`), ids {:?}",
            targets.ids.len(),
            targets.ids
        ));
        let points = marker_points(&targets);
        let moved = match &inputs.deformation {
            Some(table) => deformed(ctx, &targets.ids, &points, table)?,
            None => points.clone(),
        };
        let (mapped, frame) =
            map_targets(&moved, &targets.frame, &transform).map_err(OpError::invalid)?;
        ctx.metric("targets", mapped.len() as f64);
        let covariances = match &inputs.covariance {
            Some(table) if table.row_count() == 0 => {
                ctx.note("the registration gave no covariance: no predicted target errors");
                Vec::new()
            }
            Some(table) => {
                let pose = pose_covariance_from_table(table)
                    .map_err(|e| OpError::invalid(format!("covariance: {e}")))?;
                mapped_target_covariances(&moved, &targets.frame, &transform, &pose)
                    .map_err(OpError::invalid)?
            }
            None => Vec::new(),
        };
        if let Some(table) = inputs.calibration_covariance.as_deref()
            && table.row_count() > 0
        {
            let pose = pose_covariance_from_table(table)
                .map_err(|e| OpError::invalid(format!("calibration_covariance: {e}")))?;
            let parts = mapped_target_covariances(&moved, &targets.frame, &transform, &pose)
                .map_err(OpError::invalid)?;
            for (id, c) in targets.ids.iter().zip(&parts) {
                ctx.metric(
                    &format!("target_{id}_calibration_tre_mm"),
                    c.trace().max(0.0).sqrt(),
                );
            }
        }
        let rows: Vec<Vec<f64>> = targets
            .ids
            .iter()
            .zip(&covariances)
            .map(|(&id, c)| error_row(id, c))
            .collect();
        for (id, row) in targets.ids.iter().zip(&rows) {
            ctx.metric(&format!("target_{id}_predicted_tre_mm"), row[1]);
            ctx.metric(&format!("target_{id}_bound95_mm"), row[2]);
        }
        if !rows.is_empty() {
            let mean_square = rows.iter().map(|r| r[1] * r[1]).sum::<f64>() / rows.len() as f64;
            ctx.metric("predicted_tre_mm", mean_square.sqrt());
            ctx.figure(
                "error_ellipses",
                "Each target (its id) with the ellipse 95 % of its predicted errors fall within, seen along each axis of its frame",
                FigureData::Svg(error_ellipses_svg(&targets.ids, &mapped, &covariances, &frame)),
            )?;
        }
        if let (Some(a), Some(b)) = (&inputs.landmarks_source, &inputs.landmarks_target) {
            report_marker_prediction(ctx, &targets, &points, a, b)?;
        }
        if let Some(file) = inputs.truth {
            let truth = load_truth(&file)?;
            if targets.frame != "mri_lps" || frame != "camera_left" {
                return Err(OpError::invalid(format!(
                    "with a truth, targets map mri_lps -> camera_left, not `{}` -> `{frame}`",
                    targets.frame
                )));
            }
            let true_mc = true_mri_to_camera(&truth, self.view).map_err(OpError::invalid)?;
            let (mean, max) = target_errors(&true_mc, &points, &mapped);
            ctx.metric("target_error_mm", mean);
            ctx.metric("target_error_max_mm", max);
            report_observed(ctx, &targets.ids, &points, &mapped, &rows, |p| {
                true_mc.apply(p)
            });
        }
        let errors = Table::new(columns_with_covariance(&ERROR_COLUMNS), rows.concat())
            .map_err(|e| OpError::invalid(e.0))?;
        Ok(MapTargetsOutputs {
            targets: markers_value(&mapped, targets.ids.to_vec(), &frame)?,
            errors,
        })
    }
}

/// `points` (of targets `ids`) moved by the field in `table`
/// (register.deformable's columns), each one's move reported as
/// `target_<id>_deformation_mm`.
fn deformed(
    ctx: &mut RunCtx,
    ids: &[u32],
    points: &[Point3<f64>],
    table: &Table,
) -> Result<Vec<Point3<f64>>, OpError> {
    let field =
        field_from_table(table).map_err(|e| OpError::invalid(format!("deformation: {e}")))?;
    let moved: Vec<Point3<f64>> = points.iter().map(|p| p + field.displacement(p)).collect();
    for ((id, p), m) in ids.iter().zip(points).zip(&moved) {
        ctx.metric(&format!("target_{id}_deformation_mm"), (m - p).norm());
    }
    Ok(moved)
}

/// Each target's observed error against the truth (`target_<id>_error_mm`,
/// and its components in the targets' mapped frame, mapped minus true,
/// `target_<id>_error_{x,y,z}_mm`) and, with predictions, how many lie within
/// their 95 % bound (`targets_within_bound95`).
fn report_observed(
    ctx: &mut RunCtx,
    ids: &[u32],
    points: &[Point3<f64>],
    mapped: &[Point3<f64>],
    rows: &[Vec<f64>],
    truth: impl Fn(&Point3<f64>) -> Point3<f64>,
) {
    let mut within = 0;
    for (k, (id, (p, m))) in ids.iter().zip(points.iter().zip(mapped)).enumerate() {
        let offset = m - truth(p);
        let error = offset.norm();
        ctx.metric(&format!("target_{id}_error_mm"), error);
        for (axis, e) in ["x", "y", "z"].iter().zip(offset.iter()) {
            ctx.metric(&format!("target_{id}_error_{axis}_mm"), *e);
        }
        within += rows.get(k).is_some_and(|r| error <= r[2]) as usize;
    }
    if !rows.is_empty() {
        ctx.metric("targets_within_bound95", within as f64);
    }
}

/// Reports the predicted TRE of a markers-only registration at each target
/// (`target_<id>_marker_tre_mm` and its 95 % bound), with the markers' FRE
/// and the FLE it implies; a note where it cannot be predicted.
fn report_marker_prediction(
    ctx: &mut RunCtx,
    targets: &Markers,
    points: &[nalgebra::Point3<f64>],
    a: &Markers,
    b: &Markers,
) -> Result<(), OpError> {
    // The markers in the targets' frame, and their matches.
    let (own, other) = if a.frame == targets.frame {
        (a, b)
    } else if b.frame == targets.frame {
        (b, a)
    } else {
        return Err(OpError::invalid(format!(
            "landmarks in `{}` and `{}`: one side must be in the targets' frame `{}`",
            a.frame, b.frame, targets.frame
        )));
    };
    let (own, other) = (marker_points(own), marker_points(other));
    if own.len() != other.len() {
        return Err(OpError::invalid(format!(
            "{} landmarks_source vs {} landmarks_target: they must correspond one to one",
            a.ids.len(),
            b.ids.len()
        )));
    }
    let Some(p) = predict_marker_tre(&own, &other, points) else {
        ctx.note(format!(
            "no predicted target error: {} matched markers (it needs 4 or more, not on one line)",
            own.len()
        ));
        return Ok(());
    };
    ctx.metric("marker_fre_mm", p.fre_mm);
    ctx.metric("marker_fle_mm", p.fle_mm);
    for (id, (rms, bound)) in targets.ids.iter().zip(&p.targets) {
        ctx.metric(&format!("target_{id}_marker_tre_mm"), *rms);
        ctx.metric(&format!("target_{id}_marker_tre_bound95_mm"), *bound);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::register::Lattice;
    use crate::register::convert::field_table;

    fn markers(positions: &[[f64; 3]], frame: &str) -> Arc<Markers> {
        let ids: Vec<u32> = (0..positions.len() as u32).collect();
        Arc::new(Markers::new(positions.concat(), ids, frame).unwrap())
    }

    const MRI_MARKERS: [[f64; 3]; 5] = [
        [40.0, 0.0, 0.0],
        [-40.0, 5.0, 0.0],
        [0.0, 40.0, 10.0],
        [0.0, -40.0, 5.0],
        [10.0, 10.0, 40.0],
    ];

    const GIVEN: MapTargets = MapTargets {
        view: 0,
        source: TargetSource::Given,
    };

    fn inputs(camera_frame: &str) -> MapTargetsInputs {
        // The camera's markers: the MRI's, each 1 mm off along some axis.
        let offsets = [
            [1.0, 0.0, 0.0],
            [0.0, -1.0, 0.0],
            [0.0, 0.0, 1.0],
            [-1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
        ];
        let camera: Vec<[f64; 3]> = MRI_MARKERS
            .iter()
            .zip(offsets)
            .map(|(p, o)| [p[0] + o[0], p[1] + o[1], p[2] + o[2]])
            .collect();
        MapTargetsInputs {
            targets: Some(markers(&[[0.0, 0.0, 20.0], [0.0, 0.0, 120.0]], "mri_lps")),
            detected: None,
            transform: Arc::new(Transform::identity("mri_lps", "camera_left")),
            truth: None,
            landmarks_source: Some(markers(&camera, camera_frame)),
            landmarks_target: Some(markers(&MRI_MARKERS, "mri_lps")),
            covariance: None,
            calibration_covariance: None,
            deformation: None,
        }
    }

    #[test]
    fn matched_markers_give_each_target_its_predicted_error() {
        let mut ctx = RunCtx::new("targets", &std::env::temp_dir());
        GIVEN.run(inputs("camera_left"), &mut ctx).unwrap();
        let m = ctx.metrics();
        let (fre, fle) = (m["marker_fre_mm"], m["marker_fle_mm"]);
        assert!(fre > 0.3 && fre < 1.0, "{fre}");
        assert!((fle - fre * (5.0f64 / 3.0).sqrt()).abs() < 1e-9);
        // The far target is predicted worse, and its bound lies beyond its RMS.
        let (near, far) = (m["target_0_marker_tre_mm"], m["target_1_marker_tre_mm"]);
        assert!(near < far, "{near} {far}");
        assert!(m["target_1_marker_tre_bound95_mm"] > far);
    }

    #[test]
    fn landmarks_in_neither_frame_of_the_targets_are_refused() {
        let mut ctx = RunCtx::new("targets", &std::env::temp_dir());
        let mut i = inputs("camera_left");
        i.landmarks_target = Some(markers(&MRI_MARKERS, "world"));
        let e = GIVEN.run(i, &mut ctx).map(|_| ()).unwrap_err();
        assert!(
            e.to_string()
                .contains("one side must be in the targets' frame `mri_lps`"),
            "{e}"
        );
    }

    #[test]
    fn a_pose_covariance_gives_each_target_its_error_bars() {
        // A pose known to 0.1 mm along each axis and not turned at all:
        // every target's covariance is 0.01 mm^2 I, its RMS error sqrt(0.03)
        // mm and its 95 % bound sqrt(0.01 chi-square(3, 0.95) = 7.815) mm.
        let sd2 = nalgebra::Vector6::new(0.0, 0.0, 0.0, 0.01, 0.01, 0.01);
        let table = crate::register::convert::pose_covariance_table(
            &nalgebra::Matrix6::from_diagonal(&sd2),
        );
        // The calibration's part: 0.05 mm along z alone.
        let calibration =
            crate::register::convert::pose_covariance_table(&nalgebra::Matrix6::from_diagonal(
                &nalgebra::Vector6::new(0.0, 0.0, 0.0, 0.0, 0.0, 0.0025),
            ));
        let mut i = inputs("camera_left");
        i.covariance = Some(Arc::new(table));
        i.calibration_covariance = Some(Arc::new(calibration));
        let mut ctx = RunCtx::new("targets", &std::env::temp_dir());
        let out = GIVEN.run(i, &mut ctx).unwrap();
        assert_eq!(out.errors.row_count(), 2);
        let m = ctx.metrics();
        for id in [0, 1] {
            let rms = m[&format!("target_{id}_predicted_tre_mm")];
            let bound = m[&format!("target_{id}_bound95_mm")];
            assert!((rms - 0.03f64.sqrt()).abs() < 1e-9, "{rms}");
            assert!((bound - 0.07815f64.sqrt()).abs() < 0.005, "{bound}");
            let part = m[&format!("target_{id}_calibration_tre_mm")];
            assert!((part - 0.05).abs() < 1e-9, "{part}");
        }
        assert_eq!(out.errors.columns[1], "predicted_tre_mm");
        assert!((out.errors.data[3] - 0.1).abs() < 1e-9, "sd_x_mm");
        // A table of another shape is refused, naming the port.
        let mut i = inputs("camera_left");
        i.covariance = Some(Arc::new(Table::new(vec!["a".into()], vec![1.0]).unwrap()));
        let e = GIVEN.run(i, &mut ctx).map(|_| ()).unwrap_err();
        assert!(
            e.to_string()
                .contains("covariance: a pose covariance has the columns"),
            "{e}"
        );
    }

    #[test]
    fn a_deformation_moves_each_target_before_the_transform() {
        // A field shifting everything 2 mm along +x (a lattice over the
        // targets), the identity transform: the targets land 2 mm along x.
        let pts = [
            nalgebra::Point3::new(-10.0, -10.0, 0.0),
            nalgebra::Point3::new(10.0, 10.0, 130.0),
        ];
        let mut field = Lattice::covering(&pts, 20.0, 10.0);
        for u in &mut field.displacements {
            *u = nalgebra::Vector3::new(2.0, 0.0, 0.0);
        }
        let table = field_table(&field);
        let mut i = inputs("camera_left");
        i.deformation = Some(Arc::new(table));
        let mut ctx = RunCtx::new("targets", &std::env::temp_dir());
        let out = GIVEN.run(i, &mut ctx).unwrap();
        assert!((out.targets.positions_mm[0] - 2.0).abs() < 1e-9);
        assert!((out.targets.positions_mm[5] - 120.0).abs() < 1e-9);
        assert!((ctx.metrics()["target_1_deformation_mm"] - 2.0).abs() < 1e-9);
        // Not a field: refused, naming the port.
        let mut i = inputs("camera_left");
        i.deformation = Some(Arc::new(Table::new(vec!["a".into()], vec![1.0]).unwrap()));
        let e = GIVEN.run(i, &mut ctx).map(|_| ()).unwrap_err();
        assert!(
            e.to_string().contains("deformation: no column `x_mm`"),
            "{e}"
        );
    }

    #[test]
    fn detected_targets_are_mapped_when_chosen_and_the_notes_say_so() {
        let mut i = inputs("camera_left");
        i.detected = Some(markers(&[[5.0, 0.0, 30.0]], "mri_lps"));
        let mut ctx = RunCtx::new("targets", std::path::Path::new("."));
        let detected = MapTargets {
            source: TargetSource::Detected,
            ..GIVEN
        };
        let out = detected.run(i, &mut ctx).unwrap();
        assert_eq!(out.targets.ids.len(), 1);
        assert!((out.targets.positions_mm[2] - 30.0).abs() < 1e-12);
        assert!(
            ctx.notes()
                .iter()
                .any(|n| n.contains("detected in the scan")),
            "{:?}",
            ctx.notes()
        );
        // Chosen but not connected: an error naming the input.
        let mut ctx = RunCtx::new("targets", std::path::Path::new("."));
        let Err(e) = detected.run(inputs("camera_left"), &mut ctx) else {
            panic!("ran without its detected targets");
        };
        assert!(e.to_string().contains("`detected` input"), "{e}");
    }
}
