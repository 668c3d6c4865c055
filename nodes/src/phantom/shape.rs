//! The phantom's solid geometry in its own frame (mm): a tilted half-ellipsoid
//! dome standing on the plane z = 0, circular markers glued on the skin (each a
//! plastic disc holding an MRI-bright gel core, its outer face coloured), and
//! small internal lesions. Point classification (for the MRI) and ray casting
//! (for the cameras) are exact on this description.

use fusegraph_engine::typed::declared_defaults;
use fusegraph_plugin_api::derive::Params;
use fusegraph_plugin_api::typed::{ParamDefault, ParamKind, ParamRef, ParamType};
use nalgebra::{Point3, Rotation3, Unit, Vector3};
use rand::Rng;
use serde::{Deserialize, Serialize};
use std::sync::OnceLock;

/// What a point of space is made of.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Material {
    /// Air (or the plastic base plate under the dome).
    Background,
    /// Breast-like tissue.
    Tissue,
    /// A lesion inside the tissue.
    Lesion,
    /// Marker plastic (dark in MRI).
    Plastic,
    /// Marker gel core (petroleum jelly, bright in MRI).
    Gel,
}

/// One marker: a disc of plastic on the skin with a gel core.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Marker {
    /// Marker number, 0-based.
    pub id: u32,
    /// Where the disc's axis meets the skin, phantom frame, mm.
    pub skin_point_mm: [f64; 3],
    /// Outward unit normal of the skin there (the disc's axis).
    pub normal: [f64; 3],
    /// Disc radius, mm.
    pub radius_mm: f64,
    /// How far the disc reaches below the skin point along -normal, mm.
    pub below_skin_mm: f64,
    /// Height of the outer (coloured) face above the skin point, mm.
    pub height_mm: f64,
    /// Gel core radius, mm.
    pub gel_radius_mm: f64,
    /// Gel core extent along the normal, mm above the skin point: [from, to].
    pub gel_span_mm: [f64; 2],
}

impl Marker {
    fn axis(&self) -> (Point3<f64>, Vector3<f64>) {
        (Point3::from(self.skin_point_mm), Vector3::from(self.normal))
    }

    /// Centre of the gel core (the marker centre MRI sees), phantom frame, mm.
    pub fn gel_center(&self) -> Point3<f64> {
        let (s, n) = self.axis();
        s + n * (0.5 * (self.gel_span_mm[0] + self.gel_span_mm[1]))
    }

    /// Centre of the coloured outer face (the marker centre cameras see), mm.
    pub fn face_center(&self) -> Point3<f64> {
        let (s, n) = self.axis();
        s + n * self.height_mm
    }

    /// What the marker is made of at `p`, or `None` outside it.
    pub fn material_at(&self, p: &Point3<f64>) -> Option<Material> {
        let (s, n) = self.axis();
        let d = p - s;
        let h = d.dot(&n);
        if h < -self.below_skin_mm || h > self.height_mm {
            return None;
        }
        let radial2 = d.norm_squared() - h * h;
        if radial2 > self.radius_mm * self.radius_mm {
            return None;
        }
        let in_gel = h >= self.gel_span_mm[0]
            && h <= self.gel_span_mm[1]
            && radial2 <= self.gel_radius_mm * self.gel_radius_mm;
        Some(if in_gel {
            Material::Gel
        } else {
            Material::Plastic
        })
    }

    /// Squared radius of a sphere around the skin point holding the whole
    /// marker, mm^2 (no square root: it is tested per MRI sample).
    pub(super) fn bounding_radius_squared(&self) -> f64 {
        let reach = self.height_mm.max(self.below_skin_mm);
        reach * reach + self.radius_mm * self.radius_mm
    }
}

/// A spherical lesion.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Lesion {
    /// Lesion number, 0-based.
    pub id: u32,
    /// Centre, phantom frame, mm.
    pub center_mm: [f64; 3],
    /// Radius, mm.
    pub radius_mm: f64,
}

/// The declared default of `ShapeParams::lesion_signal`, for truth files
/// written before it could be set.
fn default_lesion_signal() -> f32 {
    ShapeParams::default().lesion_signal as f32
}

fn is_default_lesion_signal(signal: &f32) -> bool {
    *signal == default_lesion_signal()
}

/// The whole phantom, in its own frame (mm): base on z = 0, dome towards +z.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PhantomShape {
    /// Centre of the ellipsoid whose upper part is the dome, mm (below z = 0).
    pub ellipsoid_center_mm: [f64; 3],
    /// Semi-axes of the ellipsoid along its own x, y, z, mm.
    pub semi_axes_mm: [f64; 3],
    /// Rotation of the ellipsoid about the phantom x axis (a forward droop), deg.
    pub tilt_deg: f64,
    /// The markers.
    pub markers: Vec<Marker>,
    /// The lesions.
    pub lesions: Vec<Lesion>,
    /// The lesions' MR signal (tissue 0.55, gel 1.0). Written only when not
    /// the default, so the default phantom's files stay byte for byte what
    /// they were before it could be set.
    #[serde(
        default = "default_lesion_signal",
        skip_serializing_if = "is_default_lesion_signal"
    )]
    pub lesion_signal: f32,
    /// The ellipsoid's rotation, computed once (ray casting asks per sample).
    #[serde(skip)]
    rotation_cache: Derived<Rotation3<f64>>,
    /// The sphere holding the dome and the markers, computed once.
    #[serde(skip)]
    bound_cache: Derived<BodyBound>,
}

/// A value derived from the rest of its struct and computed on first use
/// (the struct is not changed after it is built): no part of the struct's
/// equality or of its serialised form.
#[derive(Debug, Clone)]
struct Derived<T>(OnceLock<T>);

impl<T> Default for Derived<T> {
    fn default() -> Self {
        Derived(OnceLock::new())
    }
}

impl<T> PartialEq for Derived<T> {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

/// Margin of [`BodyBound`]'s radius beyond what it holds, mm: far above the
/// rounding of a hit's position (about 1e-13 mm here), so a ray that misses
/// the sphere surely meets nothing inside it.
const BOUND_MARGIN_MM: f64 = 1e-3;

/// A sphere (phantom frame, mm) holding the dome (the ellipsoid's part
/// above z = 0) and every marker's bounding sphere, [`BOUND_MARGIN_MM`]
/// wider: most of a view's rays, and the shadow rays from the table, pass
/// it by, and skip the ellipsoid's and the twelve markers' tests.
#[derive(Debug, Clone, Copy)]
struct BodyBound {
    centre: Point3<f64>,
    radius_squared: f64,
}

impl BodyBound {
    /// Around the box holding the dome: the rotated ellipsoid's box (its
    /// half extent along axis i is the length of row i of R diag(a)) cut to
    /// z >= 0; widened to each marker's bounding sphere.
    fn of(shape: &PhantomShape) -> Self {
        let r = shape.rotation();
        let (axes, c) = (shape.semi_axes_mm, shape.ellipsoid_center_mm);
        let half: [f64; 3] = std::array::from_fn(|i| {
            (0..3)
                .map(|j| (r[(i, j)] * axes[j]).powi(2))
                .sum::<f64>()
                .sqrt()
        });
        let lo = Vector3::new(c[0] - half[0], c[1] - half[1], (c[2] - half[2]).max(0.0));
        let hi = Vector3::new(c[0] + half[0], c[1] + half[1], (c[2] + half[2]).max(0.0));
        let centre = Point3::from(0.5 * (lo + hi));
        let radius = shape
            .markers
            .iter()
            .map(|m| {
                (Point3::from(m.skin_point_mm) - centre).norm() + m.bounding_radius_squared().sqrt()
            })
            .fold(0.5 * (hi - lo).norm(), f64::max)
            + BOUND_MARGIN_MM;
        BodyBound {
            centre,
            radius_squared: radius * radius,
        }
    }

    /// Whether the ray from `origin` along unit `dir` surely meets nothing
    /// inside the sphere at a distance t >= 0: its line passes the sphere
    /// by, or the sphere lies wholly behind the origin.
    fn passed_by(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> bool {
        let w = origin - self.centre;
        let b_half = w.dot(dir);
        let c = w.norm_squared() - self.radius_squared;
        c > 0.0 && (b_half > 0.0 || b_half * b_half < c)
    }
}

/// The geometry parameters a phantom is built from, in the phantom's own
/// frame (mm): the dome's width along x and depth along y at its base on
/// z = 0, its height along z, a forward droop about x; markers on the skin
/// and spherical lesions inside. They are the shape parameters of
/// `phantom.generate` (flattened into it), declared here once: each field's
/// doc, default, unit and range; [`Default`] gives the declared defaults.
#[derive(Debug, Clone, PartialEq, Params)]
pub struct ShapeParams {
    /// Dome width at the base
    #[param(default = 130.0, unit = "mm", min = 60.0, max = 200.0)]
    pub width_mm: f64,
    /// Dome depth at the base
    #[param(default = 120.0, unit = "mm", min = 60.0, max = 200.0)]
    pub depth_mm: f64,
    /// Dome height
    #[param(default = 60.0, unit = "mm", min = 30.0, max = 100.0)]
    pub height_mm: f64,
    /// Forward droop of the dome
    #[param(default = 8.0, unit = "deg", min = -20.0, max = 20.0)]
    pub droop_deg: f64,
    /// Number of markers
    #[param(default = 12, min = 0, max = 30)]
    pub marker_count: usize,
    /// Marker disc diameter
    #[param(default = 9.0, unit = "mm", min = 4.0, max = 20.0)]
    pub marker_diameter_mm: f64,
    /// Marker height above the skin
    #[param(default = 5.0, unit = "mm", min = 2.5, max = 10.0)]
    pub marker_thickness_mm: f64,
    /// Lesion centres in the phantom frame, flattened x, y, z triples
    #[param(
        default = Triples(vec![[12.0, -8.0, 22.0], [-18.0, 14.0, 16.0], [20.0, 16.0, 32.0]]),
        unit = "mm",
        length_multiple_of = 3
    )]
    pub lesions_mm: Triples,
    /// Lesion diameter
    #[param(default = 6.0, unit = "mm", min = 1.0, max = 20.0)]
    pub lesion_diameter_mm: f64,
    /// The lesions' MR signal, in the scan's signal units (tissue 0.55, gel 1.0, air 0): below 0.55 darker than the tissue, above it brighter; the contrast-to-noise ratio is |this - 0.55| / mri_noise
    #[param(default = 0.35, min = 0.0, max = 1.5)]
    pub lesion_signal: f64,
}

impl Default for ShapeParams {
    /// Every parameter at its declared default.
    fn default() -> Self {
        declared_defaults().expect("every shape parameter has a default")
    }
}

/// 3D points (x, y, z, e.g. mm) that a parameter gives as one flat list of
/// numbers, whose length must be a multiple of 3.
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct Triples(pub Vec<[f64; 3]>);

impl std::ops::Deref for Triples {
    type Target = [[f64; 3]];
    fn deref(&self) -> &Self::Target {
        &self.0
    }
}

impl From<Vec<[f64; 3]>> for Triples {
    fn from(points: Vec<[f64; 3]>) -> Self {
        Triples(points)
    }
}

impl ParamType for Triples {
    const KIND: ParamKind = ParamKind::FloatList;
    fn from_param(value: ParamRef<'_>) -> Result<Self, String> {
        let flat = Vec::<f64>::from_param(value)?;
        if flat.len() % 3 != 0 {
            return Err(format!(
                "holds {} numbers; it must hold x, y, z triples",
                flat.len()
            ));
        }
        Ok(Triples(
            flat.chunks(3).map(|c| [c[0], c[1], c[2]]).collect(),
        ))
    }
    fn to_default(&self) -> ParamDefault {
        ParamDefault::FloatList(self.0.iter().flatten().copied().collect())
    }
}

/// A ray hit on the phantom.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Distance along the (unit) ray, mm.
    pub t: f64,
    /// Outward unit normal at the hit.
    pub normal: Vector3<f64>,
    /// What was hit.
    pub surface: Surface,
}

/// Which surface a ray hit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Surface {
    /// The skin of the dome.
    Skin,
    /// The coloured outer face of marker `id`.
    MarkerFace(u32),
    /// The plastic side wall of a marker.
    MarkerSide,
}

impl PhantomShape {
    /// Builds the phantom: the ellipsoid is sized so its part above z = 0 has the
    /// requested base width, depth and height; markers are laid out in two rings
    /// with seeded jitter (so the layout has no symmetry).
    ///
    /// # Examples
    ///
    /// ```
    /// use fusegraph_nodes::phantom::{PhantomShape, ShapeParams};
    /// use rand::SeedableRng;
    ///
    /// let p = ShapeParams { marker_count: 6, ..ShapeParams::default() };
    /// let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    /// let shape = PhantomShape::build(&p, &mut rng).unwrap();
    /// assert_eq!(shape.markers.len(), 6);
    /// // The default lesions, 6 mm across.
    /// assert_eq!(shape.lesions.len(), 3);
    /// assert!(shape.lesions.iter().all(|l| l.radius_mm == 3.0));
    /// // Markers sit on the dome: their coloured faces above the base.
    /// assert!(shape.markers.iter().all(|m| m.face_center().z > 0.0));
    /// ```
    pub fn build(p: &ShapeParams, rng: &mut impl Rng) -> Result<Self, String> {
        if p.width_mm <= 0.0 || p.depth_mm <= 0.0 || p.height_mm <= 0.0 {
            return Err("phantom sizes must be positive".into());
        }
        // The ellipsoid centre sits a quarter of the height below the base, so the
        // skin meets the base at an angle, as a real breast phantom's does.
        let below = 0.25 * p.height_mm;
        let c = p.height_mm + below;
        let base_scale = (1.0 - (below / c).powi(2)).sqrt();
        let mut shape = PhantomShape {
            ellipsoid_center_mm: [0.0, 0.0, -below],
            semi_axes_mm: [
                0.5 * p.width_mm / base_scale,
                0.5 * p.depth_mm / base_scale,
                c,
            ],
            tilt_deg: p.droop_deg,
            markers: Vec::new(),
            lesions: Vec::new(),
            lesion_signal: p.lesion_signal as f32,
            rotation_cache: Derived::default(),
            bound_cache: Derived::default(),
        };
        shape.markers = shape.layout_markers(p, rng)?;
        for (i, c) in p.lesions_mm.iter().enumerate() {
            let center = Point3::from(*c);
            let r = 0.5 * p.lesion_diameter_mm;
            if !shape.inside_dome(&center) || shape.surface_clearance(&center) < r + 3.0 {
                return Err(format!(
                    "lesion {i} at {c:?} mm is not at least 3 mm inside the dome"
                ));
            }
            shape.lesions.push(Lesion {
                id: i as u32,
                center_mm: *c,
                radius_mm: r,
            });
        }
        Ok(shape)
    }

    /// Rotation of the ellipsoid's axes in the phantom frame.
    pub fn rotation(&self) -> Rotation3<f64> {
        *self.rotation_cache.0.get_or_init(|| {
            Rotation3::from_axis_angle(&Vector3::x_axis(), self.tilt_deg.to_radians())
        })
    }

    /// The sphere holding the dome and the markers.
    fn bound(&self) -> &BodyBound {
        self.bound_cache.0.get_or_init(|| BodyBound::of(self))
    }

    /// `p` in the ellipsoid's unit-sphere frame (the dome's surface at
    /// length 1).
    pub(super) fn to_unit_sphere(&self, p: &Point3<f64>) -> Vector3<f64> {
        self.to_unit_frame(&(p - Point3::from(self.ellipsoid_center_mm)))
    }

    /// A displacement `v` (phantom frame, mm) in the ellipsoid's
    /// unit-sphere frame.
    pub(super) fn to_unit_frame(&self, v: &Vector3<f64>) -> Vector3<f64> {
        (self.rotation().inverse() * v).component_div(&Vector3::from(self.semi_axes_mm))
    }

    /// Whether `p` is inside the dome (tissue, before markers and lesions).
    pub fn inside_dome(&self, p: &Point3<f64>) -> bool {
        p.z >= 0.0 && self.to_unit_sphere(p).norm_squared() <= 1.0
    }

    /// Outward unit normal of the ellipsoid at (or near) `p`.
    pub fn skin_normal(&self, p: &Point3<f64>) -> Vector3<f64> {
        let axes = Vector3::from(self.semi_axes_mm);
        let q = self.rotation().inverse() * (p - Point3::from(self.ellipsoid_center_mm));
        (self.rotation() * q.component_div(&axes.component_mul(&axes))).normalize()
    }

    /// What `p` is made of. Markers override tissue (their base is set into the
    /// skin), lesions override tissue.
    pub fn material_at(&self, p: &Point3<f64>) -> Material {
        self.material_among(&self.markers, &self.lesions, p)
    }

    /// [`PhantomShape::material_at`] with only `markers` (in the shape's
    /// order) and `lesions` tested: the same answer wherever the others
    /// cannot hold `p`.
    pub(super) fn material_among<'a>(
        &self,
        markers: impl IntoIterator<Item = &'a Marker>,
        lesions: impl IntoIterator<Item = &'a Lesion>,
        p: &Point3<f64>,
    ) -> Material {
        for m in markers {
            if (p - Point3::from(m.skin_point_mm)).norm_squared() <= m.bounding_radius_squared()
                && let Some(material) = m.material_at(p)
            {
                return material;
            }
        }
        if !self.inside_dome(p) {
            return Material::Background;
        }
        for l in lesions {
            if (p - Point3::from(l.center_mm)).norm_squared() <= l.radius_mm * l.radius_mm {
                return Material::Lesion;
            }
        }
        Material::Tissue
    }

    /// Where the ray from `origin` (inside the dome) along unit `dir` leaves the
    /// ellipsoid.
    fn exit_point(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Point3<f64> {
        let (t_near, t_far) = self
            .ellipsoid_roots(origin, dir)
            .expect("origin inside the ellipsoid");
        origin + dir * t_near.max(t_far)
    }

    /// Both ray parameters where the ray meets the ellipsoid, if it does.
    fn ellipsoid_roots(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Option<(f64, f64)> {
        self.ellipsoid_roots_from(&self.unit_origin(origin), dir)
    }

    /// `origin` in the ellipsoid's unit-sphere coordinates, and its squared
    /// length less 1: what [`PhantomShape::ellipsoid_roots`] needs of it.
    fn unit_origin(&self, origin: &Point3<f64>) -> (Vector3<f64>, f64) {
        let axes = Vector3::from(self.semi_axes_mm);
        let r_inv = self.rotation().inverse();
        let o = (r_inv * (origin - Point3::from(self.ellipsoid_center_mm))).component_div(&axes);
        let c = o.norm_squared() - 1.0;
        (o, c)
    }

    /// [`PhantomShape::ellipsoid_roots`] from the origin's
    /// [`PhantomShape::unit_origin`].
    fn ellipsoid_roots_from(
        &self,
        (o, c): &(Vector3<f64>, f64),
        dir: &Vector3<f64>,
    ) -> Option<(f64, f64)> {
        let axes = Vector3::from(self.semi_axes_mm);
        let r_inv = self.rotation().inverse();
        let d = (r_inv * dir).component_div(&axes);
        let (a, b, c) = (d.norm_squared(), 2.0 * o.dot(&d), *c);
        let disc = b * b - 4.0 * a * c;
        if disc < 0.0 {
            return None;
        }
        let sq = disc.sqrt();
        // Numerically stable roots.
        let q = -0.5 * (b + b.signum() * sq);
        let (t1, t2) = if q == 0.0 { (0.0, 0.0) } else { (q / a, c / q) };
        Some((t1.min(t2), t1.max(t2)))
    }

    /// The first surface hit by the ray from `origin` along unit `dir`, beyond
    /// `t_min`. The base (z = 0) is not a visible surface.
    pub fn intersect(&self, origin: &Point3<f64>, dir: &Vector3<f64>, t_min: f64) -> Option<Hit> {
        self.intersect_from(origin, &self.unit_origin(origin), dir, t_min, |i| {
            MarkerOffset::new(&self.markers[i], origin)
        })
    }

    /// Rays from `origin` (phantom frame, mm), ready for
    /// [`RaysFrom::intersect`].
    pub fn rays_from(&self, origin: &Point3<f64>) -> RaysFrom<'_> {
        RaysFrom {
            shape: self,
            origin: *origin,
            unit_origin: self.unit_origin(origin),
            markers: self
                .markers
                .iter()
                .map(|m| MarkerOffset::new(m, origin))
                .collect(),
        }
    }

    /// [`PhantomShape::intersect`] given what depends on the origin alone:
    /// its [`PhantomShape::unit_origin`] and each marker's offset. A ray
    /// that passes the [`BodyBound`] by meets nothing, without the tests
    /// ([`PhantomShape::intersect_each`]'s answer).
    fn intersect_from(
        &self,
        origin: &Point3<f64>,
        unit_origin: &(Vector3<f64>, f64),
        dir: &Vector3<f64>,
        t_min: f64,
        offset: impl Fn(usize) -> MarkerOffset,
    ) -> Option<Hit> {
        if t_min >= 0.0 && self.bound().passed_by(origin, dir) {
            return None;
        }
        self.intersect_each(origin, unit_origin, dir, t_min, offset)
    }

    /// [`PhantomShape::intersect_from`] by testing the skin and each
    /// marker.
    fn intersect_each(
        &self,
        origin: &Point3<f64>,
        unit_origin: &(Vector3<f64>, f64),
        dir: &Vector3<f64>,
        t_min: f64,
        offset: impl Fn(usize) -> MarkerOffset,
    ) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut consider = |hit: Hit| {
            if hit.t > t_min && best.is_none_or(|b| hit.t < b.t) {
                best = Some(hit);
            }
        };
        if let Some((t1, _)) = self.ellipsoid_roots_from(unit_origin, dir) {
            let p = origin + dir * t1;
            if p.z >= 0.0 {
                consider(Hit {
                    t: t1,
                    normal: self.skin_normal(&p),
                    surface: Surface::Skin,
                });
            }
        }
        for (i, m) in self.markers.iter().enumerate() {
            let offset = offset(i);
            if offset.passed_by(dir) {
                continue;
            }
            if let Some(hit) = intersect_marker(m, &offset, dir, t_min) {
                consider(hit);
            }
        }
        best
    }

    /// Euclidean distance (mm) from `p` (phantom frame, inside or outside) to the
    /// ellipsoid whose upper part is the skin, by Eberly's bisection on the
    /// Lagrange parameter ("Distance from a point to an ellipse, an ellipsoid,
    /// or a hyperellipsoid", 2013), accurate to ~1e-9 mm.
    pub fn distance_to_ellipsoid(&self, p: &Point3<f64>) -> f64 {
        let q = self.rotation().inverse() * (p - Point3::from(self.ellipsoid_center_mm));
        let e = self.semi_axes_mm;
        // First octant; a coordinate of exactly zero is nudged (the distance
        // changes by far less than the tolerance).
        let y: [f64; 3] = std::array::from_fn(|i| q[i].abs().max(1e-12));
        let f = |t: f64| {
            (0..3)
                .map(|i| (e[i] * y[i] / (t + e[i] * e[i])).powi(2))
                .sum::<f64>()
                - 1.0
        };
        let m = (0..3)
            .min_by(|&a, &b| e[a].total_cmp(&e[b]))
            .expect("three axes");
        let norm = (y[0] * y[0] + y[1] * y[1] + y[2] * y[2]).sqrt();
        let (mut lo, mut hi) = (
            -e[m] * e[m] + e[m] * y[m],
            e.iter().cloned().fold(0.0, f64::max) * norm,
        );
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if f(mid) > 0.0 {
                lo = mid
            } else {
                hi = mid
            }
            if hi - lo < 1e-13 * (1.0 + hi.abs()) {
                break;
            }
        }
        let t = 0.5 * (lo + hi);
        (0..3)
            .map(|i| (e[i] * e[i] * y[i] / (t + e[i] * e[i]) - y[i]).powi(2))
            .sum::<f64>()
            .sqrt()
    }

    /// Signed distance (mm) from `p` (phantom frame) to the ellipsoid:
    /// positive outside (along the outward normal), negative inside.
    pub fn signed_distance_to_ellipsoid(&self, p: &Point3<f64>) -> f64 {
        let d = self.distance_to_ellipsoid(p);
        if self.to_unit_sphere(p).norm_squared() < 1.0 {
            -d
        } else {
            d
        }
    }

    /// Distance (mm) from an inside point to the nearest point of the dome's
    /// skin, by sampling directions (an upper bound, exact to ~0.1 mm; used only
    /// to check lesion placement).
    fn surface_clearance(&self, p: &Point3<f64>) -> f64 {
        let mut best = p.z;
        for i in 0..40 {
            for j in 0..80 {
                let theta = std::f64::consts::PI * (i as f64 + 0.5) / 40.0;
                let phi = 2.0 * std::f64::consts::PI * j as f64 / 80.0;
                let d = Vector3::new(
                    theta.sin() * phi.cos(),
                    theta.sin() * phi.sin(),
                    theta.cos(),
                );
                if let Some((_, t_far)) = self.ellipsoid_roots(p, &d) {
                    best = best.min(t_far);
                }
            }
        }
        best
    }

    fn layout_markers(&self, p: &ShapeParams, rng: &mut impl Rng) -> Result<Vec<Marker>, String> {
        let n = p.marker_count;
        if n == 0 {
            return Ok(Vec::new());
        }
        let radius = 0.5 * p.marker_diameter_mm;
        let lower_ring = n.div_ceil(3) * 2;
        let origin = Point3::new(0.0, 0.0, 0.15 * p.height_mm);
        for _attempt in 0..200 {
            let mut markers = Vec::with_capacity(n);
            for i in 0..n {
                let (ring_i, ring_n, elevation_deg, phase_deg) = if i < lower_ring {
                    (i, lower_ring, 22.0, 0.0)
                } else {
                    (i - lower_ring, n - lower_ring, 52.0, 20.0)
                };
                let azimuth = (phase_deg
                    + 360.0 * ring_i as f64 / ring_n as f64
                    + rng.random_range(-12.0..12.0))
                .to_radians();
                let elevation = (elevation_deg + rng.random_range(-5.0..5.0f64)).to_radians();
                let dir = Vector3::new(
                    elevation.cos() * azimuth.cos(),
                    elevation.cos() * azimuth.sin(),
                    elevation.sin(),
                );
                let skin = self.exit_point(&origin, &dir);
                let normal = self.skin_normal(&skin);
                let thickness = p.marker_thickness_mm;
                markers.push(Marker {
                    id: i as u32,
                    skin_point_mm: skin.into(),
                    normal: normal.into(),
                    radius_mm: radius,
                    below_skin_mm: 1.0,
                    height_mm: thickness,
                    gel_radius_mm: (radius - 1.5).max(0.5 * radius),
                    gel_span_mm: [0.4 * thickness, 0.8 * thickness],
                });
            }
            if markers_apart(&markers, radius) {
                return Ok(markers);
            }
        }
        Err(format!(
            "cannot place {n} markers of {} mm apart on this dome; use fewer or smaller markers",
            p.marker_diameter_mm
        ))
    }
}

/// Markers must keep clear of each other (a gap of at least 6 mm between discs).
/// The seeded jitter of the layout breaks every symmetry, so correspondence
/// search has one answer.
fn markers_apart(markers: &[Marker], radius: f64) -> bool {
    let centers: Vec<Point3<f64>> = markers.iter().map(|m| m.face_center()).collect();
    (0..centers.len()).all(|i| {
        (i + 1..centers.len()).all(|j| (centers[i] - centers[j]).norm() >= 2.0 * radius + 6.0)
    })
}

/// A marker seen from a ray's origin: the origin less the marker's skin
/// point, and that offset's squared length less the marker's bounding
/// radius squared (positive: the origin is outside its bounding sphere).
#[derive(Debug, Clone, Copy)]
struct MarkerOffset {
    w: Vector3<f64>,
    c_sphere: f64,
}

impl MarkerOffset {
    /// Whether the ray from the origin along unit `dir` surely misses the
    /// marker's bounding sphere: the origin is outside it, and the sphere
    /// lies behind it or the line passes it by. (Tested here, inline, for
    /// each marker: most rays that reach the body's bound meet no marker.)
    #[inline]
    fn passed_by(&self, dir: &Vector3<f64>) -> bool {
        let b_half = self.w.dot(dir);
        self.c_sphere > 0.0 && (b_half > 0.0 || b_half * b_half < self.c_sphere)
    }

    fn new(m: &Marker, origin: &Point3<f64>) -> Self {
        let w = origin - Point3::from(m.skin_point_mm);
        MarkerOffset {
            w,
            c_sphere: w.norm_squared() - m.bounding_radius_squared(),
        }
    }
}

/// [`PhantomShape::intersect`] for many rays from one origin: what depends
/// on the origin alone (its place in the ellipsoid's unit sphere, each
/// marker's offset) is computed once, and each ray's answer has the same
/// bits.
pub struct RaysFrom<'a> {
    shape: &'a PhantomShape,
    origin: Point3<f64>,
    unit_origin: (Vector3<f64>, f64),
    markers: Vec<MarkerOffset>,
}

impl RaysFrom<'_> {
    /// The origin, phantom frame, mm.
    pub fn origin(&self) -> &Point3<f64> {
        &self.origin
    }

    /// [`PhantomShape::intersect`] from the origin along unit `dir`.
    pub fn intersect(&self, dir: &Vector3<f64>, t_min: f64) -> Option<Hit> {
        self.shape
            .intersect_from(&self.origin, &self.unit_origin, dir, t_min, |i| {
                self.markers[i]
            })
    }
}

/// The first of marker `m`'s side and outer face the ray from the origin
/// along unit `dir` meets beyond `t_min`, for a ray its bounding sphere's
/// test ([`MarkerOffset::passed_by`]) did not rule out.
fn intersect_marker(
    m: &Marker,
    &MarkerOffset { w, .. }: &MarkerOffset,
    dir: &Vector3<f64>,
    t_min: f64,
) -> Option<Hit> {
    let (_, n) = m.axis();
    let (wn, dn) = (w.dot(&n), dir.dot(&n));
    let w_perp = w - n * wn;
    let d_perp = dir - n * dn;
    let mut best: Option<Hit> = None;
    let a = d_perp.norm_squared();
    if a > 1e-15 {
        let b = 2.0 * w_perp.dot(&d_perp);
        let c = w_perp.norm_squared() - m.radius_mm * m.radius_mm;
        let disc = b * b - 4.0 * a * c;
        if disc >= 0.0 {
            let sq = disc.sqrt();
            for t in [(-b - sq) / (2.0 * a), (-b + sq) / (2.0 * a)] {
                let h = wn + t * dn;
                if t > t_min && h >= -m.below_skin_mm && h <= m.height_mm {
                    let normal = Unit::new_normalize(w_perp + d_perp * t).into_inner();
                    best = Some(Hit {
                        t,
                        normal,
                        surface: Surface::MarkerSide,
                    });
                    break;
                }
            }
        }
    }
    if dn.abs() > 1e-15 {
        let t = (m.height_mm - wn) / dn;
        let radial = w_perp + d_perp * t;
        if t > t_min
            && radial.norm_squared() <= m.radius_mm * m.radius_mm
            && best.is_none_or(|b| t < b.t)
        {
            best = Some(Hit {
                t,
                normal: n,
                surface: Surface::MarkerFace(m.id),
            });
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn phantom() -> PhantomShape {
        PhantomShape::build(
            &ShapeParams::default(),
            &mut rand_chacha::ChaCha8Rng::seed_from_u64(1),
        )
        .unwrap()
    }

    /// Points of the dome (the ellipsoid above z = 0) and of every marker's
    /// cylinder, spread over them.
    fn body_points(s: &PhantomShape, rng: &mut impl Rng) -> Vec<Point3<f64>> {
        let (axes, c) = (
            Vector3::from(s.semi_axes_mm),
            Point3::from(s.ellipsoid_center_mm),
        );
        let mut points = Vec::new();
        while points.len() < 20_000 {
            let u = Vector3::new(
                rng.random_range(-1.0..1.0f64),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            );
            if u.norm() > 1.0 || u.norm() < 1e-3 {
                continue;
            }
            let p = c + s.rotation() * u.normalize().component_mul(&axes);
            if p.z >= 0.0 {
                points.push(p);
            }
        }
        for m in &s.markers {
            let (base, n) = m.axis();
            let a = n.cross(&Vector3::x()).normalize();
            let b = n.cross(&a);
            for k in 0..64 {
                let angle = k as f64 / 64.0 * std::f64::consts::TAU;
                let rim = (a * angle.cos() + b * angle.sin()) * m.radius_mm;
                points.push(base + n * m.height_mm + rim);
                points.push(base - n * m.below_skin_mm + rim);
            }
        }
        points
    }

    #[test]
    fn the_body_bound_holds_the_dome_and_the_markers_with_its_margin() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
        for params in [
            ShapeParams::default(),
            ShapeParams {
                droop_deg: -20.0,
                height_mm: 100.0,
                width_mm: 60.0,
                ..ShapeParams::default()
            },
        ] {
            let s = PhantomShape::build(&params, &mut rng).unwrap();
            let bound = s.bound();
            let radius = bound.radius_squared.sqrt();
            let farthest = body_points(&s, &mut rng)
                .iter()
                .map(|p| (p - bound.centre).norm())
                .fold(0.0, f64::max);
            // Inside by far more than a hit's rounding (1e-13 mm).
            assert!(farthest < radius - 1e-4, "{farthest} {radius}");
            // Not loose: around the dome's box, whose corners it does not reach.
            assert!(farthest > 0.7 * radius, "{farthest} {radius}");
        }
    }

    #[test]
    fn rays_the_body_bound_skips_meet_nothing_the_tests_would_meet() {
        let s = phantom();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let targets = body_points(&s, &mut rng);
        let bound = *s.bound();
        let radius = bound.radius_squared.sqrt();
        let (mut skipped, mut met, n) = (0, 0, 40_000);
        for k in 0..n {
            // Cameras around and above, and points on the table (shadow rays).
            let origin = if k % 2 == 0 {
                Point3::new(
                    rng.random_range(-600.0..600.0),
                    rng.random_range(-600.0..600.0),
                    rng.random_range(50.0..600.0),
                )
            } else {
                Point3::new(
                    rng.random_range(-300.0..300.0),
                    rng.random_range(-300.0..300.0),
                    0.0,
                )
            };
            let dir = match k % 4 {
                // At the body: grazing rays included (its points).
                0 | 1 => (targets[rng.random_range(0..targets.len())] - origin).normalize(),
                // Past the bound's edge, just outside or inside it.
                2 => {
                    let to = bound.centre - origin;
                    let side = to.cross(&Vector3::z()).normalize();
                    let off = radius * (1.0 + rng.random_range(-1e-6..1e-6));
                    (to + side * off).normalize()
                }
                _ => Vector3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                )
                .normalize(),
            };
            let each = s.intersect_each(&origin, &s.unit_origin(&origin), &dir, 1e-6, |i| {
                MarkerOffset::new(&s.markers[i], &origin)
            });
            assert_eq!(s.intersect(&origin, &dir, 1e-6), each, "{origin} {dir}");
            assert_eq!(s.rays_from(&origin).intersect(&dir, 1e-6), each);
            skipped += usize::from(bound.passed_by(&origin, &dir));
            met += usize::from(each.is_some());
        }
        assert!(
            skipped > n / 8 && met > n / 4,
            "{skipped} skipped, {met} met of {n}"
        );
    }

    #[test]
    fn dome_has_the_requested_size() {
        let s = phantom();
        let p = ShapeParams::default();
        // Highest point: straight up from the middle (the tilt lowers it a little).
        let top = s
            .intersect(&Point3::new(0.0, 0.0, 500.0), &-Vector3::z(), 0.0)
            .unwrap();
        let height = 500.0 - top.t;
        assert!(
            (height - p.height_mm).abs() < 0.02 * p.height_mm,
            "{height}"
        );
        // Width at the base, along x (the tilt is about x, so this is exact).
        let side = s
            .intersect(&Point3::new(-500.0, 0.0, 0.001), &Vector3::x(), 0.0)
            .unwrap();
        assert!(
            (2.0 * (500.0 - side.t) - p.width_mm).abs() < 0.5,
            "{}",
            side.t
        );
        assert!(s.inside_dome(&Point3::new(0.0, 0.0, 10.0)));
        assert!(!s.inside_dome(&Point3::new(0.0, 0.0, -1.0)));
        assert!(!s.inside_dome(&Point3::new(0.0, 0.0, 80.0)));
    }

    #[test]
    fn markers_sit_on_the_skin_with_gel_inside() {
        let s = phantom();
        assert_eq!(s.markers.len(), 12);
        for m in &s.markers {
            let skin = Point3::from(m.skin_point_mm);
            assert!(s.to_unit_sphere(&skin).norm() - 1.0 < 1e-9);
            assert_eq!(s.material_at(&m.gel_center()), Material::Gel);
            let n = Vector3::from(m.normal);
            // Plastic between skin and gel keeps the gel apart from tissue.
            assert_eq!(s.material_at(&(skin + n * 0.5)), Material::Plastic);
            assert_eq!(s.material_at(&(skin - n * 2.0)), Material::Tissue);
            assert_eq!(
                s.material_at(&(m.face_center() + n * 0.1)),
                Material::Background
            );
            // A ray straight down the axis hits the coloured face at its centre.
            let origin = m.face_center() + n * 100.0;
            let hit = s.intersect(&origin, &-n, 0.0).unwrap();
            assert_eq!(hit.surface, Surface::MarkerFace(m.id));
            assert!((hit.t - 100.0).abs() < 1e-9);
        }
        for l in &s.lesions {
            assert_eq!(s.material_at(&Point3::from(l.center_mm)), Material::Lesion);
        }
    }

    #[test]
    fn rays_hit_the_skin_where_the_ellipsoid_is() {
        let s = phantom();
        let origin = Point3::new(30.0, -200.0, 150.0);
        let dir = (Point3::new(10.0, 0.0, 20.0) - origin).normalize();
        let hit = s.intersect(&origin, &dir, 0.0).unwrap();
        let p = origin + dir * hit.t;
        assert!((s.to_unit_sphere(&p).norm() - 1.0).abs() < 1e-9);
        assert!(hit.normal.dot(&dir) < 0.0, "normal faces the camera");
        assert!(s.intersect(&origin, &-dir, 0.0).is_none());
    }

    #[test]
    fn rays_from_one_origin_hit_what_single_rays_hit() {
        let s = phantom();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(21);
        let mut surfaces = std::collections::HashSet::new();
        for origin in [
            Point3::new(30.0, -200.0, 150.0),
            Point3::new(-160.0, 40.0, 90.0),
            Point3::new(0.0, 0.0, 30.0),
        ] {
            let rays = s.rays_from(&origin);
            // Rays at the markers' faces, near them and at random.
            let aims = s.markers.iter().flat_map(|m| {
                let face = m.face_center();
                [face, face + Vector3::new(3.0, -2.0, 1.0)]
            });
            let random: Vec<Point3<f64>> = (0..400)
                .map(|_| Point3::from(Vector3::from_fn(|_, _| rng.random_range(-80.0..80.0))))
                .collect();
            for aim in aims.chain(random) {
                let dir = (aim - origin).normalize();
                let (one, shared) = (s.intersect(&origin, &dir, 1e-6), rays.intersect(&dir, 1e-6));
                assert_eq!(one, shared, "from {origin} towards {aim}");
                if let Some(hit) = one {
                    surfaces.insert(
                        format!("{:?}", hit.surface)
                            .chars()
                            .take(10)
                            .collect::<String>(),
                    );
                }
            }
        }
        // Skin, marker faces and marker sides were all met.
        assert_eq!(surfaces.len(), 3, "{surfaces:?}");
    }

    #[test]
    fn distance_to_the_ellipsoid_is_exact() {
        let s = phantom();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        for _ in 0..200 {
            // A surface point, moved along its normal by a known distance.
            let dir = Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(0.1..1.0),
            )
            .normalize();
            let skin = s.exit_point(&Point3::new(0.0, 0.0, 5.0), &dir);
            let n = s.skin_normal(&skin);
            for d in [-3.0, -0.2, 0.0, 0.7, 4.0] {
                let got = s.distance_to_ellipsoid(&(skin + n * d));
                assert!((got - f64::abs(d)).abs() < 1e-6, "{d}: {got}");
            }
        }
    }

    #[test]
    fn bad_geometry_is_an_error() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let p = ShapeParams {
            lesions_mm: vec![[0.0, 0.0, 200.0]].into(),
            ..ShapeParams::default()
        };
        assert!(
            PhantomShape::build(&p, &mut rng)
                .unwrap_err()
                .contains("lesion 0")
        );
        let p = ShapeParams {
            marker_count: 80,
            ..ShapeParams::default()
        };
        assert!(
            PhantomShape::build(&p, &mut rng)
                .unwrap_err()
                .contains("80 markers")
        );
    }
}
