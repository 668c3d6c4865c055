//! Inputs a careless user or an unlucky machine brings: special files, an
//! output path that is a file, a closed pipe, out-of-range sizes, a tampered
//! cache. Each gets a clear error (exit 1 or 2) or the right result, never a
//! panic (exit 101) or a hang.

use super::common::{fusegraph, stderr};
use std::io::Read;
use std::path::Path;
use std::process::{Command, Stdio};

fn demo_copy(dir: &Path) {
    let demo = Path::new(env!("CARGO_MANIFEST_DIR")).join("graphs/demo.toml");
    std::fs::copy(demo, dir.join("demo.toml")).unwrap();
}

#[cfg(unix)]
#[test]
fn a_device_is_refused_as_a_graph_file() {
    let t = tempfile::tempdir().unwrap();
    let o = fusegraph(&["validate", "/dev/zero"], t.path());
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("/dev/zero: not a regular file"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn an_output_path_that_is_a_file_is_named() {
    let t = tempfile::tempdir().unwrap();
    demo_copy(t.path());
    std::fs::write(t.path().join("taken"), "x").unwrap();
    let o = fusegraph(&["run", "demo.toml", "--out", "taken"], t.path());
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("--out taken: is a file, not a folder"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn sizes_out_of_range_are_refused_before_allocating() {
    let t = tempfile::tempdir().unwrap();
    for args in [
        &["bench", "icp", "--iterations", "0"][..],
        &["bench", "marching-cubes", "--size", "100000"][..],
        &["bench", "scheduler", "--nodes", "0"][..],
        &["bench", "deformable", "--points", "0"][..],
    ] {
        let o = fusegraph(args, t.path());
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", stderr(&o));
        assert!(
            stderr(&o).contains("is not within 1 to"),
            "{args:?}: {}",
            stderr(&o)
        );
    }
}

#[test]
fn bench_deformable_refuses_a_sag_out_of_range_and_follows_a_small_one() {
    let t = tempfile::tempdir().unwrap();
    let o = fusegraph(&["bench", "deformable", "--sag-mm", "40"], t.path());
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("--sag-mm 40"), "{}", stderr(&o));
    // 3000 points a skin: the field brings the inside within a quarter of
    // the sag (about 3-5 mm at those points), as the fit's own tests ask.
    let o = fusegraph(
        &["bench", "deformable", "--points", "3000", "--repeat", "1"],
        t.path(),
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let printed = String::from_utf8_lossy(&o.stdout).into_owned();
    let worst: f64 = printed
        .split("worst ")
        .nth(1)
        .and_then(|rest| rest.split(' ').next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no worst error in {printed}"));
    assert!(worst < 1.0, "{printed}");
}

#[cfg(unix)]
#[test]
fn a_closed_output_pipe_ends_the_process_quietly() {
    let mut child = Command::new(env!("CARGO_BIN_EXE_fusegraph"))
        .args(["nodes", "--json"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut first = [0u8; 10];
    child.stdout.take().unwrap().read_exact(&mut first).unwrap();
    // The pipe closes here, as `| head -c 10` closes it.
    let out = child.wait_with_output().unwrap();
    assert_ne!(out.status.code(), Some(101), "{}", stderr(&out));
    assert!(!stderr(&out).contains("panicked"), "{}", stderr(&out));
}

#[test]
fn a_cache_entry_copied_over_another_nodes_is_recomputed() {
    let t = tempfile::tempdir().unwrap();
    demo_copy(t.path());
    let o = fusegraph(&["run", "demo.toml"], t.path());
    assert!(o.status.success(), "{}", stderr(&o));
    let report = |dir: &Path| -> serde_json::Value {
        let text = std::fs::read_to_string(dir.join("out/demo/report.json")).unwrap();
        serde_json::from_str(&text).unwrap()
    };
    let first = report(t.path());
    let key = |node: &str| first["nodes"][node]["key"].as_str().unwrap().to_string();
    let entry = |k: &str| {
        t.path().join(format!(
            ".fusegraph/cache/v{}/{}/{k}.entry",
            fusegraph_engine::cache::FORMAT_VERSION,
            &k[..2]
        ))
    };
    // Two nodes with the same output type: the focal length's entry over the
    // verging angle's.
    std::fs::copy(entry(&key("focal_mm")), entry(&key("verging_deg"))).unwrap();
    let o = fusegraph(&["run", "demo.toml"], t.path());
    assert!(o.status.success(), "{}", stderr(&o));
    let again = report(t.path());
    assert_eq!(again["nodes"]["verging_deg"]["status"], "ran");
    assert_eq!(again["metrics"], first["metrics"]);
}

/// A PNG file of a few dozen bytes whose header declares `w x h` pixels
/// (the first rows only, compressed).
fn png_bomb(w: u32, h: u32) -> Vec<u8> {
    let mut ihdr = b"IHDR".to_vec();
    ihdr.extend(w.to_be_bytes());
    ihdr.extend(h.to_be_bytes());
    ihdr.extend([8, 0, 0, 0, 0]);
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut chunk = |body: &[u8]| {
        png.extend(((body.len() - 4) as u32).to_be_bytes());
        png.extend(body);
        png.extend(crc32(body).to_be_bytes());
    };
    chunk(&ihdr);
    // A stored (uncompressed) zlib block of 64 zero bytes.
    let mut idat = b"IDAT\x78\x01\x01\x40\x00\xbf\xff".to_vec();
    idat.extend([0u8; 64]);
    idat.extend(adler32(&[0u8; 64]).to_be_bytes());
    chunk(&idat);
    chunk(b"IEND");
    png
}

fn crc32(bytes: &[u8]) -> u32 {
    let mut c = !0u32;
    for &b in bytes {
        c ^= b as u32;
        for _ in 0..8 {
            c = if c & 1 != 0 {
                0xEDB8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
        }
    }
    !c
}

fn adler32(bytes: &[u8]) -> u32 {
    let (mut a, mut b) = (1u32, 0u32);
    for &x in bytes {
        a = (a + x as u32) % 65521;
        b = (b + a) % 65521;
    }
    (b << 16) | a
}

#[cfg(target_os = "linux")]
#[test]
fn a_decompression_bomb_fails_clearly_under_a_memory_limit() {
    let t = tempfile::tempdir().unwrap();
    std::fs::write(t.path().join("bomb.png"), png_bomb(20_000, 20_000)).unwrap();
    std::fs::write(
        t.path().join("g.toml"),
        "[node.img]\nop = \"io.read_image\"\npath = \"bomb.png\"\n",
    )
    .unwrap();
    let o = super::common::limited(
        &["run", "g.toml", "--no-cache"],
        t.path(),
        1 << 30,
        std::time::Duration::from_secs(120),
    );
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(e.contains("bomb.png: declares 20000 x 20000 px"), "{e}");
    assert!(
        t.path().join("out/g/report.json").is_file(),
        "a report is written"
    );
}

/// `bench stereo-calibration --pairs` on a corner set made here from the
/// paper's rig: exact corners give the rig back, the set it writes is the
/// one it read, and a broken set is refused naming the file and line.
#[test]
fn the_calibration_bench_reads_a_corner_set() {
    use fusegraph_nodes::phantom::Rig;
    use nalgebra::{Isometry3, Point3, Vector3};
    let rig = Rig::paper_rig();
    let mut csv = String::from(
        "view,corner,board_x_mm,board_y_mm,left_x_px,left_y_px,right_x_px,right_y_px,width_px,height_px\n",
    );
    let poses = [
        ([0.3, -0.2, 0.1], [-100.0, -60.0, 520.0]),
        ([-0.25, 0.35, -0.2], [-90.0, -80.0, 600.0]),
        ([0.1, 0.4, 0.3], [-120.0, -50.0, 480.0]),
        ([-0.4, -0.1, 0.0], [-80.0, -70.0, 650.0]),
    ];
    for (view, (r, t)) in poses.iter().enumerate() {
        let pose = Isometry3::new(Vector3::from(*t), Vector3::from(*r));
        for k in 0..54 {
            let board = Point3::new((k % 9) as f64 * 25.0, (k / 9) as f64 * 25.0, 0.0);
            let l = rig.left.project(&(pose * board)).unwrap();
            let r = rig
                .right
                .project(&(rig.left_to_right * pose * board))
                .unwrap();
            csv.push_str(&format!(
                "{view},{k},{},{},{:.9},{:.9},{:.9},{:.9},800,600\n",
                board.x, board.y, l.x, l.y, r.x, r.y
            ));
        }
    }
    let t = tempfile::tempdir().unwrap();
    std::fs::write(t.path().join("pairs.csv"), &csv).unwrap();
    let o = fusegraph(
        &[
            "bench",
            "stereo-calibration",
            "--pairs",
            "pairs.csv",
            "--repeat",
            "1",
            "--out",
            "again",
        ],
        t.path(),
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let printed = String::from_utf8_lossy(&o.stdout).into_owned();
    let baseline = rig.left_to_right.translation.vector.norm();
    assert!(
        printed.contains("4 pairs") && printed.contains(&format!("baseline {baseline:.5} mm")),
        "{printed}"
    );
    assert_eq!(
        std::fs::read_to_string(t.path().join("again/pairs.csv")).unwrap(),
        csv
    );
    let broken = csv.replacen("800,600\n", "800\n", 1);
    std::fs::write(t.path().join("broken.csv"), broken).unwrap();
    let o = fusegraph(
        &["bench", "stereo-calibration", "--pairs", "broken.csv"],
        t.path(),
    );
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("broken.csv line 2: 10 finite numbers expected"),
        "{}",
        stderr(&o)
    );
}

/// `bench camera-calibration` on the two real photos kept in tests/data:
/// both boards are found, and two views are refused as too few.
#[test]
fn the_camera_calibration_bench_refuses_too_few_views() {
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/chessboard");
    let t = tempfile::tempdir().unwrap();
    let o = fusegraph(
        &[
            "bench",
            "camera-calibration",
            data.to_str().unwrap(),
            "--repeat",
            "1",
        ],
        t.path(),
    );
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("2 usable views; calibration needs at least 3"),
        "{}",
        stderr(&o)
    );
}
