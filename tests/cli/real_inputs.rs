//! Inputs as users bring them: stereo photos paired by the number in their
//! names whatever else the folder holds, pairs of different sizes, too few
//! pairs, an absurd calibration, malformed list parameters; warnings in
//! report.json and the CLI summary, on a cached re-run too.

use super::common::{fusegraph, stderr};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// The small phantom's calibration photos, written once for this file's tests.
fn phantom_calib() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let t = tempfile::tempdir().unwrap().keep();
        let o = fusegraph(&["phantom", "--out", "ph", "--size", "small"], &t);
        assert!(o.status.success(), "{}", stderr(&o));
        t.join("ph/calib")
    })
}

/// A folder of photos taken from the phantom's calibration pairs:
/// `(source, name)` copies, so a test can drop, add and rename files.
fn photo_folder(files: &[(&str, &str)]) -> tempfile::TempDir {
    let t = tempfile::tempdir().unwrap();
    std::fs::create_dir(t.path().join("photos")).unwrap();
    for (from, to) in files {
        std::fs::copy(phantom_calib().join(from), t.path().join("photos").join(to)).unwrap();
    }
    std::fs::write(t.path().join("stereo.toml"), STEREO_GRAPH).unwrap();
    t
}

const STEREO_GRAPH: &str = r#"
[graph]
name = "pairs"

[node.left_corners]
op = "calib.find_chessboard"
dir = "photos"
glob = "left*"

[node.right_corners]
op = "calib.find_chessboard"
dir = "photos"
glob = "right*"

[node.stereo]
op = "calib.stereo_calibrate"
in.left = "left_corners.corners"
in.right = "right_corners.corners"
in.left_views = "left_corners.views"
in.right_views = "right_corners.views"
"#;

fn report(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("out/pairs/report.json")).unwrap();
    serde_json::from_str(&text).unwrap()
}

/// The error of the stereo node in the last run.
fn stereo_error(dir: &Path) -> String {
    report(dir)["nodes"]["stereo"]["error"]
        .as_str()
        .expect("the stereo node failed")
        .to_string()
}

fn notes(r: &serde_json::Value, node: &str) -> Vec<String> {
    r["nodes"][node]["notes"]
        .as_array()
        .map(|a| a.iter().map(|n| n.as_str().unwrap().to_string()).collect())
        .unwrap_or_default()
}

/// Views 0-7 as `left_NN.png` and `rightNN.png` (two naming styles).
fn eight_pairs() -> Vec<(String, String)> {
    (0..8)
        .flat_map(|v| {
            [
                (format!("left_{v:02}.png"), format!("left_{v:02}.png")),
                (format!("right_{v:02}.png"), format!("right{v:02}.png")),
            ]
        })
        .collect()
}

fn as_refs(v: &[(String, String)]) -> Vec<(&str, &str)> {
    v.iter().map(|(a, b)| (a.as_str(), b.as_str())).collect()
}

#[test]
fn photos_pair_by_the_number_in_their_names() {
    let mut files = eight_pairs();
    // One right photo missing, one extra left photo, a non-image the glob
    // also matches: none of them may shift the pairing.
    files.retain(|(_, to)| to != "right03.png");
    files.push(("left_12.png".into(), "left_12.png".into()));
    let t = photo_folder(&as_refs(&files));
    std::fs::write(t.path().join("photos/left_intrinsics.yml"), "%YAML:1.0\n").unwrap();
    let o = fusegraph(&["run", "stereo.toml"], t.path());
    assert!(o.status.success(), "{}", stderr(&o));
    let r = report(t.path());
    let m = &r["metrics"];
    assert_eq!(m["stereo.pairs"], 7.0);
    assert!(m["stereo.rms_px"].as_f64().unwrap() < 0.2, "{m}");
    assert!(
        (m["stereo.baseline_mm"].as_f64().unwrap() - 55.0).abs() < 0.5,
        "{m}"
    );
    // Every estimated parameter's standard deviation, and each pair's RMS.
    for key in [
        "left_fx_sd_px",
        "right_cy_sd_px",
        "left_k1_sd",
        "baseline_sd_mm",
        "rotation_y_sd_deg",
        "translation_z_sd_mm",
        "left_residual_sd_px",
    ] {
        let sd = m[format!("stereo.{key}")].as_f64();
        assert!(sd.is_some_and(|v| v > 0.0 && v < 1.0), "{key}: {m}");
    }
    assert!(m.get("stereo.left_k3_sd").is_none(), "k3 is held: {m}");
    assert!(m["stereo.pair_0_rms_px"].as_f64().unwrap() < 0.2, "{m}");
    let left = notes(&r, "left_corners");
    assert!(
        left.iter()
            .any(|n| n.starts_with("left_intrinsics.yml: skipped: not an image")),
        "{left:?}"
    );
    let stereo = notes(&r, "stereo");
    assert_eq!(
        stereo,
        [
            "view 3: left board found, right no photo: pair left out",
            "view 12: left board found, right no photo: pair left out",
        ]
    );
    assert_eq!(r["warnings"], 3);
    let summary = stderr(&o);
    assert!(
        summary.contains("3 warnings (left_corners 1, stereo 2)"),
        "{summary}"
    );
    // A cached re-run still shows them.
    let again = fusegraph(&["run", "stereo.toml"], t.path());
    assert!(again.status.success());
    let r = report(t.path());
    assert_eq!(r["nodes"]["stereo"]["status"], "cached");
    assert_eq!(notes(&r, "stereo"), stereo);
    assert!(stderr(&again).contains("3 warnings"), "{}", stderr(&again));
}

#[test]
fn repeated_photos_of_one_pose_are_left_out_and_too_few_poses_fail() {
    // Eight real pairs, then views 8-11 copied from views 0 and 1.
    let mut files = eight_pairs();
    for (v, from) in [(8, 0), (9, 1), (10, 0), (11, 1)] {
        files.push((format!("left_{from:02}.png"), format!("left_{v:02}.png")));
        files.push((format!("right_{from:02}.png"), format!("right{v:02}.png")));
    }
    let t = photo_folder(&as_refs(&files));
    let o = fusegraph(&["run", "stereo.toml"], t.path());
    assert!(o.status.success(), "{}", stderr(&o));
    let r = report(t.path());
    assert_eq!(r["metrics"]["stereo.pairs"], 8.0);
    let stereo = notes(&r, "stereo");
    for (v, from) in [(8, 0), (9, 1), (10, 0), (11, 1)] {
        assert!(
            stereo.iter().any(|n| n.starts_with(&format!(
                "view {v}: the same board pose as view {from} in both photos (corners within 0.00 px)"
            ))),
            "{stereo:?}"
        );
    }
    // Twelve photos of two poses: an error, not a fit that looks good.
    let files: Vec<(String, String)> = (0..12)
        .flat_map(|v| {
            let from = v % 2;
            [
                (format!("left_{from:02}.png"), format!("left_{v:02}.png")),
                (format!("right_{from:02}.png"), format!("right{v:02}.png")),
            ]
        })
        .collect();
    let t = photo_folder(&as_refs(&files));
    let o = fusegraph(&["run", "stereo.toml"], t.path());
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let err = stereo_error(t.path());
    assert!(
        err.starts_with("2 usable pairs of 12 views, 3 needed"),
        "{err}"
    );
    assert!(err.contains("a repeated photo"), "{err}");
}

#[test]
fn a_pair_of_different_sizes_is_an_error_naming_the_view() {
    let t = photo_folder(&as_refs(&eight_pairs()));
    let right = t.path().join("photos/right05.png");
    let small = image::open(&right)
        .unwrap()
        .resize_exact(400, 300, image::imageops::Triangle);
    small.save(&right).unwrap();
    let o = fusegraph(&["run", "stereo.toml"], t.path());
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let err = stereo_error(t.path());
    assert_eq!(
        err,
        "view 5: the left photo is 800 x 600 px but the right one 400 x 300 px"
    );
}

#[test]
fn too_few_pairs_says_which_side_lacks_which_view() {
    let mut files = eight_pairs();
    files.retain(|(_, to)| !to.starts_with("right") || to == "right00.png" || to == "right01.png");
    let t = photo_folder(&as_refs(&files));
    let o = fusegraph(&["run", "stereo.toml"], t.path());
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let err = report(t.path())["nodes"]["stereo"]["error"]
        .as_str()
        .unwrap()
        .to_string();
    assert!(
        err.starts_with("2 usable pairs of 8 views, 3 needed"),
        "{err}"
    );
    assert!(
        err.contains("view 7: left board found, right no photo"),
        "{err}"
    );
}

#[test]
fn an_absurd_calibration_fails_instead_of_passing_a_garbage_rig_on() {
    // The right photos numbered one view late: every pair is a mismatch.
    let files: Vec<(String, String)> = (0..8)
        .flat_map(|v| {
            [
                (format!("left_{v:02}.png"), format!("left_{v:02}.png")),
                (
                    format!("right_{:02}.png", v + 1),
                    format!("right{v:02}.png"),
                ),
            ]
        })
        .collect();
    let t = photo_folder(&as_refs(&files));
    let o = fusegraph(&["run", "stereo.toml"], t.path());
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let err = stereo_error(t.path());
    assert!(err.contains("is above max_rms_px = 2 px"), "{err}");
    assert!(err.contains("worst: view "), "{err}");
}

#[test]
fn a_pattern_of_three_numbers_fails_validation() {
    let t = photo_folder(&[]);
    let o = fusegraph(
        &[
            "validate",
            "stereo.toml",
            "--set",
            "left_corners.pattern=[9, 6, 10]",
        ],
        t.path(),
    );
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(
        e.contains("node `left_corners`")
            && e.contains("pattern")
            && e.contains("a list of 3 items, expected 2"),
        "{e}"
    );
    // Every problem one pass can find, in one report: a pattern no board
    // can have on one node, a mistyped key on another, an override naming
    // no node and a coefficient no camera model has.
    let o = fusegraph(
        &[
            "validate",
            "stereo.toml",
            "--set",
            "left_corners.pattern=[2, 2]",
            "--set",
            "right_corners.patern=[9, 6]",
            "--set",
            "no_such_node.x=1",
            "--set",
            "stereo.free=[\"k1\", \"k9\"]",
        ],
        t.path(),
    );
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    let e = stderr(&o);
    for says in [
        "pattern 2 x 2: use one odd and one even count",
        "node `no_such_node`, key `x`: --set: no node with this id",
        "node `stereo`, key `free`: unknown coefficient \"k9\"",
    ] {
        assert!(e.contains(says), "missing {says:?} in:\n{e}");
    }
    assert!(
        e.contains("node `right_corners`") && e.contains("patern"),
        "{e}"
    );
}

#[test]
fn a_photo_decodes_to_the_same_corners_in_every_binary() {
    // The CLI binary and this test binary (another build profile's code
    // paths) must see the same pixels: corners to the printed 6 decimals.
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/chessboard");
    let t = tempfile::tempdir().unwrap();
    let out = t.path().join("bench");
    let o = fusegraph(
        &[
            "bench",
            "chessboard",
            data.to_str().unwrap(),
            "--repeat",
            "1",
            "--out",
            out.to_str().unwrap(),
        ],
        t.path(),
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let cli = std::fs::read_to_string(out.join("corners.csv")).unwrap();
    let mut here = String::from("file,corner,x_px,y_px\n");
    for name in ["calibration03.jpg", "calibration13.jpg"] {
        let img = fusegraph_nodes::io::load_grey(&data.join(name)).unwrap();
        let corners =
            fusegraph_nodes::calib::find_chessboard(&img.levels, img.width, img.height, 9, 6)
                .unwrap();
        for (k, c) in corners.iter().enumerate() {
            here.push_str(&format!("{name},{k},{:.6},{:.6}\n", c.x, c.y));
        }
    }
    assert_eq!(cli, here);
}
