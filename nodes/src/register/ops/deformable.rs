//! `register.deformable`: after a rigid registration, the smooth field that
//! takes the scanned skin and markers onto those seen now.

use crate::cloud::convert::{cloud_normals, cloud_points};
use crate::cloud::plane_from_table;
use crate::register::convert::{MatchedLandmarks, field_table, landmark_pairs, transform_isometry};
use crate::register::figures::field_on_skin_svg;
use crate::register::{
    DeformParams, LandmarkPairs, Lattice, Support, base_on, displacement_stats, fit_deformation,
};
use fusegraph_engine::figure::FigureData;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Markers, PointCloud, Table, Transform};
use nalgebra::{Point3, Vector3};

/// A smooth displacement field (nonrigid ICP on a lattice, bending-regularised) taking the scanned skin and markers onto those seen now, after the rigid registration; zero (the rigid result kept) where the data do not support one
#[derive(Op)]
// 2: the skins thinned to a random subset, not every k-th point.
// 3: a field must also explain min_explained_share of the rigid residual.
// 4: the scan's flat base rests on the plane seen now (input support).
#[op(name = "register.deformable", version = 5)]
pub struct Deformable {
    /// deformable: fit the field; rigid: give a zero field (the rigid result), e.g. --set deform.mode=rigid
    #[param(default = DeformMode::Deformable)]
    pub mode: DeformMode,
    /// Bending length L: a bend of the field of 1 / L costs as much as a surface residual of L (larger: stiffer, smoother)
    #[param(default = 10.0, unit = "mm", min = 0.5, max = 1000.0)]
    pub stiffness_mm: f64,
    /// Spacing of the field's lattice
    #[param(default = 10.0, unit = "mm", min = 2.0, max = 100.0)]
    pub spacing_mm: f64,
    /// The markers' total weight against the whole skin's (they pin a slide along the skin the surfaces cannot see)
    #[param(default = 0.1, min = 0.0)]
    pub landmark_weight: f64,
    /// With a support plane: the scan's flat base resting on it weighs this much against the whole skin
    #[param(default = 1.0, min = 0.0)]
    pub support_weight: f64,
    /// Pairs of skin points farther apart than this are left out
    #[param(default = 15.0, unit = "mm", min = 0.1)]
    pub max_distance_mm: f64,
    /// Share of the closest skin pairs kept each step
    #[param(default = 0.9, min = 0.05, max = 1.0)]
    pub trim_ratio: f64,
    /// A field that explains less than this of the skin's RMS residual after the rigid fit (sqrt(rigid^2 - after^2)) is not applied: no motion beyond what noise and a rigid fit leave
    #[param(default = 0.2, unit = "mm", min = 0.0)]
    pub min_explained_mm: f64,
    /// A field that explains less than this share of the skin's RMS residual after the rigid fit is not applied either: fitted to the surfaces' noise alone it explains a share that does not shrink as the noise grows (18-60 % on unmoved phantoms, ideal to lab at 6 DN), where real motion leaves a residual it explains nearly all of (99 % and more at 5-10 mm of sag or compression)
    #[param(default = 0.8, min = 0.0, max = 1.0)]
    pub min_explained_share: f64,
    /// Each skin is thinned to at most this many points (a random subset, the same every run) for the fit
    #[param(default = 20000, min = 100)]
    pub max_points: usize,
    /// A field whose peak over the skin exceeds this is not trusted (the rigid result is kept)
    #[param(default = 30.0, unit = "mm", min = 0.0)]
    pub max_motion_mm: f64,
    /// Fewer matched markers than this: no field (the surfaces alone cannot pin a slide along the skin)
    #[param(default = 4, min = 0)]
    pub min_landmarks: usize,
    /// Conjugate-gradient iterations at most per step's linear system (multigrid-preconditioned, each system reaches its tolerance in 7-21 on the main job: the cap only bounds a badly conditioned one, which is then noted)
    #[param(default = 100, min = 1, max = 100000)]
    pub solver_iterations: usize,
}

/// Whether a field is fitted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Choice)]
pub enum DeformMode {
    /// Fit the field.
    Deformable,
    /// A zero field: the rigid registration alone.
    Rigid,
}

#[derive(Inputs)]
pub struct DeformableInputs {
    /// The rigid registration, `source` frame -> `target` frame (register.icp's transform)
    pub transform: Arc<Transform>,
    /// The skin seen now (e.g. the merged camera cloud), in the transform's from frame
    pub source: Arc<PointCloud>,
    /// The scanned skin with normals (e.g. the MRI cloud), in the transform's to frame
    pub target: Arc<PointCloud>,
    /// Markers seen now (e.g. match_markers.source), paired in order with `landmarks_target`
    pub landmarks_source: Option<Arc<Markers>>,
    /// The same markers in the scan
    pub landmarks_target: Option<Arc<Markers>>,
    /// The plane the tissue rests on now, in the source's frame (cloud.remove_plane's `plane`: the table under a phantom, the support around a breast's root); the scan's flat base is held on it, so the field is interpolated between skin and base inside rather than carried down from the skin; none, or a scan without a flat base: skin and markers alone
    pub support: Option<Arc<Table>>,
}

#[derive(Outputs)]
pub struct DeformableOutputs {
    /// The field in the scan's frame: each lattice node's position and displacement (x_mm, y_mm, z_mm, u_x_mm, u_y_mm, u_z_mm): a scanned point at p lies now at p + u(p), before the rigid transform's inverse (register.map_targets' `deformation`); all zero where no field is applied
    pub field: Table,
}

impl RunOp for Deformable {
    type Inputs = DeformableInputs;
    type Outputs = DeformableOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let t = &inputs.transform;
        if t.from != inputs.source.frame || t.to != inputs.target.frame {
            return Err(OpError::invalid(format!(
                "the transform maps `{}` -> `{}`, but the clouds are `{}` (source) and `{}` (target)",
                t.from, t.to, inputs.source.frame, inputs.target.frame
            )));
        }
        let normals = cloud_normals(&inputs.target).ok_or_else(|| {
            OpError::invalid(
                "the target (scanned) cloud has no normals: the fit measures across them",
            )
        })?;
        let scan_points = cloud_points(&inputs.target);
        let kept = subset(scan_points.len(), self.max_points);
        let (scan, normals) = (pick(&scan_points, &kept), pick(&normals, &kept));
        let iso = transform_isometry(t);
        let now_points = cloud_points(&inputs.source);
        let now: Vec<Point3<f64>> = pick(&now_points, &subset(now_points.len(), self.max_points))
            .iter()
            .map(|p| iso * p)
            .collect();
        let landmarks = landmark_points(&inputs, &iso)?;
        let support = self.support(&inputs, &iso, &scan, &normals, ctx)?;
        let params = DeformParams {
            spacing_mm: self.spacing_mm,
            stiffness_mm: self.stiffness_mm,
            landmark_weight: self.landmark_weight,
            support_weight: self.support_weight,
            max_distance_mm: self.max_distance_mm,
            trim_ratio: self.trim_ratio,
            solver_iterations: self.solver_iterations,
            ..DeformParams::default()
        };
        let zero = || Lattice::covering(&scan, self.spacing_mm, 2.0 * self.spacing_mm);
        let pairs = landmarks.as_ref().map_or(0, |(a, _)| a.len());
        let field = if self.mode == DeformMode::Rigid {
            ctx.note("mode = rigid: no field; the targets follow the rigid registration");
            zero()
        } else if pairs < self.min_landmarks {
            ctx.note(format!(
                "{pairs} matched markers, under min_landmarks = {}: the skin alone cannot pin a \
                 slide along itself, so no field is fitted; the rigid result stands",
                self.min_landmarks
            ));
            zero()
        } else {
            let d = fit_deformation(
                &scan,
                &normals,
                &now,
                landmarks
                    .as_ref()
                    .map(|(a, b)| LandmarkPairs { scan: b, now: a }),
                support.as_ref(),
                &params,
            )
            .map_err(OpError::invalid)?;
            ctx.metric("solver_iterations", d.solver_iterations as f64);
            if d.unconverged_steps > 0 {
                ctx.note(format!(
                    "{} of the fit's linear systems stopped at solver_iterations = {} short of \
                     their tolerance (worst relative residual {:.1e}): the field depends on \
                     where they stopped; raise solver_iterations",
                    d.unconverged_steps, self.solver_iterations, d.worst_relative_residual
                ));
            }
            if support.is_some() {
                ctx.metric("rigid_support_residual_mm", d.rigid_support_residual_mm);
                ctx.metric("support_residual_mm", d.support_residual_mm);
            }
            let seen: Vec<Point3<f64>> = d.seen.iter().map(|&j| scan[j]).collect();
            let shifts: Vec<Vector3<f64>> = seen.iter().map(|p| d.field.displacement(p)).collect();
            let (peak, rms) = displacement_stats(&shifts);
            ctx.metric("peak_displacement_mm", peak);
            ctx.metric("rms_displacement_mm", rms);
            ctx.metric("rigid_residual_mm", d.rigid_residual_mm);
            ctx.metric("residual_mm", d.residual_mm);
            ctx.metric("rigid_landmark_residual_mm", d.rigid_landmark_residual_mm);
            ctx.metric("landmark_residual_mm", d.landmark_residual_mm);
            ctx.figure(
                "field",
                "How far the deformation moved each point of the skin both see (scan frame), seen along each axis",
                FigureData::Svg(field_on_skin_svg(&seen, &shifts, &inputs.target.frame)),
            )?;
            let explained = Explained::of(d.rigid_residual_mm, d.residual_mm);
            ctx.metric("explained_residual_mm", explained.mm);
            ctx.metric("explained_share", explained.share);
            match self.refusal(&explained, peak) {
                Some(why) => {
                    ctx.note(format!(
                        "{why}, so it is not applied; the rigid result stands"
                    ));
                    zero()
                }
                None => {
                    ctx.note(format!(
                        "the tissue moved: a field of {rms:.2} mm RMS ({peak:.2} mm peak) takes \
                         the skin from {:.2} to {:.2} mm RMS residual; the targets' error bars \
                         are the rigid registration's and do not count the field's own error",
                        d.rigid_residual_mm, d.residual_mm
                    ));
                    d.field
                }
            }
        };
        ctx.metric(
            "applied",
            field.displacements.iter().any(|u| u.norm() > 0.0) as u8 as f64,
        );
        Ok(DeformableOutputs {
            field: field_table(&field),
        })
    }
}

/// How much of the skin's RMS residual after the rigid fit a field explains.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Explained {
    /// The residual after the rigid fit, mm.
    rigid_mm: f64,
    /// The residual after the field, mm.
    after_mm: f64,
    /// sqrt(rigid^2 - after^2), mm.
    mm: f64,
    /// `mm` as a share of `rigid_mm` (0..1).
    share: f64,
}

impl Explained {
    fn of(rigid_mm: f64, after_mm: f64) -> Explained {
        let mm = (rigid_mm.powi(2) - after_mm.powi(2)).max(0.0).sqrt();
        Explained {
            rigid_mm,
            after_mm,
            mm,
            share: mm / rigid_mm.max(f64::MIN_POSITIVE),
        }
    }
}

impl Deformable {
    /// The scan's flat base and the support plane (moved into the scan's
    /// frame) it rests on, when a plane is given and the scan has such a
    /// base; else `None`, with a note saying why.
    fn support(
        &self,
        inputs: &DeformableInputs,
        iso: &nalgebra::Isometry3<f64>,
        scan: &[Point3<f64>],
        normals: &[Vector3<f64>],
        ctx: &mut RunCtx,
    ) -> Result<Option<Support>, OpError> {
        let Some(table) = inputs.support.as_deref() else {
            return Ok(None);
        };
        let Some(plane) =
            plane_from_table(table).map_err(|e| OpError::invalid(format!("support: {e}")))?
        else {
            ctx.note("the support input holds no plane: skin and markers alone");
            return Ok(None);
        };
        match base_on(scan, normals, &plane.moved_by(iso)) {
            Ok(support) => {
                let off_mm = support.residual_mm(|_| Vector3::zeros());
                if off_mm > self.max_distance_mm {
                    ctx.note(format!(
                        "the scan's flat base lies {off_mm:.1} mm RMS from the support plane after \
                         the rigid fit, over max_distance_mm = {}: not the plane it rests on, so \
                         it is not used",
                        self.max_distance_mm
                    ));
                    return Ok(None);
                }
                ctx.metric("support_points", support.base.len() as f64);
                Ok(Some(support))
            }
            Err(why) => {
                ctx.note(format!("{why}: the support plane is not used"));
                Ok(None)
            }
        }
    }

    /// Why a fitted field is not to be applied (`None`: it is), from what it
    /// explains of the skin's residual and its peak over the skin (mm).
    fn refusal(&self, explained: &Explained, peak_mm: f64) -> Option<String> {
        let &Explained {
            rigid_mm,
            after_mm,
            mm: explained,
            share,
        } = explained;
        if explained < self.min_explained_mm {
            Some(format!(
                "the field explains {explained:.2} mm RMS of the skin's residual after the rigid \
                 fit ({rigid_mm:.2} -> {after_mm:.2} mm), under min_explained_mm = {}: no motion \
                 beyond what noise and a rigid fit leave",
                self.min_explained_mm
            ))
        } else if share < self.min_explained_share {
            Some(format!(
                "the field explains {:.0} % of the skin's residual after the rigid fit \
                 ({rigid_mm:.2} -> {after_mm:.2} mm), under min_explained_share = {}: no more \
                 than a field fitted to the surfaces' noise explains",
                100.0 * share,
                self.min_explained_share
            ))
        } else if peak_mm > self.max_motion_mm {
            Some(format!(
                "the field's peak is {peak_mm:.1} mm, over max_motion_mm = {}: more than the data \
                 support",
                self.max_motion_mm
            ))
        } else {
            None
        }
    }
}

/// The indices of at most `max` of `count` items, a uniform random subset
/// (fixed seed, so the same every run) in their order. A stride (every
/// k-th) aliases with the order a cloud was written in.
fn subset(count: usize, max: usize) -> Vec<usize> {
    use rand::SeedableRng;
    use rand::seq::index::sample;
    if count <= max {
        return (0..count).collect();
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x5EED);
    let mut chosen = sample(&mut rng, count, max).into_vec();
    chosen.sort_unstable();
    chosen
}

/// The items at `indices`.
fn pick<T: Copy>(items: &[T], indices: &[usize]) -> Vec<T> {
    indices.iter().map(|&i| items[i]).collect()
}

/// The landmark pairs (seen now, moved by the rigid transform into the
/// scan's frame; the scan's), or none.
fn landmark_points(
    inputs: &DeformableInputs,
    iso: &nalgebra::Isometry3<f64>,
) -> Result<Option<MatchedLandmarks>, OpError> {
    let pairs = landmark_pairs(
        inputs.landmarks_source.as_deref(),
        inputs.landmarks_target.as_deref(),
        &inputs.source.frame,
        &inputs.target.frame,
    )?;
    Ok(pairs.map(|(now, scan)| (now.iter().map(|p| iso * p).collect(), scan)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::register::convert::field_from_table;
    use crate::register::deformable::synthetic::{dome, dome_with_base};

    fn cloud(
        points: &[Point3<f64>],
        normals: Option<&[Vector3<f64>]>,
        frame: &str,
    ) -> Arc<PointCloud> {
        let flat = |v: &mut dyn Iterator<Item = [f64; 3]>| -> Vec<f32> {
            v.flat_map(|p| p.map(|c| c as f32)).collect()
        };
        let p = flat(&mut points.iter().map(|p| [p.x, p.y, p.z]));
        let n = normals.map(|n| flat(&mut n.iter().map(|v| [v.x, v.y, v.z])).into());
        Arc::new(PointCloud::new(p, None, n, frame).unwrap())
    }

    fn markers(points: &[Point3<f64>], frame: &str) -> Arc<Markers> {
        let flat: Vec<f64> = points.iter().flat_map(|p| [p.x, p.y, p.z]).collect();
        let ids: Vec<u32> = (0..points.len() as u32).collect();
        Arc::new(Markers::new(flat, ids, frame).unwrap())
    }

    /// The dome scanned, and seen again `shift` (mm) along x above 30 mm
    /// (a shear the rigid transform, the identity, leaves), with `landmarks`
    /// markers on both.
    fn inputs(shift: f64, landmarks: usize) -> DeformableInputs {
        let (scan, normals) = dome(4.0);
        let moved =
            |p: &Point3<f64>| p + Vector3::new(shift * (p.z / 95.0).clamp(0.0, 1.0), 0.0, 0.0);
        let now: Vec<Point3<f64>> = scan.iter().filter(|p| p.z > 30.0).map(moved).collect();
        let marks: Vec<Point3<f64>> = scan.iter().step_by(37).take(landmarks).copied().collect();
        let seen: Vec<Point3<f64>> = marks.iter().map(moved).collect();
        DeformableInputs {
            transform: Arc::new(Transform::identity("camera_left", "mri_lps")),
            source: cloud(&now, None, "camera_left"),
            target: cloud(&scan, Some(&normals), "mri_lps"),
            landmarks_source: Some(markers(&seen, "camera_left")),
            landmarks_target: Some(markers(&marks, "mri_lps")),
            support: None,
        }
    }

    fn op() -> Deformable {
        Deformable {
            mode: DeformMode::Deformable,
            stiffness_mm: 10.0,
            spacing_mm: 10.0,
            landmark_weight: 0.1,
            support_weight: 1.0,
            max_distance_mm: 15.0,
            trim_ratio: 0.9,
            min_explained_mm: 0.2,
            min_explained_share: 0.8,
            max_motion_mm: 30.0,
            max_points: 20000,
            min_landmarks: 4,
            solver_iterations: 100,
        }
    }

    fn largest(field: &Table) -> f64 {
        field_from_table(field)
            .unwrap()
            .displacements
            .iter()
            .map(|u| u.norm())
            .fold(0.0, f64::max)
    }

    #[test]
    fn a_moved_skin_gets_a_field_and_an_unmoved_one_or_a_rigid_mode_none() {
        let mut ctx = RunCtx::new("deform", &std::env::temp_dir());
        let out = op().run(inputs(6.0, 12), &mut ctx).unwrap();
        assert_eq!(ctx.metrics()["applied"], 1.0);
        assert!(largest(&out.field) > 3.0);
        assert!(ctx.notes().iter().any(|n| n.contains("the tissue moved")));
        assert!(!ctx.notes().iter().any(|n| n.contains("solver_iterations")));
        // A cap its systems cannot converge under is said.
        let mut ctx = RunCtx::new("deform", &std::env::temp_dir());
        let capped = Deformable {
            solver_iterations: 1,
            ..op()
        };
        capped.run(inputs(6.0, 12), &mut ctx).unwrap();
        assert!(
            ctx.notes()
                .iter()
                .any(|n| n.contains("stopped at solver_iterations = 1")),
            "{:?}",
            ctx.notes()
        );
        let mut ctx = RunCtx::new("deform", &std::env::temp_dir());
        let out = op().run(inputs(0.0, 12), &mut ctx).unwrap();
        assert_eq!((ctx.metrics()["applied"], largest(&out.field)), (0.0, 0.0));
        assert!(
            ctx.notes().iter().any(|n| n.contains("min_explained_mm")),
            "{:?}",
            ctx.notes()
        );
        let mut ctx = RunCtx::new("deform", &std::env::temp_dir());
        let rigid = Deformable {
            mode: DeformMode::Rigid,
            ..op()
        };
        let out = rigid.run(inputs(6.0, 12), &mut ctx).unwrap();
        assert_eq!(largest(&out.field), 0.0);
    }

    #[test]
    fn too_few_markers_keep_the_rigid_result_and_say_so() {
        let mut ctx = RunCtx::new("deform", &std::env::temp_dir());
        let out = op().run(inputs(6.0, 3), &mut ctx).unwrap();
        assert_eq!(largest(&out.field), 0.0);
        assert!(
            ctx.notes()
                .iter()
                .any(|n| n.contains("3 matched markers, under min_landmarks = 4"))
        );
    }

    #[test]
    fn a_support_plane_is_used_where_the_scan_has_a_base_on_it_and_a_bad_one_named() {
        use crate::cloud::{Plane, plane_table};
        let table = |normal: Vector3<f64>, offset: f64| {
            let plane = Plane { normal, offset };
            Some(Arc::new(plane_table(Some(&plane)).unwrap()))
        };
        // The dome's skin has no flat base: noted, skin and markers alone.
        let mut ctx = RunCtx::new("deform", &std::env::temp_dir());
        let mut i = inputs(6.0, 12);
        i.support = table(Vector3::z(), 0.0);
        op().run(i, &mut ctx).unwrap();
        assert!(!ctx.metrics().contains_key("support_points"));
        assert!(
            ctx.notes()
                .iter()
                .any(|n| n.contains("no flat base") && n.contains("not used")),
            "{:?}",
            ctx.notes()
        );
        // With its base disc, on the table z = 0: the base is held there.
        let mut ctx = RunCtx::new("deform", &std::env::temp_dir());
        let mut i = inputs(6.0, 12);
        let (scan, normals) = dome_with_base(4.0);
        i.target = cloud(&scan, Some(&normals), "mri_lps");
        i.support = table(Vector3::z(), 0.0);
        op().run(i, &mut ctx).unwrap();
        let m = ctx.metrics();
        assert!(m["support_points"] > 100.0, "{m:?}");
        assert!(m["support_residual_mm"] < 0.2, "{m:?}");
        // A plane 40 mm under the base is not what it rests on.
        let mut ctx = RunCtx::new("deform", &std::env::temp_dir());
        let mut i = inputs(6.0, 12);
        i.target = cloud(&scan, Some(&normals), "mri_lps");
        i.support = table(Vector3::z(), -40.0);
        op().run(i, &mut ctx).unwrap();
        assert!(!ctx.metrics().contains_key("support_points"));
        assert!(
            ctx.notes()
                .iter()
                .any(|n| n.contains("40.0 mm RMS from the support plane after the rigid fit, over")),
            "{:?}",
            ctx.notes()
        );
        // Not a plane: an error naming the input.
        let mut i = inputs(6.0, 12);
        i.support = Some(Arc::new(Table::new(vec!["x".into()], vec![1.0]).unwrap()));
        let e = op().run(i, &mut ctx).map(|_| ()).unwrap_err().to_string();
        assert!(e.contains("support: a plane's columns"), "{e}");
    }

    #[test]
    fn wrong_frames_and_a_scan_without_normals_are_refused_by_name() {
        let mut ctx = RunCtx::new("deform", &std::env::temp_dir());
        let mut i = inputs(6.0, 12);
        i.transform = Arc::new(Transform::identity("world", "mri_lps"));
        let e = op().run(i, &mut ctx).map(|_| ()).unwrap_err().to_string();
        assert!(e.contains("maps `world` -> `mri_lps`"), "{e}");
        let mut i = inputs(6.0, 12);
        let (scan, _) = dome(4.0);
        i.target = cloud(&scan, None, "mri_lps");
        let e = op().run(i, &mut ctx).map(|_| ()).unwrap_err().to_string();
        assert!(e.contains("no normals"), "{e}");
        let mut i = inputs(6.0, 12);
        i.landmarks_target = None;
        let e = op().run(i, &mut ctx).map(|_| ()).unwrap_err().to_string();
        assert!(e.contains("connect both"), "{e}");
    }

    #[test]
    fn a_field_is_refused_when_it_explains_too_little_or_moves_too_far() {
        let op: Deformable = fusegraph_engine::typed::declared_defaults().unwrap();
        // Sagged 5 mm (measured): 0.74 mm RMS after the rigid fit, 0.11 after
        // the field, which explains 99 % of it.
        assert_eq!(op.refusal(&Explained::of(0.743, 0.109), 6.0), None);
        // Unmoved, lab preset at 6 DN (measured): the field explains 0.22 mm
        // of 0.67, a third; enough by the absolute rule alone.
        let noise = op
            .refusal(&Explained::of(0.67, 0.632), 2.0)
            .expect("refused");
        assert!(noise.contains("min_explained_share"), "{noise}");
        // Unmoved, ideal: too little in millimetres.
        let small = op
            .refusal(&Explained::of(0.121, 0.118), 1.0)
            .expect("refused");
        assert!(small.contains("min_explained_mm"), "{small}");
        // A peak past max_motion_mm.
        let far = op.refusal(&Explained::of(3.0, 0.5), 45.0).expect("refused");
        assert!(far.contains("max_motion_mm"), "{far}");
        // The share's edge: 0.8 of the residual explained is applied.
        let after_at_edge = (1.0f64 - 0.8 * 0.8).sqrt();
        assert_eq!(
            op.refusal(&Explained::of(1.0, after_at_edge - 1e-9), 5.0),
            None
        );
        assert!(
            op.refusal(&Explained::of(1.0, after_at_edge + 1e-3), 5.0)
                .is_some()
        );
    }
}
