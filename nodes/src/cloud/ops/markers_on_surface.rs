//! `cloud.markers_on_surface`: a view's markers that sit on its skin cloud,
//! seen whole.

use super::MarkerColour;
use crate::cloud::convert::{cloud_points, marker_points, markers_value};
use crate::cloud::{SurfaceTest, markers_on_surface};
use crate::stereo::colour_mask;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Markers, PointCloud};

/// Keeps the markers that sit on the skin cloud around them with nothing in front of them: refuses green things off the skin (on the table) and markers partly hidden by a tool
#[derive(Debug, Clone, PartialEq, Op)]
#[op(name = "cloud.markers_on_surface", version = 1)]
pub struct MarkersOnSurface {
    /// The markers' colour, whose points are not skin
    #[param(flatten)]
    pub colour: MarkerColour,
    /// Radius of the skin patch around a marker (beyond the hole its face and walls leave in the cloud)
    #[param(default = SurfaceTest::default().support_radius_mm, unit = "mm", min = 1e-3)]
    pub support_radius_mm: f64,
    /// Sides, of 8 around a marker, that must hold skin
    #[param(default = SurfaceTest::default().min_sides, min = 0, max = 8)]
    pub min_sides: usize,
    /// Largest distance of a marker from the skin patch's plane (its face stands its height above the skin)
    #[param(default = SurfaceTest::default().max_off_surface_mm, unit = "mm", min = 0.0)]
    pub max_off_surface_mm: f64,
    /// Points this close to the patch's plane are skin
    #[param(default = SurfaceTest::default().plane_tolerance_mm, unit = "mm", min = 1e-3)]
    pub plane_tolerance_mm: f64,
    /// Radius about a marker's line of sight, at its range, in which something nearer the camera hides part of it
    #[param(default = SurfaceTest::default().occluder_radius_mm, unit = "mm", min = 0.0)]
    pub occluder_radius_mm: f64,
    /// How far in front of the skin a point must be to hide a marker
    #[param(default = SurfaceTest::default().min_front_mm, unit = "mm", min = 0.0)]
    pub min_front_mm: f64,
    /// Above this fraction of the points in its line of sight in front of it, a marker is hidden (below, they are stereo's stray mismatches)
    #[param(default = SurfaceTest::default().min_hidden_fraction, min = 0.0, max = 1.0)]
    pub min_hidden_fraction: f64,
}

#[derive(Inputs)]
pub struct MarkersOnSurfaceInputs {
    /// Markers found in one view, mm, in its camera frame
    pub markers: Arc<Markers>,
    /// The view's cloud in the same frame (camera at the origin), without the table; with colours, the points of the markers' colour are not skin (a green cup does not hold a marker up)
    pub cloud: Arc<PointCloud>,
}

#[derive(Outputs)]
pub struct MarkersOnSurfaceOutputs {
    /// The markers kept, ids unchanged
    pub markers: Markers,
}

impl MarkersOnSurface {
    fn test(&self) -> SurfaceTest {
        SurfaceTest {
            support_radius_mm: self.support_radius_mm,
            min_sides: self.min_sides,
            max_off_surface_mm: self.max_off_surface_mm,
            plane_tolerance_mm: self.plane_tolerance_mm,
            occluder_radius_mm: self.occluder_radius_mm,
            min_front_mm: self.min_front_mm,
            min_hidden_fraction: self.min_hidden_fraction,
        }
    }
}

impl RunOp for MarkersOnSurface {
    type Inputs = MarkersOnSurfaceInputs;
    type Outputs = MarkersOnSurfaceOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let (markers, cloud) = (inputs.markers, inputs.cloud);
        if markers.frame != cloud.frame {
            return Err(OpError::invalid(format!(
                "markers are in `{}` but the cloud in `{}`: both must be in the view's camera frame",
                markers.frame, cloud.frame
            )));
        }
        let test = self.test();
        let points = marker_points(&markers);
        let mut skin = cloud_points(&cloud);
        if let Some(rgb) = &cloud.colors {
            let colour = self.colour.blob_params();
            let mut coloured = colour_mask(rgb, &colour).into_iter();
            skin.retain(|_| !coloured.next().unwrap_or(false));
        }
        let verdicts = markers_on_surface(&points, &skin, &test);
        let (mut kept, mut ids) = (Vec::new(), Vec::new());
        let (mut off_skin, mut hidden) = (0, 0);
        for ((p, id), v) in points.iter().zip(markers.ids.iter()).zip(&verdicts) {
            if v.kept() {
                kept.push(*p);
                ids.push(*id);
                continue;
            }
            if matches!(v, crate::cloud::OnSurface::Occluded { .. }) {
                hidden += 1;
            } else {
                off_skin += 1;
            }
            ctx.note(format!(
                "marker {id} at ({:.1}, {:.1}, {:.1}) mm refused: {}",
                p.x,
                p.y,
                p.z,
                v.reason(&test)
            ));
        }
        ctx.metric("kept", kept.len() as f64);
        ctx.metric("off_skin", off_skin as f64);
        ctx.metric("hidden", hidden as f64);
        Ok(MarkersOnSurfaceOutputs {
            markers: markers_value(&kept, ids, &markers.frame)?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cloud::ops::test_cloud;

    fn run(markers: Markers, cloud: PointCloud) -> Result<(Markers, Vec<String>), OpError> {
        let mut ctx = RunCtx::new("on_skin", &std::env::temp_dir());
        let op: MarkersOnSurface = fusegraph_engine::typed::declared_defaults().unwrap();
        assert_eq!(op.test(), SurfaceTest::default());
        let inputs = MarkersOnSurfaceInputs {
            markers: Arc::new(markers),
            cloud: Arc::new(cloud),
        };
        op.run(inputs, &mut ctx)
            .map(|out| (out.markers, ctx.notes().to_vec()))
    }

    #[test]
    fn keeps_a_marker_on_the_skin_and_names_the_one_off_it() {
        // Flat skin at 500 mm with a hole of 10 mm about the first marker.
        let mut skin = Vec::new();
        for i in -40..=40 {
            for j in -40..=40 {
                let (x, y) = (i as f32, j as f32);
                if x.hypot(y) > 10.0 {
                    skin.push([x, y, 500.0]);
                }
            }
        }
        let markers = Markers::new(
            vec![0.0, 0.0, 495.0, 100.0, 0.0, 500.0],
            vec![4, 9],
            "camera_left",
        )
        .unwrap();
        let (kept, notes) = run(markers, test_cloud(&skin, "camera_left")).unwrap();
        assert_eq!(&kept.ids[..], [4]);
        assert_eq!(notes.len(), 1);
        assert!(
            notes[0].starts_with("marker 9 at (100.0, 0.0, 500.0) mm refused: skin on 0 of 8"),
            "{}",
            notes[0]
        );
    }

    #[test]
    fn markers_and_cloud_in_other_frames_are_an_error() {
        let markers = Markers::new(vec![0.0, 0.0, 500.0], vec![0], "camera_left").unwrap();
        let err = run(markers, test_cloud(&[[0.0, 0.0, 500.0]], "world")).unwrap_err();
        assert!(
            err.to_string()
                .contains("`camera_left` but the cloud in `world`"),
            "{err}"
        );
    }
}
