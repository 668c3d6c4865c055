//! A corpus of bad inputs, run through the CLI under a 1 GiB address-space
//! limit and a time limit: corrupt DICOM slices (patched from the small
//! phantom's), special files where files are expected, absurd parameters,
//! clashing sinks and undecodable photos. Each must end with a clear error
//! (exit 1 or 2) naming the file, node or key, within bounded time and
//! memory; never a panic (exit 101), an abort or a hang.

use super::common::{fusegraph, limited, stderr};
use std::path::Path;

/// One bad input: what to run and what the user must be told.
struct Case {
    name: &'static str,
    args: Vec<String>,
    exit: i32,
    /// Every one of these must appear on stderr.
    says: Vec<String>,
}

/// The first occurrence of `tag` (group, element) with explicit VR `vr` in
/// an explicit-VR little-endian file: the offset of its value and its length.
fn find_element(bytes: &[u8], (group, element): (u16, u16), vr: &[u8; 2]) -> (usize, usize) {
    let mut pattern = group.to_le_bytes().to_vec();
    pattern.extend(element.to_le_bytes());
    pattern.extend(vr);
    let at = bytes
        .windows(pattern.len())
        .position(|w| w == pattern)
        .unwrap_or_else(|| panic!("({group:04X},{element:04X}) in the slice"));
    let long = matches!(vr, b"OB" | b"OW" | b"SQ" | b"UN" | b"UT");
    if long {
        let len = u32::from_le_bytes(bytes[at + 8..at + 12].try_into().unwrap());
        (at + 12, len as usize)
    } else {
        let len = u16::from_le_bytes(bytes[at + 6..at + 8].try_into().unwrap());
        (at + 8, len as usize)
    }
}

/// Overwrites the value of a short-VR element with `value`, padded with
/// spaces to its length (the length stays, so the file stays parseable).
fn patch_value(bytes: &mut [u8], tag: (u16, u16), vr: &[u8; 2], value: &[u8]) {
    let (at, len) = find_element(bytes, tag, vr);
    assert!(value.len() <= len, "{value:?} fits in {len} bytes");
    bytes[at..at + len].fill(b' ');
    bytes[at..at + value.len()].copy_from_slice(value);
}

/// A series folder `name` holding the phantom's slices, with slice 2
/// changed by `change`.
fn series_with(root: &Path, slices: &Path, name: &str, change: impl Fn(&mut Vec<u8>)) -> String {
    let dir = root.join(name);
    std::fs::create_dir_all(&dir).unwrap();
    let mut files: Vec<_> = std::fs::read_dir(slices)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    for (i, file) in files.iter().enumerate() {
        let mut bytes = std::fs::read(file).unwrap();
        if i == 2 {
            change(&mut bytes);
        }
        std::fs::write(dir.join(file.file_name().unwrap()), bytes).unwrap();
    }
    dir.to_str().unwrap().to_string()
}

fn load_case(name: &'static str, dir: &str, says: &[&str]) -> Case {
    Case {
        name,
        args: [
            "run",
            "load.toml",
            "--no-cache",
            "--set",
            &format!("load.path={dir}"),
        ]
        .map(String::from)
        .to_vec(),
        exit: 1,
        says: says.iter().map(|s| s.to_string()).collect(),
    }
}

fn write_graph(dir: &Path, name: &str, text: &str) {
    std::fs::write(dir.join(name), text).unwrap();
}

/// A graph `text` run without a cache, which must end with `exit` and say
/// each of `says`.
fn graph_case(root: &Path, name: &'static str, text: &str, exit: i32, says: &[&str]) -> Case {
    let file = format!(
        "case{}.toml",
        root.read_dir().map(|d| d.count()).unwrap_or(0)
    );
    write_graph(root, &file, text);
    Case {
        name,
        args: vec!["run".into(), file, "--no-cache".into()],
        exit,
        says: says.iter().map(|s| s.to_string()).collect(),
    }
}

#[cfg(target_os = "linux")]
#[test]
fn every_bad_input_of_the_corpus_gets_a_clear_error_in_bounded_memory_and_time() {
    let t = tempfile::tempdir().unwrap();
    let root = t.path();
    let o = fusegraph(&["phantom", "--size", "small", "--out", "ph"], root);
    assert!(o.status.success(), "{}", stderr(&o));
    let slices = root.join("ph/mri");
    let third = {
        let mut f: Vec<_> = std::fs::read_dir(&slices)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        f.sort();
        f[2].clone()
    };
    write_graph(
        root,
        "load.toml",
        "[node.load]\nop = \"dicom.load_series\"\npath = \"ph/mri\"\n",
    );

    let mut cases = vec![
        load_case(
            "PixelData length 0xFFFFFFF0",
            &series_with(root, &slices, "pixel_length", |b| {
                let (at, _) = find_element(b, (0x7FE0, 0x0010), b"OW");
                b[at - 4..at].copy_from_slice(&0xFFFF_FFF0u32.to_le_bytes());
            }),
            &[&third, "PixelData", "declares 4294967280 bytes"],
        ),
        load_case(
            "big-endian transfer syntax on little-endian data",
            &series_with(root, &slices, "syntax", |b| {
                let (at, len) = find_element(b, (0x0002, 0x0010), b"UI");
                assert_eq!(&b[at..at + len], b"1.2.840.10008.1.2.1\0");
                b[at..at + len].copy_from_slice(b"1.2.840.10008.1.2.2\0");
            }),
            &[&third],
        ),
        load_case(
            "BitsStored 0",
            &series_with(root, &slices, "bits_stored", |b| {
                let (at, _) = find_element(b, (0x0028, 0x0101), b"US");
                b[at..at + 2].copy_from_slice(&0u16.to_le_bytes());
            }),
            &[&third, "BitsStored"],
        ),
        load_case(
            "BitsAllocated 8 in one slice of 16-bit slices",
            &series_with(root, &slices, "bits_allocated", |b| {
                let (at, _) = find_element(b, (0x0028, 0x0100), b"US");
                b[at..at + 2].copy_from_slice(&8u16.to_le_bytes());
                let (at, _) = find_element(b, (0x0028, 0x0101), b"US");
                b[at..at + 2].copy_from_slice(&8u16.to_le_bytes());
            }),
            &[&third, "BitsAllocated"],
        ),
        load_case(
            "a slice cut in half",
            &series_with(root, &slices, "truncated", |b| b.truncate(b.len() / 2)),
            &[&third],
        ),
    ];
    // Numbers that do not parse or are absurd, in place of the real ones.
    for (name, folder, tag, value, says) in [
        (
            "RescaleSlope abc",
            "slope_abc",
            (0x0028, 0x1053),
            &b"abc"[..],
            "RescaleSlope",
        ),
        (
            "RescaleSlope nan",
            "slope_nan",
            (0x0028, 0x1053),
            b"nan",
            "RescaleSlope",
        ),
        (
            "PixelSpacing 1e308",
            "spacing",
            (0x0028, 0x0030),
            b"1e308\\1",
            "PixelSpacing",
        ),
    ] {
        let dir = series_with(root, &slices, folder, |b| patch_value(b, tag, b"DS", value));
        cases.push(load_case(name, &dir, &[&third, says]));
    }

    // A decoder that panics on a truncated RLE fragment (dicom-rs 0.10): the
    // panic is caught per file and printed as an error, not as a crash.
    let rle = root.join("rle");
    std::fs::create_dir(&rle).unwrap();
    let bytes = std::fs::read(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/dicom/MR_small_RLE.dcm"),
    )
    .unwrap();
    std::fs::write(rle.join("cut.dcm"), &bytes[..5000]).unwrap();
    cases.push(load_case(
        "an RLE file cut inside a segment",
        rle.to_str().unwrap(),
        &["cut.dcm", "pixel data could not be decoded (RLE Lossless)"],
    ));

    // A FIFO among the slices: never opened, named.
    let fifo_dir = series_with(root, &slices, "fifo", |_| {});
    let fifo = std::ffi::CString::new(format!("{fifo_dir}/IM9999.dcm")).unwrap();
    // SAFETY: a valid NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(fifo.as_ptr(), 0o600) }, 0);
    cases.push(Case {
        exit: 2,
        ..load_case(
            "a FIFO in the series folder",
            &fifo_dir,
            &["load", "IM9999.dcm", "not a regular file"],
        )
    });

    // Special files and absurd values where parameters are read.
    cases.push(graph_case(
        root,
        "/dev/zero as an image",
        "[node.img]\nop = \"io.read_image\"\npath = \"/dev/zero\"\n",
        2,
        &["/dev/zero", "not a regular file"],
    ));
    cases.push(graph_case(
        root,
        "a reversed working range",
        "[node.mc]\nop = \"design.baseline_monte_carlo\"\nlens_mm = 8.0\nrange_mm = [700.0, 400.0]\n",
        2,
        &["mc", "range_mm"],
    ));
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("graphs/multiview.toml"),
        root.join("multiview.toml"),
    )
    .unwrap();
    cases.push(Case {
        name: "a pose noise of 1e300 deg",
        args: [
            "run",
            "multiview.toml",
            "--no-cache",
            "--set",
            "phantom.size=small",
            "--set",
            "pose1.noise_deg=1e300",
        ]
        .map(String::from)
        .to_vec(),
        exit: 2,
        says: vec!["pose1".into(), "noise_deg".into()],
    });
    write_graph(
        root,
        "sinks.toml",
        "[node.a]\nop = \"math.constant\"\nvalue = 1.0\n\
         [node.t]\nop = \"io.write_json\"\nin.value = \"a.value\"\nfile = \"x.json\"\n\
         [node.u]\nop = \"io.write_json\"\nin.value = \"a.value\"\nfile = \"x.json\"\n",
    );
    cases.push(Case {
        name: "two sinks writing one file",
        args: ["validate", "sinks.toml"].map(String::from).to_vec(),
        exit: 2,
        says: vec!["x.json".into()],
    });
    cases.push(Case {
        name: "a --set with a newline",
        args: ["validate", "sinks.toml", "--set", "a.value=1\n[node.z]"]
            .map(String::from)
            .to_vec(),
        exit: 2,
        says: vec!["a.value".into(), "line break".into()],
    });

    // Photos none of which decode: the detector fails, naming each.
    let photos = root.join("photos");
    std::fs::create_dir(&photos).unwrap();
    for i in 1..=3 {
        std::fs::write(
            photos.join(format!("left_{i:02}.png")),
            b"\x89PNG\r\n\x1a\nnot",
        )
        .unwrap();
    }
    write_graph(
        root,
        "photos.toml",
        "[node.corners]\nop = \"calib.find_chessboard\"\ndir = \"photos\"\nglob = \"left_*.png\"\npattern = [9, 6]\n",
    );
    cases.push(Case {
        name: "three undecodable photos",
        args: ["run", "photos.toml", "--no-cache"]
            .map(String::from)
            .to_vec(),
        exit: 1,
        says: vec![
            "corners".into(),
            "found in none of the 3 photos".into(),
            "note: left_01.png".into(),
        ],
    });

    // Sources and settings an op refuses, found at validation rather than
    // when the node runs, all in one report.
    cases.push(graph_case(
        root,
        "a reader's file without its folder, a chessboard with two sources, SGM settings",
        "[node.img]\nop = \"io.read_image\"\nfile = \"left_00.png\"\n\
         [node.corners]\nop = \"calib.find_chessboard\"\ndir = \"ph\"\nin.image = \"img.image\"\n\
         [node.depth]\nop = \"design.depth_of_field\"\nnear_mm = 500.0\nfar_mm = 400.0\n\
         [node.match]\nop = \"stereo.sgm\"\nin.left = \"img.image\"\nin.right = \"img.image\"\n\
         paths = 6\np1 = 90\n",
        2,
        &[
            "node `img`, key `file`",
            "not connected",
            "node `corners`, key `in.image`: `dir` and `in.image` are both given",
            "node `depth`, key `far_mm`: need near 500 < far 400",
            "node `match`, key `paths`: paths = 6",
            "node `match`, key `p2`: SGM penalties P1 = 90 and P2 = 80",
        ],
    ));

    // Round 2 of the probe: a sink writing outside --out, a small file that
    // would expand to a million nodes, targets Slicer never placed, and a
    // truncated JPEG.
    cases.push(graph_case(
        root,
        "a sink file outside the output folder",
        "[node.a]\nop = \"math.constant\"\nvalue = 1.0\n[node.w]\nop = \"io.write_json\"\nin.value = \"a.value\"\nfile = \"../../x.json\"\n",
        2,
        &["`w`", "file", "inside the output folder"],
    ));
    let values: Vec<String> = (0..10_000).map(|i| i.to_string()).collect();
    let nodes: String = (0..100)
        .map(|i| format!("[each.v.node.n{i}]\nop = \"math.constant\"\nvalue = 1.0\n"))
        .collect();
    cases.push(graph_case(
        root,
        "an [each] group of a million nodes",
        &format!("[each.v]\nvalues = [{}]\n{nodes}", values.join(", ")),
        2,
        &["[each.v]", "1000000 nodes"],
    ));
    std::fs::write(
        root.join("unplaced.mrk.json"),
        r#"{"markups":[{"coordinateSystem":"LPS","controlPoints":[{"id":"1","label":"T-1","position":[0,0,0],"positionStatus":"undefined"}]}]}"#,
    )
    .unwrap();
    cases.push(graph_case(
        root,
        "targets Slicer never placed",
        "[node.t]\nop = \"io.read_markers\"\npath = \"unplaced.mrk.json\"\n",
        1,
        &["unplaced.mrk.json", "no placed control points"],
    ));
    let jpeg = std::fs::read(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/chessboard/calibration03.jpg"),
    )
    .unwrap();
    std::fs::write(root.join("cut.jpg"), &jpeg[..jpeg.len() / 2]).unwrap();
    cases.push(graph_case(
        root,
        "a truncated JPEG",
        "[node.i]\nop = \"io.read_image\"\npath = \"cut.jpg\"\n",
        1,
        &["cut.jpg", "does not decode cleanly"],
    ));

    let mut failures = Vec::new();
    for case in &cases {
        let args: Vec<&str> = case.args.iter().map(String::as_str).collect();
        let o = limited(&args, root, 1 << 30, std::time::Duration::from_secs(120));
        let e = stderr(&o);
        let missing: Vec<&String> = case
            .says
            .iter()
            .filter(|s| !e.contains(s.as_str()))
            .collect();
        if o.status.code() != Some(case.exit) || !missing.is_empty() || e.contains("panicked") {
            failures.push(format!(
                "{}: exit {:?} (want {}), missing {missing:?}:\n{e}",
                case.name,
                o.status.code(),
                case.exit
            ));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n---\n"));
}
