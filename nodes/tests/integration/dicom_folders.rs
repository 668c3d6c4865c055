//! Scanner folders as they come: a corrupt file among good slices, data sets
//! without the Part 10 header, exact copies, different slices at one
//! position, gaps, overlays and sheared stacks. Each folder is made in the
//! test from pydicom's 5-slice CT series in tests/data/dicom.

use dicom_core::value::PrimitiveValue;
use dicom_core::{DataElement, Tag, VR};
use dicom_dictionary_std::tags;
use dicom_transfer_syntax_registry::TransferSyntaxIndex;
use fusegraph_nodes::dicom::{LoadOptions, SeriesError, load_series, load_series_with};
use std::path::{Path, PathBuf};

fn data(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../tests/data/dicom")
        .join(name)
}

/// The CT5N series' five slices copied into `dir`, sorted by name.
fn copy_ct5n(dir: &Path) -> Vec<PathBuf> {
    std::fs::create_dir_all(dir).unwrap();
    let mut out = Vec::new();
    for entry in std::fs::read_dir(data("series_CT5N_98892001")).unwrap() {
        let f = entry.unwrap().path();
        let to = dir.join(f.file_name().unwrap());
        std::fs::copy(&f, &to).unwrap();
        out.push(to);
    }
    out.sort();
    out
}

/// Rewrites a DICOM file after `edit`.
fn patch(path: &Path, edit: impl FnOnce(&mut dicom_object::DefaultDicomObject)) {
    let mut obj = dicom_object::open_file(path).unwrap();
    edit(&mut obj);
    obj.write_to_file(path).unwrap();
}

fn position(obj: &dicom_object::DefaultDicomObject) -> [f64; 3] {
    let v = obj
        .element(tags::IMAGE_POSITION_PATIENT)
        .unwrap()
        .to_multi_float64()
        .unwrap();
    [v[0], v[1], v[2]]
}

fn put_position(obj: &mut dicom_object::DefaultDicomObject, p: [f64; 3]) {
    obj.put(DataElement::new(
        tags::IMAGE_POSITION_PATIENT,
        VR::DS,
        PrimitiveValue::Strs(p.iter().map(|x| format!("{x}")).collect()),
    ));
}

fn reference() -> fusegraph_nodes::dicom::LoadedSeries {
    load_series(&data("series_CT5N_98892001"), None).unwrap()
}

#[test]
fn a_corrupt_file_among_good_slices_is_skipped_with_a_note_or_refused_when_strict() {
    let t = tempfile::tempdir().unwrap();
    let dir = t.path().join("series");
    copy_ct5n(&dir);
    // A truncated file that still starts like DICOM.
    let bytes = std::fs::read(data("MR_small.dcm")).unwrap();
    std::fs::write(dir.join("broken.dcm"), &bytes[..bytes.len() / 2]).unwrap();
    let s = load_series(&dir, None).unwrap();
    let good = reference();
    assert_eq!((s.grid.clone(), s.voxels.clone()), (good.grid, good.voxels));
    assert!(
        s.warnings
            .iter()
            .any(|w| w.starts_with("broken.dcm: skipped: ")),
        "{:#?}",
        s.warnings
    );
    let strict = LoadOptions {
        series_uid: None,
        strict: true,
    };
    let err = load_series_with(&dir, &strict).unwrap_err().to_string();
    assert!(
        err.contains(&dir.join("broken.dcm").display().to_string()),
        "{err}"
    );
}

#[test]
fn a_skipped_slice_inside_the_stack_is_still_refused_as_a_gap() {
    let t = tempfile::tempdir().unwrap();
    let dir = t.path().join("series");
    let files = copy_ct5n(&dir);
    // Slices sorted by name are not sorted by position: corrupt the one in
    // the middle of the stack.
    let good = reference();
    let middle_z = good.grid.to_patient([0.0, 0.0, 2.0])[2];
    let middle = files
        .iter()
        .find(|f| {
            let z = position(&dicom_object::open_file(f).unwrap())[2];
            (z - middle_z).abs() < 1e-3
        })
        .unwrap();
    let bytes = std::fs::read(middle).unwrap();
    std::fs::write(middle, &bytes[..bytes.len() - 100]).unwrap();
    let err = load_series(&dir, None).unwrap_err();
    assert!(matches!(err, SeriesError::Spacing(_)), "{err}");
    let msg = err.to_string();
    assert!(msg.contains("a gap of 5.000 mm between"), "{msg}");
    assert!(msg.contains(&format!("(in {})", dir.display())), "{msg}");
}

#[test]
fn the_gap_error_names_the_folder_and_the_files_on_each_side() {
    let dir = data("series_CT2_77654033");
    let err = load_series(&dir, None).unwrap_err();
    assert!(matches!(err, SeriesError::Spacing(_)), "{err}");
    let msg = err.to_string();
    assert!(msg.contains(&format!("(in {})", dir.display())), "{msg}");
    let named = std::fs::read_dir(&dir)
        .unwrap()
        .filter(|e| {
            let name = e.as_ref().unwrap().path().display().to_string();
            msg.contains(&format!("between {name} ")) || msg.contains(&format!("and {name} ("))
        })
        .count();
    assert_eq!(named, 2, "{msg}");
}

/// The data set of a Part 10 file, re-encoded as implicit VR little endian
/// and written with no preamble and no file meta group.
fn write_bare(from: &Path, to: &Path) {
    let obj = dicom_object::open_file(from).unwrap();
    let ts = dicom_transfer_syntax_registry::TransferSyntaxRegistry
        .get("1.2.840.10008.1.2")
        .unwrap();
    let mut out = Vec::new();
    obj.write_dataset_with_ts(&mut out, ts).unwrap();
    assert_ne!(&out[..2], b"\0\0");
    std::fs::write(to, out).unwrap();
}

#[test]
fn data_sets_without_the_part_10_header_are_read_as_implicit_vr() {
    let t = tempfile::tempdir().unwrap();
    let dir = t.path().join("bare");
    std::fs::create_dir(&dir).unwrap();
    for entry in std::fs::read_dir(data("series_CT5N_98892001")).unwrap() {
        let f = entry.unwrap().path();
        write_bare(&f, &dir.join(f.file_name().unwrap()));
    }
    std::fs::write(dir.join("notes.txt"), "exported").unwrap();
    let s = load_series(&dir, None).unwrap();
    let good = reference();
    assert_eq!((s.grid, s.voxels), (good.grid, good.voxels));
    assert!(
        s.warnings
            .iter()
            .any(|w| w.starts_with("notes.txt: skipped: not a DICOM file")),
        "{:#?}",
        s.warnings
    );
    // One bare file alone, against the Part 10 original.
    let single = t.path().join("mr.raw");
    write_bare(&data("MR_small.dcm"), &single);
    let bare = load_series(&single, None).unwrap();
    let part10 = load_series(&data("MR_small.dcm"), None).unwrap();
    assert_eq!((bare.grid, bare.voxels), (part10.grid, part10.voxels));
}

#[test]
fn exact_copies_are_dropped_and_different_slices_at_one_place_are_duplicates() {
    let t = tempfile::tempdir().unwrap();
    let dir = t.path().join("series");
    let files = copy_ct5n(&dir);
    // The folder copied into itself.
    copy_ct5n(&dir.join("copy"));
    let s = load_series(&dir, None).unwrap();
    let good = reference();
    assert_eq!((s.grid, s.voxels), (good.grid, good.voxels));
    let dropped: Vec<_> = s
        .warnings
        .iter()
        .filter(|w| w.contains("dropped: an exact copy of"))
        .collect();
    assert_eq!(dropped.len(), 5, "{:#?}", s.warnings);
    let first = files[0].file_name().unwrap().to_string_lossy().to_string();
    assert!(
        dropped.contains(&&format!("copy/{first}: dropped: an exact copy of {first}")),
        "{dropped:#?}"
    );
    // A different image at a slice's position (another SOP instance).
    std::fs::remove_dir_all(dir.join("copy")).unwrap();
    let other = dir.join("other.dcm");
    std::fs::copy(&files[0], &other).unwrap();
    patch(&other, |obj| {
        obj.put(DataElement::new(
            tags::SOP_INSTANCE_UID,
            VR::UI,
            PrimitiveValue::from("2.25.1234"),
        ));
    });
    let err = load_series(&dir, None).unwrap_err();
    assert!(matches!(err, SeriesError::Duplicate(_)), "{err}");
    let msg = err.to_string();
    assert!(
        msg.starts_with("duplicate slices: ")
            && msg.contains("other.dcm")
            && !msg.contains("spaced"),
        "{msg}"
    );
}

#[test]
fn overlays_are_noted() {
    let t = tempfile::tempdir().unwrap();
    let dir = t.path().join("series");
    let files = copy_ct5n(&dir);
    for f in &files[..2] {
        patch(f, |obj| {
            obj.put(DataElement::new(
                Tag(0x6000, 0x0010),
                VR::US,
                PrimitiveValue::from(16u16),
            ));
            obj.put(DataElement::new(
                Tag(0x6000, 0x0011),
                VR::US,
                PrimitiveValue::from(16u16),
            ));
            obj.put(DataElement::new(
                Tag(0x6000, 0x3000),
                VR::OW,
                PrimitiveValue::from(vec![0u8; 32]),
            ));
        });
    }
    let s = load_series(&dir, None).unwrap();
    assert!(
        s.warnings
            .iter()
            .any(|w| w.starts_with("2 file(s) carry overlay planes")),
        "{:#?}",
        s.warnings
    );
}

#[test]
fn a_sheared_stack_loads_with_its_shear_in_degrees() {
    let t = tempfile::tempdir().unwrap();
    let dir = t.path().join("series");
    let files = copy_ct5n(&dir);
    let good = reference();
    let z0 = good.grid.to_patient([0.0; 3])[2];
    // Each slice 1 mm further along x per 2.5 mm slice: atan(1 / 2.5).
    for f in &files {
        patch(f, |obj| {
            let mut p = position(obj);
            p[0] += (p[2] - z0) / 2.5;
            put_position(obj, p);
        });
    }
    let s = load_series(&dir, None).unwrap();
    let shear = (1.0f64 / 2.5).atan().to_degrees();
    assert!(
        s.warnings
            .iter()
            .any(|w| w.contains(&format!("sheared by {shear:.3} deg"))),
        "{:#?}",
        s.warnings
    );
    // The voxels are where the files put them.
    let top = s.grid.to_patient([0.0, 0.0, 4.0]);
    let good_top = good.grid.to_patient([0.0, 0.0, 4.0]);
    assert!(
        (top[0] - good_top[0] - 4.0).abs() < 1e-4,
        "{top:?} {good_top:?}"
    );
    assert_eq!(s.voxels, good.voxels);
}
