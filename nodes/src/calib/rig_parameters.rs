//! A stereo rig's estimated parameters by name, their covariance as a
//! [`Table`], and how a point the rig triangulates moves when they are off:
//! the calibration's uncertainty carried into 3D (and how a point's 3 x 3
//! covariance is written in a table).
//!
//! The names are those of `calib.stereo_calibrate`'s solver: each camera's
//! estimated intrinsics (`left_fx_px`, ..., `right_k2`), then the rig's
//! left -> right rotation vector (`rotation_vector_x_rad`, ...; R = exp([v]x))
//! and translation (`translation_x_mm`, ..., right camera frame).

use crate::calib::rig_isometry;
use crate::camera::CameraModel;
use fusegraph_engine::value::{StereoRig, Table};
use nalgebra::{
    DMatrix, Isometry3, Matrix3, Matrix4x3, Point3, Translation3, UnitQuaternion, Vector3,
};

/// Intrinsics in the solver's order, with their units.
pub const INTRINSIC_NAMES: [&str; 9] = [
    "fx_px", "fy_px", "cx_px", "cy_px", "k1", "k2", "p1", "p2", "k3",
];

/// The rig's six pose parameters, in the solver's order.
pub const POSE_NAMES: [&str; 6] = [
    "rotation_vector_x_rad",
    "rotation_vector_y_rad",
    "rotation_vector_z_rad",
    "translation_x_mm",
    "translation_y_mm",
    "translation_z_mm",
];

/// A stereo rig as plain types: both cameras and left -> right (mm).
#[derive(Debug, Clone, PartialEq)]
pub struct RigModel {
    /// The left (reference) camera.
    pub left: CameraModel,
    /// The right camera.
    pub right: CameraModel,
    /// Left camera frame -> right camera frame, mm.
    pub left_to_right: Isometry3<f64>,
}

impl RigModel {
    /// The model of an engine rig value.
    pub fn from_value(rig: &StereoRig) -> Self {
        RigModel {
            left: CameraModel::from_value(&rig.left),
            right: CameraModel::from_value(&rig.right),
            left_to_right: rig_isometry(rig),
        }
    }

    /// Where a point of the left camera's frame (mm) appears in the raw
    /// (distorted) left and right images: u, v left, then u, v right (px);
    /// `None` behind either camera.
    pub fn project(&self, p: &Point3<f64>) -> Option<[f64; 4]> {
        let l = self.left.project(p)?;
        let r = self.right.project(&(self.left_to_right * p))?;
        Some([l.x, l.y, r.x, r.y])
    }

    /// The rig with the named parameters moved by `delta` (their units).
    pub fn perturbed(&self, names: &[String], delta: &[f64]) -> Result<RigModel, String> {
        let mut rig = self.clone();
        let mut rotation = self.left_to_right.rotation.scaled_axis();
        let mut translation = self.left_to_right.translation.vector;
        for (name, &d) in names.iter().zip(delta) {
            if let Some(i) = POSE_NAMES.iter().position(|n| n == name) {
                if i < 3 {
                    rotation[i] += d;
                } else {
                    translation[i - 3] += d;
                }
                continue;
            }
            let (camera, intrinsic) = if let Some(rest) = name.strip_prefix("left_") {
                (&mut rig.left, rest)
            } else if let Some(rest) = name.strip_prefix("right_") {
                (&mut rig.right, rest)
            } else {
                return Err(format!("`{name}` is not a rig parameter"));
            };
            match INTRINSIC_NAMES.iter().position(|n| *n == intrinsic) {
                Some(0) => camera.fx += d,
                Some(1) => camera.fy += d,
                Some(2) => camera.cx += d,
                Some(3) => camera.cy += d,
                Some(k) => camera.distortion[k - 4] += d,
                None => return Err(format!("`{name}` is not a rig parameter")),
            }
        }
        rig.left_to_right = Isometry3::from_parts(
            Translation3::from(translation),
            UnitQuaternion::from_scaled_axis(rotation),
        );
        Ok(rig)
    }
}

/// Table columns of a 3 x 3 covariance's upper triangle, mm^2.
pub const COVARIANCE_COLUMNS: [&str; 6] = [
    "cov_xx_mm2",
    "cov_xy_mm2",
    "cov_xz_mm2",
    "cov_yy_mm2",
    "cov_yz_mm2",
    "cov_zz_mm2",
];

/// A 3 x 3 covariance's upper triangle, in [`COVARIANCE_COLUMNS`]' order.
pub fn covariance_entries(c: &Matrix3<f64>) -> [f64; 6] {
    [
        c[(0, 0)],
        c[(0, 1)],
        c[(0, 2)],
        c[(1, 1)],
        c[(1, 2)],
        c[(2, 2)],
    ]
}

/// The symmetric 3 x 3 matrix of an upper triangle in
/// [`COVARIANCE_COLUMNS`]' order (the inverse of [`covariance_entries`]).
pub fn covariance_from_entries(e: [f64; 6]) -> Matrix3<f64> {
    Matrix3::new(e[0], e[1], e[2], e[1], e[3], e[4], e[2], e[4], e[5])
}

/// The covariance (mm^2) of each of `ids` from a table with an `id` column
/// and [`COVARIANCE_COLUMNS`] (as `stereo.hsv_markers` writes), in `ids`'
/// order; an error naming a missing column or id.
pub fn covariances_for_ids(table: &Table, ids: &[u32]) -> Result<Vec<Matrix3<f64>>, String> {
    let column = |name: &str| {
        table
            .column(name)
            .ok_or_else(|| format!("no column `{name}`"))
    };
    let id_column = column("id")?;
    let entries: Vec<Vec<f64>> = COVARIANCE_COLUMNS
        .iter()
        .map(|c| column(c))
        .collect::<Result<_, _>>()?;
    ids.iter()
        .map(|&id| {
            let r = id_column
                .iter()
                .position(|&x| x == id as f64)
                .ok_or_else(|| format!("no row for marker {id}"))?;
            Ok(covariance_from_entries(std::array::from_fn(|k| {
                entries[k][r]
            })))
        })
        .collect()
}

/// `leading` columns, then [`COVARIANCE_COLUMNS`].
pub fn columns_with_covariance(leading: &[&str]) -> Vec<String> {
    leading
        .iter()
        .chain(COVARIANCE_COLUMNS.iter())
        .map(|c| c.to_string())
        .collect()
}

/// The names of a stereo calibration's shared parameters: each camera's
/// estimated intrinsics (`estimated`: solver-order indices), then the rig's.
pub fn parameter_names(estimated: &[usize]) -> Vec<String> {
    let mut names = Vec::new();
    for side in ["left_", "right_"] {
        names.extend(
            estimated
                .iter()
                .map(|&i| format!("{side}{}", INTRINSIC_NAMES[i])),
        );
    }
    names.extend(POSE_NAMES.iter().map(|n| n.to_string()));
    names
}

/// Named parameters and their covariance (units: the names').
#[derive(Debug, Clone, PartialEq)]
pub struct ParameterCovariance {
    /// One name per parameter.
    pub names: Vec<String>,
    /// Symmetric, names x names.
    pub matrix: DMatrix<f64>,
}

impl ParameterCovariance {
    /// As a table: one column per parameter, one row per parameter in the
    /// same order.
    pub fn to_table(&self) -> Table {
        let n = self.names.len();
        let data: Vec<f64> = (0..n * n).map(|k| self.matrix[(k / n, k % n)]).collect();
        Table::new(self.names.clone(), data).expect("a square table")
    }

    /// From such a table: square, finite, symmetric, with a non-negative
    /// diagonal.
    pub fn from_table(table: &Table) -> Result<Self, String> {
        let n = table.columns.len();
        if table.row_count() != n {
            return Err(format!(
                "a covariance table has one row per column: {n} columns, {} rows",
                table.row_count()
            ));
        }
        let matrix = DMatrix::from_fn(n, n, |r, c| table.data[r * n + c]);
        let scale = matrix.diagonal().amax().max(f64::MIN_POSITIVE);
        for r in 0..n {
            if !matrix[(r, r)].is_finite() || matrix[(r, r)] < 0.0 {
                return Err(format!(
                    "the variance of `{}` is {}: not a covariance",
                    table.columns[r],
                    matrix[(r, r)]
                ));
            }
            for c in 0..r {
                if !matrix[(r, c)].is_finite()
                    || (matrix[(r, c)] - matrix[(c, r)]).abs() > 1e-9 * scale
                {
                    return Err(format!(
                        "`{}` and `{}`: the covariance table is not symmetric",
                        table.columns[r], table.columns[c]
                    ));
                }
            }
        }
        Ok(ParameterCovariance {
            names: table.columns.clone(),
            matrix,
        })
    }

    /// Directions of one standard deviation whose outer products sum to the
    /// covariance (the columns of its Cholesky factor; of its eigenvectors
    /// scaled by the root eigenvalues where it is only semi-definite).
    pub fn sigma_directions(&self) -> Vec<Vec<f64>> {
        let n = self.names.len();
        let factor = match self.matrix.clone().cholesky() {
            Some(c) => c.l(),
            None => {
                let e = self.matrix.clone().symmetric_eigen();
                let mut f = e.eigenvectors.clone();
                for (k, &l) in e.eigenvalues.iter().enumerate() {
                    f.column_mut(k).scale_mut(l.max(0.0).sqrt());
                }
                f
            }
        };
        (0..n)
            .map(|k| factor.column(k).iter().copied().collect())
            .collect()
    }
}

/// How a point the rig triangulated moves when the rig's parameters are off
/// by each of the directions `perturbed` was made from ([`perturbed_rigs`]):
/// for a point `p` (left camera
/// frame, mm) seen at the raw pixels it projects to, the first-order shift of
/// its triangulation, -(A^T A)^-1 A^T B, with A the pixels' derivative in p
/// and B in the parameters (central differences). `None` behind a camera or
/// where the two rays are parallel.
pub fn triangulation_shifts(
    rig: &RigModel,
    perturbed: &[(RigModel, RigModel)],
    p: &Point3<f64>,
) -> Option<Vec<Vector3<f64>>> {
    shifts_with(&pixel_jacobian(rig, p)?, perturbed, p)
}

/// [`triangulation_shifts`] given the pixels' Jacobian `a` at `p`.
fn shifts_with(
    a: &Matrix4x3<f64>,
    perturbed: &[(RigModel, RigModel)],
    p: &Point3<f64>,
) -> Option<Vec<Vector3<f64>>> {
    let solve = (a.transpose() * a).try_inverse()? * a.transpose();
    perturbed
        .iter()
        .map(|(plus, minus)| {
            let (up, um) = (plus.project(p)?, minus.project(p)?);
            let b = nalgebra::Vector4::from_fn(|r, _| (up[r] - um[r]) / 2.0);
            Some(-(solve * b))
        })
        .collect()
}

/// The raw pixels' derivative in the point (4 x 3, px per mm; rows u, v
/// left then right), by central differences of 1 um; `None` behind a
/// camera.
fn pixel_jacobian(rig: &RigModel, p: &Point3<f64>) -> Option<Matrix4x3<f64>> {
    const H_MM: f64 = 1e-3;
    let mut a = Matrix4x3::zeros();
    for axis in 0..3 {
        let mut step = Vector3::zeros();
        step[axis] = H_MM;
        let (plus, minus) = (rig.project(&(p + step))?, rig.project(&(p - step))?);
        for r in 0..4 {
            a[(r, axis)] = (plus[r] - minus[r]) / (2.0 * H_MM);
        }
    }
    Some(a)
}

/// The covariance (mm^2, left camera frame) of point `p` triangulated from
/// the raw pixels it projects to, each of whose coordinates is off by
/// independent noise of `sigma_px`, by a rig whose parameters have the
/// spread `perturbed` was made from ([`perturbed_rigs`]; empty: none):
/// sigma^2 (A^T A)^-1 plus the outer products of the calibration's shifts.
/// `None` behind a camera or where the rays are parallel.
pub fn triangulated_covariance(
    rig: &RigModel,
    perturbed: &[(RigModel, RigModel)],
    p: &Point3<f64>,
    sigma_px: f64,
) -> Option<Matrix3<f64>> {
    let a = pixel_jacobian(rig, p)?;
    let noise = (a.transpose() * a).try_inverse()? * sigma_px.powi(2);
    let shifts = shifts_with(&a, perturbed, p)?;
    Some(shifts.iter().fold(noise, |c, s| c + s * s.transpose()))
}

/// The rigs moved by + and - each of `directions`, for
/// [`triangulation_shifts`].
pub fn perturbed_rigs(
    rig: &RigModel,
    names: &[String],
    directions: &[Vec<f64>],
) -> Result<Vec<(RigModel, RigModel)>, String> {
    directions
        .iter()
        .map(|d| {
            let minus: Vec<f64> = d.iter().map(|x| -x).collect();
            Ok((rig.perturbed(names, d)?, rig.perturbed(names, &minus)?))
        })
        .collect()
}

/// The rigs moved by + and - each standard-deviation direction of a
/// parameter covariance table (calib.stereo_calibrate's `covariance`), for
/// [`triangulation_shifts`].
pub fn perturbed_rigs_from_table(
    rig: &RigModel,
    covariance: &Table,
) -> Result<Vec<(RigModel, RigModel)>, String> {
    let c = ParameterCovariance::from_table(covariance)?;
    perturbed_rigs(rig, &c.names, &c.sigma_directions())
}

/// The rig moved by + and - a disparity offset of `sd_px` that every match
/// shares (a dense matcher's bias on a curved, weakly textured surface),
/// for [`triangulation_shifts`]: the right camera's principal point moved
/// along its rows by `sd_px`, which moves every disparity by as much (to
/// first order, for a rig near its rectified one) and every point along its
/// ray by z^2 / (f b) per px.
pub fn disparity_offset_rigs(rig: &RigModel, sd_px: f64) -> (RigModel, RigModel) {
    let (mut plus, mut minus) = (rig.clone(), rig.clone());
    plus.right.cx += sd_px;
    minus.right.cx -= sd_px;
    (plus, minus)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn marker_covariances_are_read_back_by_id_from_their_table() {
        let a = Matrix3::new(4.0, 0.5, -0.2, 0.5, 1.0, 0.3, -0.2, 0.3, 9.0);
        let b = Matrix3::from_diagonal(&Vector3::new(0.01, 0.02, 0.5));
        let rows: Vec<f64> = [(7.0, a), (2.0, b)]
            .iter()
            .flat_map(|(id, c)| std::iter::once(*id).chain(covariance_entries(c)))
            .collect();
        let table = Table::new(columns_with_covariance(&["id"]), rows).unwrap();
        // In the order asked, not the table's.
        assert_eq!(covariances_for_ids(&table, &[2, 7]).unwrap(), vec![b, a]);
        assert_eq!(covariance_from_entries(covariance_entries(&a)), a);
        assert!(
            covariances_for_ids(&table, &[3])
                .unwrap_err()
                .contains("marker 3")
        );
    }

    fn camera() -> CameraModel {
        CameraModel {
            width: 800,
            height: 600,
            fx: 1300.0,
            fy: 1300.0,
            cx: 400.0,
            cy: 300.0,
            distortion: [-0.1, 0.05, 0.0, 0.0, 0.0],
        }
    }

    fn rig() -> RigModel {
        RigModel {
            left: camera(),
            right: camera(),
            left_to_right: Isometry3::new(
                Vector3::new(-55.0, 0.0, 0.0),
                Vector3::new(0.0, 0.05, 0.0),
            ),
        }
    }

    /// Triangulates raw pixels with a rig by Gauss-Newton on the
    /// reprojection error (numeric Jacobian), from `start`.
    fn triangulate(rig: &RigModel, pixels: &[f64; 4], start: Point3<f64>) -> Point3<f64> {
        let mut p = start;
        for _ in 0..20 {
            let u = rig.project(&p).unwrap();
            let r = nalgebra::Vector4::from_fn(|i, _| u[i] - pixels[i]);
            let a = pixel_jacobian(rig, &p).unwrap();
            let step = (a.transpose() * a).try_inverse().unwrap() * a.transpose() * r;
            p -= step;
        }
        p
    }

    #[test]
    fn a_points_shift_is_its_retriangulation_with_the_rig_off() {
        // The same pixels triangulated with a rig whose focal length,
        // principal point and baseline are slightly off land where the
        // first-order shift says, to a few per cent of the shift.
        let rig = rig();
        let names: Vec<String> = [
            "left_fx_px",
            "right_cx_px",
            "translation_x_mm",
            "rotation_vector_y_rad",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        let directions = vec![
            vec![2.0, 0.0, 0.0, 0.0],
            vec![0.0, 0.5, 0.0, 0.0],
            vec![0.0, 0.0, 0.1, 0.0],
            vec![0.0, 0.0, 0.0, 1e-4],
        ];
        let rigs = perturbed_rigs(&rig, &names, &directions).unwrap();
        let p = Point3::new(20.0, -15.0, 600.0);
        let shifts = triangulation_shifts(&rig, &rigs, &p).unwrap();
        let pixels = rig.project(&p).unwrap();
        for (k, d) in directions.iter().enumerate() {
            let off = rig.perturbed(&names, d).unwrap();
            let moved = triangulate(&off, &pixels, p);
            let (expected, got) = (moved - p, shifts[k]);
            assert!(
                expected.norm() > 0.05,
                "{k}: the shift is measurable ({expected})"
            );
            assert!(
                (expected - got).norm() < 0.03 * expected.norm(),
                "{k}: {expected} vs {got}"
            );
        }
        // A baseline 0.1 mm shorter (x from -55 to -54.9 mm) puts a point at
        // 600 mm about 600 * 0.1 / 55 mm nearer (depth is proportional to
        // the baseline).
        assert!(
            (shifts[2].z + 600.0 * 0.1 / 55.0).abs() < 0.1,
            "{}",
            shifts[2]
        );
    }

    #[test]
    fn a_shared_disparity_offset_moves_a_point_along_its_ray_by_z2_over_fb() {
        // 0.05 px at 600 mm with f = 1300 px and b = 55 mm: 600^2 * 0.05 /
        // (1300 * 55) = 0.2517 mm of depth, along the point's ray.
        let rig = rig();
        let p = Point3::new(20.0, -15.0, 600.0);
        let shifts = triangulation_shifts(&rig, &[disparity_offset_rigs(&rig, 0.05)], &p).unwrap();
        let shift = shifts[0];
        let depth = 600.0f64.powi(2) * 0.05 / (1300.0 * 55.0);
        assert!((shift.z.abs() - depth).abs() < 0.03 * depth, "{shift}");
        let along = shift.dot(&p.coords.normalize()).abs();
        let across = (shift.norm_squared() - along * along).max(0.0).sqrt();
        assert!(across < 0.1 * along, "{shift}: {across} across the ray");
    }

    #[test]
    fn a_covariance_table_round_trips_and_bad_ones_are_refused() {
        let names = parameter_names(&[0, 2, 4]);
        assert_eq!(names[0], "left_fx_px");
        assert_eq!(names[3], "right_fx_px");
        assert_eq!(names[6], "rotation_vector_x_rad");
        let n = names.len();
        let matrix = DMatrix::from_fn(n, n, |r, c| if r == c { 1.0 + r as f64 } else { 0.1 });
        let c = ParameterCovariance { names, matrix };
        assert_eq!(ParameterCovariance::from_table(&c.to_table()).unwrap(), c);
        let directions = c.sigma_directions();
        let sum = directions.iter().fold(DMatrix::zeros(n, n), |s, d| {
            let v = nalgebra::DVector::from_column_slice(d);
            s + &v * v.transpose()
        });
        assert!((sum - &c.matrix).amax() < 1e-9);
        let mut t = c.to_table();
        let mut data = t.data.to_vec();
        data[1] = 0.5;
        t.data = data.into();
        let e = ParameterCovariance::from_table(&t).unwrap_err();
        assert!(e.contains("not symmetric"), "{e}");
        let wide = Table::new(vec!["a".into(), "b".into()], vec![1.0, 0.0]).unwrap();
        assert!(
            ParameterCovariance::from_table(&wide)
                .unwrap_err()
                .contains("one row per column")
        );
        let e = rig()
            .perturbed(&["middle_fx_px".to_string()], &[1.0])
            .unwrap_err();
        assert!(e.contains("`middle_fx_px`"), "{e}");
    }

    #[test]
    fn a_points_covariance_is_the_spread_of_its_triangulations() {
        // 2,000 triangulations of the pixels of one point, each coordinate
        // off by 0.2 px of noise, with the rig itself off along its spread
        // (0.5 px of left fx, 0.05 mm of baseline) drawn anew each time.
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let rig = rig();
        let names: Vec<String> = ["left_fx_px", "translation_x_mm"]
            .iter()
            .map(|s| s.to_string())
            .collect();
        let spread = ParameterCovariance {
            names: names.clone(),
            matrix: DMatrix::from_diagonal(&nalgebra::DVector::from_vec(vec![0.25, 0.0025])),
        };
        let rigs = perturbed_rigs(&rig, &names, &spread.sigma_directions()).unwrap();
        let p = Point3::new(-30.0, 20.0, 550.0);
        let predicted = triangulated_covariance(&rig, &rigs, &p, 0.2).unwrap();
        let pixels = rig.project(&p).unwrap();
        let mut rng = rand::rngs::StdRng::seed_from_u64(11);
        let (pixel, unit) = (
            Normal::new(0.0, 0.2).unwrap(),
            Normal::new(0.0, 1.0).unwrap(),
        );
        let draws: Vec<Vector3<f64>> = (0..2000)
            .map(|_| {
                let noisy: [f64; 4] = std::array::from_fn(|i| pixels[i] + pixel.sample(&mut rng));
                // The true rig is the estimate off by minus the error.
                let error = [0.5 * unit.sample(&mut rng), 0.05 * unit.sample(&mut rng)];
                let truth = rig.perturbed(&names, &error).unwrap();
                let seen = truth.project(&p).unwrap();
                let observed: [f64; 4] = std::array::from_fn(|i| noisy[i] - pixels[i] + seen[i]);
                triangulate(&rig, &observed, p).coords
            })
            .collect();
        let mean = draws.iter().sum::<Vector3<f64>>() / draws.len() as f64;
        let sample = draws.iter().fold(Matrix3::zeros(), |c, d| {
            c + (d - mean) * (d - mean).transpose()
        }) / (draws.len() - 1) as f64;
        for i in 0..3 {
            let ratio = (sample[(i, i)] / predicted[(i, i)]).sqrt();
            assert!(
                (ratio - 1.0).abs() < 0.1,
                "axis {i}: sd ratio {ratio}\n{sample}\n{predicted}"
            );
        }
        // From the pixels alone, depth is as the textbook has it: z^2 / (f b)
        // times the disparity's noise, sqrt(2) x 0.2 px, here about 1.2 mm
        // (to 10 %: the rig verges and the point is off-axis).
        let pixels_only = triangulated_covariance(&rig, &[], &p, 0.2).unwrap();
        let textbook = 550.0f64.powi(2) / (1300.0 * 55.0) * 0.2 * 2f64.sqrt();
        let sd_z = pixels_only[(2, 2)].sqrt();
        assert!((sd_z / textbook - 1.0).abs() < 0.1, "{sd_z} vs {textbook}");
    }
}
