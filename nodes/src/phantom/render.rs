//! A ray-casting camera simulator: for every pixel, rays through the exact
//! camera model (distortion included) into a [`Scene`], adaptively supersampled
//! where the image has edges (anti-aliasing; a pixel whose eight neighbours'
//! centres all met one smooth surface differs from them by texture alone:
//! it takes fewer samples, tells them so, and the scene may search only
//! near their distances), then lens blur and defocus
//! ([`super::defocus`]) and the sensor ([`super::sensor`]: vignetting,
//! exposure, noise, mosaic), quantised to 8-bit RGB. Rows render in parallel
//! with per-row random streams, so output is identical for any thread count.

use super::defocus::{Lens, defocus, gaussian_blur};
use super::sensor::{SensorParams, expose};
use crate::camera::CameraModel;
use crate::numeric::floor_usize;
use crate::simd::{Isa, kernels};
use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;

/// What a ray meets first.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Seen {
    /// Linear RGB (0..1).
    pub rgb: [f32; 3],
    /// Distance along the ray, mm (infinite for nothing).
    pub distance_mm: f64,
    /// A key of the smooth surface met, when the scene can search a ray
    /// near a depth its neighbours saw on it ([`Scene::radiance_near`]).
    pub smooth_surface: Option<u32>,
}

/// Something rays can look at.
pub trait Scene: Sync {
    /// Linear RGB (0..1) seen along the ray from `origin` along unit `dir`
    /// (world frame, mm), and the distance to what is seen, mm (infinite
    /// for nothing).
    fn radiance_at(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> ([f32; 3], f64);

    /// Linear RGB (0..1) seen along the ray.
    fn radiance(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> [f32; 3] {
        self.radiance_at(origin, dir).0
    }

    /// [`Scene::radiance_at`] with the smooth surface met, if the scene
    /// tells surfaces apart (by default it does not).
    fn seen(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Seen {
        let (rgb, distance_mm) = self.radiance_at(origin, dir);
        Seen {
            rgb,
            distance_mm,
            smooth_surface: None,
        }
    }

    /// [`Scene::seen`] for the rays from one `origin` along each of
    /// `dirs` (a row of pixels): what each sees into `rgb`, and its
    /// distance and smooth surface into `hits`. A scene may override it
    /// to do once what depends on the origin alone; the answers must be
    /// [`Scene::seen`]'s.
    fn seen_all(
        &self,
        origin: &Point3<f64>,
        dirs: &[Vector3<f64>],
        rgb: &mut [[f32; 3]],
        hits: &mut [(f64, Option<u32>)],
    ) {
        for ((dir, rgb), hit) in dirs.iter().zip(rgb).zip(hits) {
            let look = self.seen(origin, dir);
            *rgb = look.rgb;
            *hit = (look.distance_mm, look.smooth_surface);
        }
    }

    /// The mean radiance over a pixel's footprint where the scene can
    /// integrate it exactly (a planar pattern): `corners` are the unit rays
    /// through the pixel's four corners, in order around it, and `centre`
    /// the ray through its centre (world frame). `None`, the default, has
    /// the pixel supersampled instead.
    fn pixel_mean(
        &self,
        _origin: &Point3<f64>,
        _corners: &[Vector3<f64>; 4],
        _centre: &Vector3<f64>,
    ) -> Option<[f32; 3]> {
        None
    }

    /// What the ray sees, told that the rays around it (within a pixel of
    /// it, on every side) all met smooth surface `surface` at distances
    /// within `span_mm`: a scene may search only near that span. The
    /// answer must be [`Scene::radiance`]'s but for what the pixel grid
    /// cannot resolve anyway (anything thinner than a pixel in front).
    fn radiance_near(
        &self,
        origin: &Point3<f64>,
        dir: &Vector3<f64>,
        _surface: u32,
        _span_mm: (f64, f64),
    ) -> [f32; 3] {
        self.radiance(origin, dir)
    }
}

/// How to turn radiance into an image.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderParams {
    /// Samples per axis in pixels that straddle an edge (1 = no anti-aliasing).
    pub supersample: usize,
    /// How pixels that differ from their neighbours by texture alone
    /// (every neighbour met one smooth surface, lit alike) are sampled: a
    /// texture's mean over a pixel needs fewer samples than an edge's
    /// coverage. (None at all, the main job's camera surface RMS went from
    /// 0.51 to 2.1 mm: aliased texture.)
    pub texture: TextureSamples,
    /// Gaussian blur of a sharp lens and sensor, px (0 = none).
    pub blur_sigma_px: f64,
    /// Defocus of a lens focused at a distance; `None` = a pinhole (all sharp).
    pub lens: Option<Lens>,
    /// The sensor.
    pub sensor: SensorParams,
}

/// How a pixel that differs from its neighbours by texture alone is
/// sampled ([`RenderParams::texture`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TextureSamples {
    /// The centre's ray alone: texture is not supersampled, edges still
    /// are (3 x 3 on the full phantom's views).
    Centre,
    /// An n x n grid over the pixel (n at most [`RenderParams::supersample`]):
    /// n² rays besides the centre's, a box filter.
    Grid(usize),
    /// The centre (weight 2/3) and the pixel's four corners (1/12 each), a
    /// corner shared by the four pixels around it: about one ray a pixel
    /// besides the centre's, where a 2 x 2 grid takes four. The weights
    /// make it the box filter's exact mean for any quadratic across the
    /// pixel. Along an axis it passes 2/3 + cos(π f) / 3 of a texture at f
    /// cycles/px: 0.67 at the grid's Nyquist rate (the box 0.64, the 2 x 2
    /// grid 0.71), 0.43 at 0.75 (the grid 0.38), 1/3 at 1 (the grid 0). On
    /// the full phantom (seeds 1-4) the main job's camera-surface RMS and
    /// TRE matched the 2 x 2 grid's within 5 %, its views rendered in 25 %
    /// less time. (The full phantom took it in `phantom.generate` v4-v5;
    /// v6 takes [`TextureSamples::Centre`].)
    Quincunx,
}

/// How the second pass samples a pixel (a byte a pixel: the surface and
/// span of a texture pixel are found again from its neighbours' hits).
#[derive(Clone, Copy, PartialEq, Eq)]
enum PixelSamples {
    /// Its centre's sample stands (it differs from no neighbour).
    Centre,
    /// The full grid: an edge may cross it.
    Edge,
    /// Texture alone on the smooth surface its neighbours all met.
    Texture,
}

kernels! {
    /// Raises each `largest[i]` to |a[i] - b[i]| where that is larger (a
    /// NaN difference is never larger).
    fn raise_to_differences(largest: &mut [f32], a: &[f32], b: &[f32]) {
        let n = largest.len();
        let (a, b) = (&a[..n], &b[..n]);
        for i in 0..n {
            largest[i] = largest[i].max((a[i] - b[i]).abs());
        }
    }
}

/// Normalised ray coordinates on a coarse pixel grid, bilinearly interpolated:
/// the distortion is smooth, so a 4 px grid reproduces the exact inverse to
/// about 1e-4 px while costing one Newton solve per 16 pixels.
struct RayMap {
    step: f64,
    cols: usize,
    xy: Vec<(f64, f64)>,
}

impl RayMap {
    fn new(camera: &CameraModel) -> Self {
        let step = 4.0;
        let cols = (camera.width as f64 / step).ceil() as usize + 3;
        let rows = (camera.height as f64 / step).ceil() as usize + 3;
        let xy = (0..rows)
            .into_par_iter()
            .flat_map_iter(|r| {
                (0..cols)
                    .map(move |c| camera.undistort(c as f64 * step - step, r as f64 * step - step))
            })
            .collect();
        RayMap { step, cols, xy }
    }

    fn direction(&self, u: f64, v: f64) -> Vector3<f64> {
        let (gx, gy) = (u / self.step + 1.0, v / self.step + 1.0);
        let (c, r) = (floor_usize(gx), floor_usize(gy));
        let (tx, ty) = (gx - c as f64, gy - r as f64);
        let at = |c: usize, r: usize| self.xy[c + r * self.cols];
        let lerp =
            |a: (f64, f64), b: (f64, f64), t: f64| (a.0 + (b.0 - a.0) * t, a.1 + (b.1 - a.1) * t);
        let top = lerp(at(c, r), at(c + 1, r), tx);
        let bottom = lerp(at(c, r + 1), at(c + 1, r + 1), tx);
        let (x, y) = lerp(top, bottom, ty);
        Vector3::new(x, y, 1.0).normalize()
    }
}

/// A camera ready to render: its model, its precomputed ray map and the
/// direction through every pixel centre, shared by every image it takes.
pub struct Renderer<'a> {
    camera: &'a CameraModel,
    rays: RayMap,
    /// `rays.direction(x, y)` at every pixel centre, row-major (camera frame):
    /// the same bits, computed once per camera instead of once per image.
    centres: Vec<Vector3<f64>>,
    /// `rays.direction(cx - 1/2, cy - 1/2)` at every pixel corner, (width +
    /// 1) x (height + 1), row-major (camera frame), likewise.
    corners: Vec<Vector3<f64>>,
}

impl<'a> Renderer<'a> {
    /// Prepares `camera` (one distortion inversion per 16 pixels, one
    /// interpolation per pixel).
    pub fn new(camera: &'a CameraModel) -> Self {
        let rays = RayMap::new(camera);
        let w = camera.width;
        let centres = (0..w * camera.height)
            .into_par_iter()
            .map(|i| rays.direction((i % w) as f64, (i / w) as f64))
            .collect();
        let corners = (0..(w + 1) * (camera.height + 1))
            .into_par_iter()
            .map(|i| rays.direction((i % (w + 1)) as f64 - 0.5, (i / (w + 1)) as f64 - 0.5))
            .collect();
        Renderer {
            camera,
            rays,
            centres,
            corners,
        }
    }

    /// Renders `scene` with the camera at `camera_to_world`; returns interleaved
    /// 8-bit RGB, row-major.
    pub fn render(
        &self,
        camera_to_world: &Isometry3<f64>,
        scene: &dyn Scene,
        p: &RenderParams,
    ) -> Vec<u8> {
        render_with(self, camera_to_world, scene, p)
    }
}

fn render_with(
    Renderer {
        camera,
        rays,
        centres,
        corners: corner_rays,
    }: &Renderer,
    camera_to_world: &Isometry3<f64>,
    scene: &dyn Scene,
    p: &RenderParams,
) -> Vec<u8> {
    let (w, h) = (camera.width, camera.height);
    let origin = Point3::from(camera_to_world.translation.vector);
    // A rotation matrix is cheaper to apply than the quaternion, per sample.
    let rotation = camera_to_world.rotation.to_rotation_matrix();

    // One sample per pixel centre (with the surface it met and how far),
    // then supersampling where neighbours differ.
    let n = p.supersample.max(1);
    let mut image = vec![[0.0f32; 3]; w * h];
    let mut seen = vec![(f64::INFINITY, None); w * h];
    image
        .par_chunks_mut(w)
        .zip(seen.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, (row, seen_row))| {
            let dirs: Vec<Vector3<f64>> = centres[y * w..(y + 1) * w]
                .iter()
                .map(|centre| rotation * centre)
                .collect();
            if n > 1 || p.lens.is_some() {
                scene.seen_all(&origin, &dirs, row, seen_row);
            } else {
                for (px, dir) in row.iter_mut().zip(&dirs) {
                    *px = scene.radiance(&origin, dir);
                }
            }
        });
    if n > 1 {
        let offsets_of =
            |n: usize| -> Vec<f64> { (0..n).map(|s| (s as f64 + 0.5) / n as f64 - 0.5).collect() };
        let offsets = offsets_of(n);
        let smooth_offsets = match p.texture {
            TextureSamples::Grid(m) => offsets_of(m.clamp(1, n)),
            TextureSamples::Quincunx | TextureSamples::Centre => Vec::new(),
        };
        // Read in place: the image changes only after the pixels are classified.
        let centre = &image;
        let neighbours = |x: usize, y: usize| {
            (y.saturating_sub(1)..(y + 2).min(h)).flat_map(move |yy| {
                (x.saturating_sub(1)..(x + 2).min(w)).map(move |xx| xx + yy * w)
            })
        };
        // The one smooth surface all the neighbours met, and the span of
        // their distances, if they all met one.
        let near = |x: usize, y: usize| {
            let surface = seen[x + y * w].1?;
            let mut span = (f64::INFINITY, f64::NEG_INFINITY);
            for i in neighbours(x, y) {
                let (t, s) = seen[i];
                if s != Some(surface) {
                    return None;
                }
                span = (span.0.min(t), span.1.max(t));
            }
            Some((surface, span))
        };
        // A pixel differing from a neighbour by more than 0.02 in a channel
        // is sampled again, a row at a time: each of the nine neighbours is
        // a shifted row, compared channel by channel as flat rows of
        // floats (a loop that vectorises), then the channels joined.
        let isa = Isa::detect();
        let mut samples = vec![PixelSamples::Centre; w * h];
        samples.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            let own = centre[y * w..(y + 1) * w].as_flattened();
            // The largest difference from a neighbour, channel by channel
            // (NaN is never larger, as it is never over the threshold).
            let mut largest = vec![0.0f32; 3 * w];
            for yy in y.saturating_sub(1)..(y + 2).min(h) {
                let other = centre[yy * w..(yy + 1) * w].as_flattened();
                // Pixel x against x - 1, x and x + 1 of that row (not
                // against itself).
                let shifts: &[(usize, usize)] = if yy == y {
                    &[(3, 0), (0, 3)]
                } else {
                    &[(3, 0), (0, 0), (0, 3)]
                };
                for &(mine, theirs) in shifts {
                    let n = 3 * w - mine.max(theirs);
                    isa.raise_to_differences(
                        &mut largest[mine..mine + n],
                        &own[mine..mine + n],
                        &other[theirs..theirs + n],
                    );
                }
            }
            let differs = |x: usize| largest[3 * x..3 * x + 3].iter().any(|&d| d > 0.02);
            for (x, sample) in row.iter_mut().enumerate().filter(|(x, _)| differs(*x)) {
                *sample = match near(x, y) {
                    None => PixelSamples::Edge,
                    Some(_) if p.texture == TextureSamples::Centre => PixelSamples::Centre,
                    Some(_) => PixelSamples::Texture,
                };
            }
        });
        let look = |u: f64, v: f64, near: Option<(u32, (f64, f64))>| {
            let dir = rotation * rays.direction(u, v);
            match near {
                Some((surface, span)) => scene.radiance_near(&origin, &dir, surface, span),
                None => scene.radiance(&origin, &dir),
            }
        };
        // Quincunx: corner (cx, cy) lies at pixel coordinates (cx - 1/2,
        // cy - 1/2), sampled once for the texture pixels around it, near
        // the surface the first of them (in row order) was told of.
        // (None where no pixel is a texture pixel: a scene that tells no
        // smooth surfaces apart, such as the calibration board's.)
        let any_texture = samples.par_iter().any(|s| *s == PixelSamples::Texture);
        let corners: Vec<[f32; 3]> = if p.texture == TextureSamples::Quincunx && any_texture {
            (0..(w + 1) * (h + 1))
                .into_par_iter()
                .map(|i| {
                    let (cx, cy) = (i % (w + 1), i / (w + 1));
                    let around = (cy.saturating_sub(1)..(cy + 1).min(h))
                        .flat_map(|y| (cx.saturating_sub(1)..(cx + 1).min(w)).map(move |x| (x, y)));
                    around
                        .filter(|&(x, y)| samples[x + y * w] == PixelSamples::Texture)
                        .find_map(|(x, y)| near(x, y))
                        .map_or([0.0; 3], |(surface, span)| {
                            let dir = rotation * corner_rays[i];
                            scene.radiance_near(&origin, &dir, surface, span)
                        })
                })
                .collect()
        } else {
            Vec::new()
        };
        image.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            for (x, px) in row.iter_mut().enumerate() {
                let (grid, near) = match samples[x + y * w] {
                    PixelSamples::Centre => continue,
                    PixelSamples::Edge => {
                        let corner =
                            |cx: usize, cy: usize| rotation * corner_rays[cx + cy * (w + 1)];
                        let corners = [
                            corner(x, y),
                            corner(x + 1, y),
                            corner(x + 1, y + 1),
                            corner(x, y + 1),
                        ];
                        let centre = rotation * centres[x + y * w];
                        if let Some(mean) = scene.pixel_mean(&origin, &corners, &centre) {
                            *px = mean;
                            continue;
                        }
                        (&offsets, None)
                    }
                    PixelSamples::Texture => {
                        if p.texture == TextureSamples::Quincunx {
                            let corner = |cx: usize, cy: usize| corners[cx + cy * (w + 1)];
                            let (a, b, c, d) = (
                                corner(x, y),
                                corner(x + 1, y),
                                corner(x, y + 1),
                                corner(x + 1, y + 1),
                            );
                            *px = std::array::from_fn(|ch| {
                                (2.0 / 3.0) * px[ch]
                                    + (1.0 / 12.0) * (a[ch] + b[ch] + c[ch] + d[ch])
                            });
                            continue;
                        }
                        // A texture pixel's neighbours all met one surface.
                        match near(x, y) {
                            Some(near) => (&smooth_offsets, Some(near)),
                            None => (&offsets, None),
                        }
                    }
                };
                let mut acc = [0.0f32; 3];
                for &dy in grid {
                    for &dx in grid {
                        let s = look(x as f64 + dx, y as f64 + dy, near);
                        (0..3).for_each(|ch| acc[ch] += s[ch]);
                    }
                }
                *px = acc.map(|a| a / (grid.len() * grid.len()) as f32);
            }
        });
    }
    if p.blur_sigma_px > 0.0 {
        image = gaussian_blur(&image, w, h, p.blur_sigma_px);
    }
    if let Some(lens) = &p.lens {
        // Depth along the optical axis of what each pixel centre met.
        let circles: Vec<f32> = (0..w * h)
            .into_par_iter()
            .map(|i| {
                let ray = centres[i];
                lens.blur_circle_px((seen[i].0 * ray.z) as f32 as f64) as f32
            })
            .collect();
        image = defocus(&image, w, h, &circles);
    }
    expose(&image, camera, &p.sensor)
}

/// The tests' render parameters: `supersample` rays a side at edges,
/// `texture` where texture alone differs, an ideal noiseless sensor without
/// vignetting, and no blur or lens.
#[cfg(test)]
pub(crate) fn sharp_params(supersample: usize, texture: TextureSamples) -> RenderParams {
    let mut sensor = SensorParams::ideal(0.0, 1);
    sensor.vignetting = 0.0;
    RenderParams {
        supersample,
        texture,
        blur_sigma_px: 0.0,
        lens: None,
        sensor,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Everything left of world x = 0 on the plane z = 100 is white.
    struct HalfPlane;

    impl Scene for HalfPlane {
        fn radiance_at(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> ([f32; 3], f64) {
            let t = (100.0 - origin.z) / dir.z;
            let rgb = if origin.x + t * dir.x < 0.0 {
                [1.0; 3]
            } else {
                [0.0; 3]
            };
            (rgb, t)
        }
    }

    fn camera() -> CameraModel {
        CameraModel {
            width: 64,
            height: 48,
            fx: 100.0,
            fy: 100.0,
            cx: 31.7,
            cy: 23.5,
            distortion: [0.0; 5],
        }
    }

    /// The plane z = 100: left of x = 0 one smooth surface (key 7) striped
    /// every 0.7 mm (finer than the test camera's 1 mm pixels there, so
    /// neighbouring pixel centres differ), right of it black; counts the rays cast near the
    /// surface and along whole rays.
    #[derive(Default)]
    struct StripedHalfPlane {
        near: std::sync::atomic::AtomicUsize,
        whole: std::sync::atomic::AtomicUsize,
    }

    impl Scene for StripedHalfPlane {
        fn radiance_at(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> ([f32; 3], f64) {
            self.whole
                .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            let t = (100.0 - origin.z) / dir.z;
            let x = origin.x + t * dir.x;
            let v = if x >= 0.0 {
                0.0
            } else if (x / 0.7).floor() as i64 % 2 == 0 {
                1.0
            } else {
                0.5
            };
            ([v; 3], t)
        }

        fn seen(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Seen {
            let (rgb, distance_mm) = self.radiance_at(origin, dir);
            let on_surface = origin.x + distance_mm * dir.x < 0.0;
            Seen {
                rgb,
                distance_mm,
                smooth_surface: on_surface.then_some(7),
            }
        }

        fn radiance_near(
            &self,
            origin: &Point3<f64>,
            dir: &Vector3<f64>,
            surface: u32,
            _span_mm: (f64, f64),
        ) -> [f32; 3] {
            assert_eq!(surface, 7);
            self.near.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            self.radiance_at(origin, dir).0
        }
    }

    #[test]
    fn texture_alone_takes_its_own_sample_count_and_edges_the_full_one() {
        let camera = camera();
        let count = |texture_grid: usize| {
            let scene = StripedHalfPlane::default();
            let p = sharp_params(4, TextureSamples::Grid(texture_grid));
            let rgb = Renderer::new(&camera).render(&Isometry3::identity(), &scene, &p);
            let load =
                |a: &std::sync::atomic::AtomicUsize| a.load(std::sync::atomic::Ordering::Relaxed);
            (load(&scene.near), load(&scene.whole), rgb)
        };
        let (near_full, whole_full, full) = count(4);
        let (near_two, whole_two, two) = count(2);
        let pixels = camera.width * camera.height;
        // Striped pixels inside the surface: 16 rays each at 4 x 4, 4 at 2 x 2.
        assert!(near_full > 0 && near_full.is_multiple_of(16), "{near_full}");
        assert_eq!(near_two * 4, near_full);
        // The edge's pixels (neighbours off the surface) keep 4 x 4 whole rays.
        assert_eq!(whole_full - near_full, whole_two - near_two);
        let edge_rays = whole_two - near_two - pixels;
        assert!(edge_rays > 0 && edge_rays.is_multiple_of(16), "{edge_rays}");
        // Fewer samples of the stripes, the same edge (x = 0 falls in column
        // 31.7: columns 31 and 32 see both sides).
        assert_ne!(full, two);
        let column = |img: &[u8], x: usize| img[(x + 24 * camera.width) * 3];
        for x in 31..34 {
            assert_eq!(column(&full, x), column(&two, x), "edge column {x}");
        }
    }

    /// The plane z = 100, one smooth surface, its brightness a cosine of
    /// period 4 mm along x (4 px at the test camera's 100 px focal
    /// length): texture alone everywhere. Counts the rays cast near it.
    #[derive(Default)]
    struct CosinePlane {
        near: std::sync::atomic::AtomicUsize,
    }

    impl Scene for CosinePlane {
        fn radiance_at(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> ([f32; 3], f64) {
            let t = (100.0 - origin.z) / dir.z;
            let x = origin.x + t * dir.x;
            let v = 0.5 + 0.4 * (std::f64::consts::TAU * x / 4.0).cos();
            ([v as f32; 3], t)
        }

        fn seen(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Seen {
            let (rgb, distance_mm) = self.radiance_at(origin, dir);
            Seen {
                rgb,
                distance_mm,
                smooth_surface: Some(7),
            }
        }

        fn radiance_near(
            &self,
            origin: &Point3<f64>,
            dir: &Vector3<f64>,
            _surface: u32,
            _span_mm: (f64, f64),
        ) -> [f32; 3] {
            self.near.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            self.radiance_at(origin, dir).0
        }
    }

    #[test]
    fn texture_samples_cost_and_box_means() {
        let camera = camera();
        let render = |texture| {
            let scene = CosinePlane::default();
            let p = sharp_params(4, texture);
            let rgb = Renderer::new(&camera).render(&Isometry3::identity(), &scene, &p);
            let rays = scene.near.load(std::sync::atomic::Ordering::Relaxed);
            (rgb.chunks(3).map(|c| c[0] as i32).collect::<Vec<_>>(), rays)
        };
        let (quincunx, quincunx_rays) = render(TextureSamples::Quincunx);
        let (grid, grid_rays) = render(TextureSamples::Grid(2));
        let (fine, _) = render(TextureSamples::Grid(16));
        let (centre, _) = render(TextureSamples::Grid(1));
        let (centre_alone, centre_alone_rays) = render(TextureSamples::Centre);
        // Every pixel differs from a neighbour: the grid casts 4 rays a
        // pixel, the quincunx one a pixel corner, the centre alone none
        // besides the first pass's (and gives the one-ray grid's pixels).
        let pixels = camera.width * camera.height;
        assert_eq!(grid_rays, 4 * pixels);
        assert_eq!(quincunx_rays, (camera.width + 1) * (camera.height + 1));
        assert_eq!((centre_alone_rays, &centre_alone), (0, &centre));
        // A 4 px cosine's box mean over a pixel is sinc(1/4) = 0.90 of it:
        // the centre alone misses that by up to 0.04 (10 grey levels),
        // the quincunx (2/3 + cos(π/4)/3 = 0.902) by under a level.
        let worst = |a: &[i32], b: &[i32]| a.iter().zip(b).map(|(a, b)| (a - b).abs()).max();
        assert!(
            worst(&centre, &fine) >= Some(6),
            "{:?}",
            worst(&centre, &fine)
        );
        assert!(
            worst(&quincunx, &fine) <= Some(1),
            "{:?}",
            worst(&quincunx, &fine)
        );
        assert!(worst(&grid, &fine) <= Some(1), "{:?}", worst(&grid, &fine));
    }

    #[test]
    fn anti_aliasing_gives_fractional_edge_coverage() {
        let p = sharp_params(8, TextureSamples::Grid(8));
        let img = Renderer::new(&camera()).render(&Isometry3::identity(), &HalfPlane, &p);
        // The edge projects to u = cx = 31.7: pixel 31 spans [30.5, 31.5] (white),
        // pixel 32 spans [31.5, 32.5], white over 0.2 of its width, which 8
        // samples per axis measure as 2 / 8.
        let at = |x: usize| img[(x + 10 * 64) * 3] as f64 / 255.0;
        assert_eq!(at(31), 1.0);
        assert!((at(32) - 0.25).abs() < 0.02, "{}", at(32));
        assert_eq!(at(33), 0.0);
    }

    /// Everything left of world x = 0 on the plane z = `depth` is white.
    struct FarHalfPlane {
        depth: f64,
    }

    impl Scene for FarHalfPlane {
        fn radiance_at(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> ([f32; 3], f64) {
            let t = (self.depth - origin.z) / dir.z;
            let white = origin.x + t * dir.x < 0.0;
            ([if white { 0.8 } else { 0.1 }; 3], t)
        }
    }

    #[test]
    fn the_defocus_edge_spread_matches_the_blur_circle_formula() {
        // The paper rig's lens (8 mm, 6 um pixels) at f/2 focused at 300 mm
        // looking at an edge 600 mm away: c = A f |D1 - D2| / ((D1 - f) D2)
        // = 4 * 8 * 300 / (292 * 600) mm = 9.13 px; a disc of diameter c
        // spreads a line with sigma c / 4, and 8 x 8 anti-aliasing adds a
        // pixel's box (variance 1/12).
        let pixel_mm = 0.006;
        let camera = CameraModel {
            width: 160,
            height: 40,
            fx: 8.0 / pixel_mm,
            fy: 8.0 / pixel_mm,
            cx: 79.3,
            cy: 19.5,
            distortion: [0.0; 5],
        };
        let lens = Lens {
            focal_mm: 8.0,
            f_number: 2.0,
            focus_mm: 300.0,
            pixel_mm,
        };
        let p = RenderParams {
            lens: Some(lens),
            ..sharp_params(8, TextureSamples::Grid(8))
        };
        let scene = FarHalfPlane { depth: 600.0 };
        // The line spread's standard deviation along the middle row, px.
        let edge_sigma = |p: &RenderParams| {
            let img = Renderer::new(&camera).render(&Isometry3::identity(), &scene, p);
            let row: Vec<f64> = (0..camera.width)
                .map(|x| img[(x + 20 * camera.width) * 3] as f64)
                .collect();
            crate::phantom::defocus::line_spread_sigma_px(&row)
        };
        let circle = 4.0 * 8.0 * 300.0 / (292.0 * 600.0) / pixel_mm;
        assert!((lens.blur_circle_px(600.0) - circle).abs() < 1e-9);
        let expected = ((circle / 4.0).powi(2) + 1.0 / 12.0).sqrt();
        let measured = edge_sigma(&p);
        assert!(
            (measured / expected - 1.0).abs() < 0.1,
            "edge spread sigma {measured:.3} px, the formula's {expected:.3} px"
        );
        // Focused on the edge: only anti-aliasing's pixel box is left.
        let sharp = RenderParams {
            lens: Some(Lens {
                focus_mm: 600.0,
                ..lens
            }),
            ..p
        };
        let in_focus = edge_sigma(&sharp);
        assert!(in_focus < 0.45, "in focus: sigma {in_focus:.3} px");
    }

    #[test]
    fn ray_map_matches_exact_undistortion() {
        let c = CameraModel {
            width: 800,
            height: 600,
            fx: 1333.0,
            fy: 1333.0,
            cx: 401.0,
            cy: 299.0,
            distortion: [-0.12, 0.15, 0.0006, -0.0004, 0.0],
        };
        let map = RayMap::new(&c);
        for (u, v) in [(0.0, 0.0), (799.4, 599.4), (123.3, 456.7), (-0.5, 300.0)] {
            let d = map.direction(u, v);
            let p = c.project(&Point3::from(d * 500.0)).unwrap();
            assert!(
                (p.x - u).abs() < 2e-3 && (p.y - v).abs() < 2e-3,
                "{u},{v}: {p}"
            );
        }
    }

    #[test]
    fn output_is_deterministic_across_thread_counts() {
        let mut sensor = SensorParams::ideal(0.01, 9);
        sensor.bayer = true;
        sensor.full_well_e = 5000.0;
        let p = RenderParams {
            supersample: 3,
            texture: TextureSamples::Grid(3),
            blur_sigma_px: 0.5,
            lens: Some(Lens {
                focal_mm: 1.0,
                f_number: 1.0,
                focus_mm: 50.0,
                pixel_mm: 0.01,
            }),
            sensor,
        };
        let c = camera();
        let a = crate::on_threads(1, || {
            Renderer::new(&c).render(&Isometry3::identity(), &HalfPlane, &p)
        });
        let b = Renderer::new(&c).render(&Isometry3::identity(), &HalfPlane, &p);
        assert_eq!(a, b);
    }
}
