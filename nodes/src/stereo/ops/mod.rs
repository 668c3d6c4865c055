//! The `stereo.*` ops: one file per op, each its declaration and thin adapter;
//! `matcher` holds what the two dense matchers share.

mod block_match;
mod disparity_range;
mod features;
mod fill_disparity;
mod hsv_markers;
mod match_features;
mod matcher;
mod refine_slanted;
mod sgm;
mod triangulate;

pub use block_match::BlockMatch;
pub use disparity_range::{DisparityRange, DisparityRangeInputs, DisparityRangeOutputs};
pub use features::{Detector, Features, FeaturesInputs, FeaturesOutputs};
pub use fill_disparity::{FillDisparity, FillDisparityInputs, FillDisparityOutputs};
pub use hsv_markers::{BLOB_COLUMNS, HsvMarkers, HsvMarkersInputs, HsvMarkersOutputs};
pub use match_features::{MatchFeatures, MatchFeaturesInputs, MatchFeaturesOutputs};
pub use matcher::{DisparityOutputs, MatcherInputs, MatcherParams, Refine};
pub use refine_slanted::{RefineSlanted, RefineSlantedInputs, RefineSlantedOutputs, Warp};
pub use sgm::{Sgm, SgmCost};
pub use triangulate::{Triangulate, TriangulateInputs, TriangulateOutputs};

use fusegraph_engine::OpError;
use fusegraph_engine::value::ValueError;

/// A value whose shape does not fit its type, as the op's error.
pub(crate) fn shape_error(e: ValueError) -> OpError {
    OpError::invalid(e.0)
}

/// Helpers of the ops' tests.
#[cfg(test)]
pub(crate) mod testing {
    use fusegraph_engine::typed::declaration::ParamSet;
    use fusegraph_engine::typed::declared_defaults;
    use fusegraph_engine::{Params, RunCtx};

    /// The parameters of `T` (an op or a group) all at their declared
    /// defaults.
    pub(crate) fn defaults<T: ParamSet>() -> T {
        declared_defaults().expect("every parameter has a default")
    }

    /// The declared defaults of `T` as the engine's parameter values.
    pub(crate) fn default_params<T: ParamSet>() -> Params {
        fusegraph_engine::typed::default_params::<T>()
    }

    /// A context for running an op outside a graph.
    pub(crate) fn ctx() -> RunCtx<'static> {
        RunCtx::new("test", std::path::Path::new("/nonexistent"))
    }
}

#[cfg(test)]
mod tests {
    use super::testing::{ctx, defaults};
    use super::*;
    use crate::stereo::features::test_images::blob_texture;
    use fusegraph_engine::Op;
    use fusegraph_engine::typed::Typed;
    use fusegraph_engine::typed::prelude::*;
    use fusegraph_engine::value::{Image, Pixels};

    #[test]
    fn specs_are_valid() {
        let specs = [
            Typed::<Sgm>::new().map(|o| o.spec().clone()),
            Typed::<BlockMatch>::new().map(|o| o.spec().clone()),
            Typed::<Triangulate>::new().map(|o| o.spec().clone()),
            Typed::<HsvMarkers>::new().map(|o| o.spec().clone()),
            Typed::<Features>::new().map(|o| o.spec().clone()),
            Typed::<MatchFeatures>::new().map(|o| o.spec().clone()),
            Typed::<DisparityRange>::new().map(|o| o.spec().clone()),
        ];
        for spec in specs {
            spec.unwrap().check().unwrap();
        }
    }

    fn image(grey: &[f32], w: usize, h: usize) -> Arc<Image> {
        Arc::new(Image::new(w, h, 1, Pixels::F32(grey.to_vec().into())).unwrap())
    }

    #[test]
    fn features_matches_and_range_chain() {
        let (w, h) = (160, 120);
        let left = image(&blob_texture(w, h, 0.0, 0.0, 5), w, h);
        let right = image(&blob_texture(w, h, -17.0, 0.0, 5), w, h);
        let detect = |op: &Features, image: Arc<Image>| {
            let mut ctx = ctx();
            let out = op.run(FeaturesInputs { image }, &mut ctx).unwrap();
            (Arc::new(out.features), ctx.metrics()["count"])
        };
        let hessian: Features = defaults();
        let (left_table, count) = detect(&hessian, left.clone());
        assert!(count > 50.0, "{count}");
        let (right_table, _) = detect(&hessian, right);
        let mut c = ctx();
        let matched = defaults::<MatchFeatures>()
            .run(
                MatchFeaturesInputs {
                    left: left_table.clone(),
                    right: right_table,
                },
                &mut c,
            )
            .unwrap();
        assert!(c.metrics()["matches"] > 30.0);
        let mut c = ctx();
        let range = defaults::<DisparityRange>()
            .run(
                DisparityRangeInputs {
                    matches: Arc::new(matched.matches),
                    rectification: None,
                },
                &mut c,
            )
            .unwrap();
        let (min, max) = (range.min_disparity, range.max_disparity);
        assert_eq!((c.metrics()["min_px"], c.metrics()["max_px"]), (min, max));
        // Every true disparity is 17 px: p2 = p98 = 17, margin 16.
        assert!(min <= 17.0 && max >= 17.0, "[{min}, {max}]");
        assert!(min >= 17.0 - 17.0 && max <= 17.0 + 17.0, "[{min}, {max}]");
        // A FAST table against a Hessian table is refused.
        let fast = Features {
            detector: Detector::Fast,
            ..defaults()
        };
        let (fast_table, _) = detect(&fast, left);
        let err = defaults::<MatchFeatures>()
            .run(
                MatchFeaturesInputs {
                    left: left_table,
                    right: fast_table,
                },
                &mut ctx(),
            )
            .err()
            .unwrap();
        assert!(err.to_string().contains("different detectors"), "{err}");
    }
}
