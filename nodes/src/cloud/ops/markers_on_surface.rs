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
    /// What a marker must have around it
    #[param(flatten)]
    pub test: SurfaceTest,
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
        let test = self.test;
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
