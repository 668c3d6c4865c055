//! The DICOM loader on real files (pydicom's test files, in tests/data/dicom;
//! its README says what each should give).

use fusegraph_nodes::dicom::{SeriesError, load_series};
use std::path::PathBuf;

fn data(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../tests/data/dicom")
        .join(name)
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol
}

#[test]
fn mr_small_loads_with_its_geometry() {
    let s = load_series(&data("MR_small.dcm"), None).unwrap();
    assert_eq!(s.grid.dims, [64, 64, 1]);
    let sp = s.grid.spacing_mm();
    assert!(
        close(sp[0], 0.3125, 1e-9) && close(sp[1], 0.3125, 1e-9) && close(sp[2], 0.8, 1e-9),
        "{sp:?}"
    );
    let origin = s.grid.to_patient([0.0, 0.0, 0.0]);
    for (a, b) in origin.iter().zip([-83.9063, -91.2, 6.6406]) {
        assert!(close(*a, b, 1e-4), "{origin:?}");
    }
    assert!(s.voxels.iter().any(|&v| v > 100.0));
}

#[test]
fn every_decodable_transfer_syntax_gives_identical_voxels() {
    let reference = load_series(&data("MR_small.dcm"), None).unwrap();
    for name in [
        "MR_small_implicit.dcm",
        "MR_small_bigendian.dcm",
        "MR_small_RLE.dcm",
        "MR_small_jp2klossless.dcm",
    ] {
        let s = load_series(&data(name), None).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(s.grid, reference.grid, "{name}");
        assert_eq!(s.voxels, reference.voxels, "{name}");
    }
}

#[test]
fn jpeg_ls_is_identical_or_a_clear_error_naming_the_syntax() {
    let reference = load_series(&data("MR_small.dcm"), None).unwrap();
    match load_series(&data("MR_small_jpeg_ls_lossless.dcm"), None) {
        Ok(s) => assert_eq!(s.voxels, reference.voxels),
        Err(e) => {
            let msg = e.to_string();
            assert!(msg.contains("MR_small_jpeg_ls_lossless.dcm"), "{msg}");
            assert!(
                msg.contains("1.2.840.10008.1.2.4.80")
                    && msg.contains("JPEG-LS is not supported by this build"),
                "{msg}"
            );
        }
    }
}

#[test]
fn ct_small_has_the_rescale_applied() {
    use dicom_dictionary_std::tags;
    let s = load_series(&data("CT_small.dcm"), None).unwrap();
    assert_eq!(s.grid.dims, [128, 128, 1]);
    assert!(close(s.grid.spacing_mm()[0], 0.661468, 1e-6));
    assert!(close(s.grid.spacing_mm()[2], 5.0, 1e-9));
    // Compare with the raw stored values and the file's own rescale.
    let obj = dicom_object::open_file(data("CT_small.dcm")).unwrap();
    let slope = obj
        .element(tags::RESCALE_SLOPE)
        .unwrap()
        .to_float64()
        .unwrap();
    let intercept = obj
        .element(tags::RESCALE_INTERCEPT)
        .unwrap()
        .to_float64()
        .unwrap();
    assert!(
        intercept != 0.0 || slope != 1.0,
        "the file has a rescale to test"
    );
    let raw: Vec<i32> = {
        use dicom_pixeldata::{ConvertOptions, ModalityLutOption, PixelDecoder};
        let opts = ConvertOptions::new().with_modality_lut(ModalityLutOption::None);
        obj.decode_pixel_data()
            .unwrap()
            .to_vec_with_options(&opts)
            .unwrap()
    };
    for (i, (&v, &r)) in s.voxels.iter().zip(&raw).enumerate().step_by(97) {
        assert!(
            close(v as f64, r as f64 * slope + intercept, 1e-3),
            "voxel {i}: {v} vs raw {r}"
        );
    }
}

#[test]
fn ct5n_series_is_one_volume_sorted_by_position() {
    let s = load_series(&data("series_CT5N_98892001"), None).unwrap();
    assert_eq!(s.grid.dims, [16, 16, 5]);
    assert_eq!(s.files, 5);
    let sp = s.grid.spacing_mm();
    assert!(
        close(sp[0], 0.488281, 1e-6) && close(sp[1], 0.488281, 1e-6) && close(sp[2], 2.5, 1e-6),
        "{sp:?}"
    );
    // Axial, normal +z: the first slice is the lowest (z = -1.2375), the last 8.7625.
    assert!(close(s.grid.to_patient([0.0, 0.0, 0.0])[2], -1.2375, 1e-4));
    assert!(close(s.grid.to_patient([0.0, 0.0, 4.0])[2], 8.7625, 1e-4));
    let m = s.grid.voxel_to_patient;
    assert!(
        close(m[0][0], 0.488281, 1e-6)
            && close(m[1][1], 0.488281, 1e-6)
            && close(m[2][2], 2.5, 1e-6)
    );
}

#[test]
fn ct2_series_with_a_gap_is_refused() {
    let err = load_series(&data("series_CT2_77654033"), None).unwrap_err();
    assert!(matches!(err, SeriesError::Spacing(_)), "{err}");
    let msg = err.to_string();
    assert!(
        msg.contains("not evenly spaced") && msg.contains("-99.480") && msg.contains("202.500"),
        "{msg}"
    );
}

#[test]
fn mr700_localiser_names_the_differing_orientations() {
    let err = load_series(&data("series_MR700_98892003"), None).unwrap_err();
    assert!(matches!(err, SeriesError::MixedOrientation(_)), "{err}");
    let msg = err.to_string();
    assert!(
        msg.contains("7 different ImageOrientationPatient")
            || msg.contains("different ImageOrientationPatient"),
        "{msg}"
    );
    assert!(msg.contains("series_MR700_98892003/"), "names files: {msg}");
}

#[test]
fn bad_inputs_get_clear_errors() {
    let t = tempfile::tempdir().unwrap();
    // A truncated DICOM file is named.
    let bytes = std::fs::read(data("MR_small.dcm")).unwrap();
    let cut = t.path().join("cut.dcm");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let msg = load_series(&cut, None).unwrap_err().to_string();
    assert!(msg.contains("cut.dcm"), "{msg}");
    // An empty folder, and a folder of non-DICOM files.
    assert!(load_series(t.path().join("none").as_path(), None).is_err());
    let empty = t.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    std::fs::write(empty.join("notes.txt"), "not an image").unwrap();
    let err = load_series(&empty, None).unwrap_err();
    assert!(matches!(err, SeriesError::Empty { .. }), "{err}");
    assert!(
        err.to_string()
            .contains("notes.txt: skipped: not a DICOM file"),
        "{err}"
    );
    // Two series in one folder: listed, and one can be chosen.
    let two = t.path().join("two");
    std::fs::create_dir(&two).unwrap();
    for f in ["MR_small.dcm", "CT_small.dcm"] {
        std::fs::copy(data(f), two.join(f)).unwrap();
    }
    let err = load_series(&two, None).unwrap_err();
    assert!(
        matches!(err, SeriesError::SeveralSeries { count: 2, .. }),
        "{err}"
    );
    let uid = dicom_object::open_file(data("CT_small.dcm"))
        .unwrap()
        .element(dicom_dictionary_std::tags::SERIES_INSTANCE_UID)
        .unwrap()
        .to_str()
        .unwrap()
        .trim_end_matches('\0')
        .to_string();
    assert!(err.to_string().contains(&uid), "{err}");
    let ct = load_series(&two, Some(&uid)).unwrap();
    assert_eq!(ct.grid.dims, [128, 128, 1]);
    assert!(matches!(
        load_series(&two, Some("9.9.9")),
        Err(SeriesError::NoSuchSeries { .. })
    ));
}

/// An enhanced multi-frame MR file: geometry in the functional groups, frames
/// stored in reverse order along the normal.
/// Puts the modality and the Image Pixel module of a monochrome object:
/// `frames` frames of `rows x cols` unsigned `bits`-bit samples.
fn put_pixel_module(
    obj: &mut dicom_object::InMemDicomObject,
    modality: &str,
    (rows, cols): (u16, u16),
    frames: usize,
    bits: u16,
) {
    use dicom_core::value::PrimitiveValue;
    use dicom_core::{DataElement, VR};
    use dicom_dictionary_std::tags;
    obj.put(DataElement::new(
        tags::MODALITY,
        VR::CS,
        PrimitiveValue::from(modality),
    ));
    obj.put(DataElement::new(
        tags::NUMBER_OF_FRAMES,
        VR::IS,
        PrimitiveValue::from(frames.to_string()),
    ));
    for (tag, v) in [
        (tags::ROWS, rows),
        (tags::COLUMNS, cols),
        (tags::SAMPLES_PER_PIXEL, 1),
        (tags::BITS_ALLOCATED, bits),
        (tags::BITS_STORED, bits),
        (tags::HIGH_BIT, bits - 1),
        (tags::PIXEL_REPRESENTATION, 0),
    ] {
        obj.put(DataElement::new(tag, VR::US, PrimitiveValue::from(v)));
    }
    obj.put(DataElement::new(
        tags::PHOTOMETRIC_INTERPRETATION,
        VR::CS,
        PrimitiveValue::from("MONOCHROME2"),
    ));
}

fn write_multiframe(path: &std::path::Path) {
    use dicom_core::value::{C, DataSetSequence, PrimitiveValue};
    use dicom_core::{DataElement, VR};
    use dicom_dictionary_std::{tags, uids};
    use dicom_object::{FileMetaTableBuilder, InMemDicomObject};
    let ds = |v: &[f64]| PrimitiveValue::Strs(v.iter().map(|x| format!("{x}")).collect());
    let seq = |tag, items: Vec<InMemDicomObject>| {
        DataElement::new(tag, VR::SQ, DataSetSequence::from(items))
    };
    let item =
        |tag, vr, value| InMemDicomObject::from_element_iter([DataElement::new(tag, vr, value)]);
    let (rows, cols, frames) = (4u16, 3u16, 3usize);
    let mut obj = InMemDicomObject::new_empty();
    obj.put(DataElement::new(
        tags::SOP_CLASS_UID,
        VR::UI,
        PrimitiveValue::from(uids::ENHANCED_MR_IMAGE_STORAGE),
    ));
    obj.put(DataElement::new(
        tags::SOP_INSTANCE_UID,
        VR::UI,
        PrimitiveValue::from("2.25.1234"),
    ));
    obj.put(DataElement::new(
        tags::SERIES_INSTANCE_UID,
        VR::UI,
        PrimitiveValue::from("2.25.99"),
    ));
    put_pixel_module(&mut obj, "MR", (rows, cols), frames, 16);
    let shared = InMemDicomObject::from_element_iter([
        seq(
            tags::PLANE_ORIENTATION_SEQUENCE,
            vec![item(
                tags::IMAGE_ORIENTATION_PATIENT,
                VR::DS,
                ds(&[1.0, 0.0, 0.0, 0.0, 0.0, -1.0]),
            )],
        ),
        seq(
            tags::PIXEL_MEASURES_SEQUENCE,
            vec![InMemDicomObject::from_element_iter([
                DataElement::new(tags::PIXEL_SPACING, VR::DS, ds(&[0.5, 0.25])),
                DataElement::new(tags::SLICE_THICKNESS, VR::DS, ds(&[2.0])),
            ])],
        ),
    ]);
    obj.put(seq(tags::SHARED_FUNCTIONAL_GROUPS_SEQUENCE, vec![shared]));
    // Coronal frames (normal = row x col = x x -z = +y), stored at y = 4, 2, 0.
    let per_frame: Vec<InMemDicomObject> = (0..frames)
        .map(|f| {
            InMemDicomObject::from_element_iter([seq(
                tags::PLANE_POSITION_SEQUENCE,
                vec![item(
                    tags::IMAGE_POSITION_PATIENT,
                    VR::DS,
                    ds(&[-5.0, 4.0 - 2.0 * f as f64, 30.0]),
                )],
            )])
        })
        .collect();
    obj.put(seq(tags::PER_FRAME_FUNCTIONAL_GROUPS_SEQUENCE, per_frame));
    let pixels: Vec<u16> = (0..frames * (rows * cols) as usize)
        .map(|i| (i / (rows * cols) as usize * 100 + i % 12) as u16)
        .collect();
    obj.put(DataElement::new(
        tags::PIXEL_DATA,
        VR::OW,
        PrimitiveValue::U16(C::from_vec(pixels)),
    ));
    obj.with_meta(FileMetaTableBuilder::new().transfer_syntax(uids::EXPLICIT_VR_LITTLE_ENDIAN))
        .unwrap()
        .write_to_file(path)
        .unwrap();
}

#[test]
fn enhanced_multiframe_files_load_sorted_along_the_normal() {
    let t = tempfile::tempdir().unwrap();
    let path = t.path().join("multi.dcm");
    write_multiframe(&path);
    let s = load_series(&path, None).unwrap();
    assert_eq!(s.grid.dims, [3, 4, 3]);
    let sp = s.grid.spacing_mm();
    assert!(
        close(sp[0], 0.25, 1e-9) && close(sp[1], 0.5, 1e-9) && close(sp[2], 2.0, 1e-9),
        "{sp:?}"
    );
    // The normal is +y: the first slice is the frame at y = 0 (stored last).
    assert_eq!(s.grid.to_patient([0.0, 0.0, 0.0]), [-5.0, 0.0, 30.0]);
    assert_eq!(s.grid.to_patient([2.0, 3.0, 2.0]), [-4.5, 4.0, 28.5]);
    assert_eq!(s.voxels[0], 200.0, "frame 2 comes first");
    assert_eq!(s.voxels[2 * 12], 0.0, "frame 0 comes last");
}

/// Writes `obj` as a Part 10 file (explicit VR little endian) of SOP class
/// `class`.
fn write_object(path: &std::path::Path, class: &str, mut obj: dicom_object::InMemDicomObject) {
    use dicom_core::value::PrimitiveValue;
    use dicom_core::{DataElement, VR};
    use dicom_dictionary_std::{tags, uids};
    use dicom_object::FileMetaTableBuilder;
    let instance = format!("2.25.{}", path.to_string_lossy().len() * 7919 + 17);
    if class != uids::MEDIA_STORAGE_DIRECTORY_STORAGE {
        obj.put(DataElement::new(
            tags::SOP_CLASS_UID,
            VR::UI,
            PrimitiveValue::from(class),
        ));
        obj.put(DataElement::new(
            tags::SOP_INSTANCE_UID,
            VR::UI,
            PrimitiveValue::from(instance.as_str()),
        ));
    }
    obj.with_meta(
        FileMetaTableBuilder::new()
            .transfer_syntax(uids::EXPLICIT_VR_LITTLE_ENDIAN)
            .media_storage_sop_class_uid(class)
            .media_storage_sop_instance_uid(instance.as_str()),
    )
    .unwrap()
    .write_to_file(path)
    .unwrap();
}

/// What a CD export puts beside the images: DICOMDIR, a structured report, an
/// RT plan, a presentation state (in a subfolder) and a text file.
fn write_export_extras(dir: &std::path::Path) {
    use dicom_core::value::{DataSetSequence, PrimitiveValue};
    use dicom_core::{DataElement, VR};
    use dicom_dictionary_std::{tags, uids};
    use dicom_object::InMemDicomObject;
    let mut dicomdir = InMemDicomObject::new_empty();
    dicomdir.put(DataElement::new(
        tags::FILE_SET_ID,
        VR::CS,
        PrimitiveValue::from("EXPORT"),
    ));
    dicomdir.put(DataElement::new(
        tags::DIRECTORY_RECORD_SEQUENCE,
        VR::SQ,
        DataSetSequence::from(Vec::<InMemDicomObject>::new()),
    ));
    write_object(
        &dir.join("DICOMDIR"),
        uids::MEDIA_STORAGE_DIRECTORY_STORAGE,
        dicomdir,
    );
    let with_uid = || {
        InMemDicomObject::from_element_iter([DataElement::new(
            tags::SERIES_INSTANCE_UID,
            VR::UI,
            PrimitiveValue::from("2.25.4242"),
        )])
    };
    write_object(&dir.join("sr.dcm"), uids::BASIC_TEXT_SR_STORAGE, with_uid());
    write_object(&dir.join("rtplan.dcm"), uids::RT_PLAN_STORAGE, with_uid());
    std::fs::create_dir_all(dir.join("sub")).unwrap();
    write_object(
        &dir.join("sub/pr.dcm"),
        uids::GRAYSCALE_SOFTCOPY_PRESENTATION_STATE_STORAGE,
        with_uid(),
    );
    std::fs::write(dir.join("README.txt"), "exported by a PACS").unwrap();
}

#[test]
fn an_export_folder_skips_non_images_with_a_note_per_file() {
    let t = tempfile::tempdir().unwrap();
    let dir = t.path().join("export");
    std::fs::create_dir(&dir).unwrap();
    for entry in std::fs::read_dir(data("series_CT5N_98892001")).unwrap() {
        let f = entry.unwrap().path();
        std::fs::copy(&f, dir.join(f.file_name().unwrap())).unwrap();
    }
    write_export_extras(&dir);
    let s = load_series(&dir, None).unwrap();
    assert_eq!((s.grid.dims, s.files), ([16, 16, 5], 5));
    let expected = [
        "DICOMDIR: skipped: a media directory (DICOMDIR), not an image",
        "sr.dcm: skipped: Basic Text SR (no pixel data)",
        "rtplan.dcm: skipped: RT Plan (no pixel data)",
        "sub/pr.dcm: skipped: Grayscale Softcopy Presentation State (no pixel data)",
        "README.txt: skipped: not a DICOM file (no 128-byte preamble and \"DICM\", nor a bare data set)",
    ];
    for e in expected {
        assert!(
            s.warnings.iter().any(|w| w == e),
            "{e} in {:#?}",
            s.warnings
        );
    }

    // The op forwards each warning to the node's notes.
    let registry = fusegraph_nodes::builtin_registry();
    let op = registry.get("dicom.load_series").unwrap();
    let mut params = fusegraph_engine::Params::default();
    for p in &op.spec().params {
        params.0.insert(p.name.clone(), p.default.clone().unwrap());
    }
    params.0.insert(
        "path".into(),
        fusegraph_engine::ParamValue::Path(dir.clone()),
    );
    let mut ctx = fusegraph_engine::RunCtx::new("load", t.path());
    op.run(&Default::default(), &params, &mut ctx).unwrap();
    for e in expected {
        assert!(
            ctx.notes().iter().any(|n| n == e),
            "{e} in {:#?}",
            ctx.notes()
        );
    }
}

#[test]
fn a_folder_without_images_names_what_it_skipped() {
    let t = tempfile::tempdir().unwrap();
    write_export_extras(t.path());
    let err = load_series(t.path(), None).unwrap_err();
    assert!(matches!(err, SeriesError::Empty { .. }), "{err}");
    let msg = err.to_string();
    assert!(
        msg.contains(&format!("{}: no DICOM image found", t.path().display()))
            && msg.contains("DICOMDIR: skipped: a media directory")
            && msg.contains("sr.dcm: skipped: Basic Text SR")
            && msg.contains("README.txt: skipped"),
        "{msg}"
    );
}

#[test]
fn a_truncated_rle_file_is_an_error_naming_it_not_a_panic() {
    let bytes = std::fs::read(data("MR_small_RLE.dcm")).unwrap();
    let t = tempfile::tempdir().unwrap();
    // Cut inside the RLE header (1540), and inside each of its two segments
    // (5000, 7000): dicom-transfer-syntax-registry 0.10 indexes past the end
    // of the fragment there and panics; the loader catches that per file.
    for cut in [1540, 3000, 5000, 7000] {
        let dir = t.path().join(format!("cut{cut}"));
        std::fs::create_dir(&dir).unwrap();
        std::fs::write(dir.join("rle.dcm"), &bytes[..cut]).unwrap();
        let msg = load_series(&dir, None).unwrap_err().to_string();
        assert!(
            msg.contains(&format!(
                "{}: pixel data could not be decoded (RLE Lossless): ",
                dir.join("rle.dcm").display()
            )),
            "cut at {cut}: {msg}"
        );
    }
}

/// A small RT Dose grid: 32-bit unsigned samples, 3 frames placed by
/// GridFrameOffsetVector on an oblique plane, DoseGridScaling 1e-4 Gy.
fn write_rt_dose(path: &std::path::Path, offsets: &[f64], iop: [f64; 6]) {
    use dicom_core::value::{C, PrimitiveValue};
    use dicom_core::{DataElement, VR};
    use dicom_dictionary_std::{tags, uids};
    use dicom_object::InMemDicomObject;
    let ds = |v: &[f64]| PrimitiveValue::Strs(v.iter().map(|x| format!("{x}")).collect());
    let (rows, cols) = (2u16, 3u16);
    let mut obj = InMemDicomObject::new_empty();
    obj.put(DataElement::new(
        tags::SERIES_INSTANCE_UID,
        VR::UI,
        PrimitiveValue::from("2.25.5151"),
    ));
    put_pixel_module(&mut obj, "RTDOSE", (rows, cols), offsets.len(), 32);
    obj.put(DataElement::new(
        tags::IMAGE_POSITION_PATIENT,
        VR::DS,
        ds(&[-20.0, 10.0, 5.0]),
    ));
    obj.put(DataElement::new(
        tags::IMAGE_ORIENTATION_PATIENT,
        VR::DS,
        ds(&iop),
    ));
    obj.put(DataElement::new(
        tags::PIXEL_SPACING,
        VR::DS,
        ds(&[2.0, 3.0]),
    ));
    obj.put(DataElement::new(
        tags::GRID_FRAME_OFFSET_VECTOR,
        VR::DS,
        ds(offsets),
    ));
    obj.put(DataElement::new(
        tags::DOSE_GRID_SCALING,
        VR::DS,
        ds(&[1e-4]),
    ));
    // Values above 2^16 and 2^31, so 32 bits are really needed.
    let n = offsets.len() * (rows * cols) as usize;
    let values: Vec<u32> = (0..n as u32)
        .map(|i| 70_000 * (i + 1) + (i << 27))
        .collect();
    let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    obj.put(DataElement::new(
        tags::PIXEL_DATA,
        VR::OW,
        PrimitiveValue::U8(C::from_vec(bytes)),
    ));
    write_object(path, uids::RT_DOSE_STORAGE, obj);
}

#[test]
fn rt_dose_32_bit_grids_load_with_dose_scaling_and_frame_offsets() {
    let t = tempfile::tempdir().unwrap();
    let path = t.path().join("dose.dcm");
    // Oblique: rows along (0.6, 0.8, 0), columns along -z; normal (-0.8, 0.6, 0).
    let iop = [0.6, 0.8, 0.0, 0.0, 0.0, -1.0];
    write_rt_dose(&path, &[0.0, 2.5, 5.0], iop);
    let s = load_series(&path, None).unwrap();
    assert_eq!(s.grid.dims, [3, 2, 3]);
    let sp = s.grid.spacing_mm();
    assert!(
        close(sp[0], 3.0, 1e-9) && close(sp[1], 2.0, 1e-9) && close(sp[2], 2.5, 1e-9),
        "{sp:?}"
    );
    let last = s.grid.to_patient([0.0, 0.0, 2.0]);
    for (a, b) in last.iter().zip([-20.0 - 0.8 * 5.0, 10.0 + 0.6 * 5.0, 5.0]) {
        assert!(close(*a, b, 1e-9), "{last:?}");
    }
    for (i, &v) in s.voxels.iter().enumerate() {
        let raw = 70_000u32 * (i as u32 + 1) + ((i as u32) << 27);
        assert!(
            close(v as f64, raw as f64 * 1e-4, raw as f64 * 1e-4 * 1e-6),
            "voxel {i}: {v} Gy, stored {raw}"
        );
    }

    // Absolute offsets (the z of each frame) are allowed for axial grids only.
    let axial = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0];
    write_rt_dose(&path, &[5.0, 7.5, 10.0], axial);
    let s = load_series(&path, None).unwrap();
    assert!(close(s.grid.to_patient([0.0, 0.0, 2.0])[2], 10.0, 1e-9));
    write_rt_dose(&path, &[5.0, 7.5, 10.0], iop);
    let msg = load_series(&path, None).unwrap_err().to_string();
    assert!(
        msg.contains("dose.dcm") && msg.contains("GridFrameOffsetVector [5, 7.5, 10]"),
        "{msg}"
    );
}

/// Peak resident memory of this process (VmHWM), in MB, or `None` without
/// /proc. Reset first (writing 5 to /proc/self/clear_refs) so that earlier
/// tests do not count.
fn peak_rss_mb(reset: bool) -> Option<f64> {
    if reset {
        let _ = std::fs::write("/proc/self/clear_refs", "5");
    }
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

/// `bytes` with the 4-byte length of the last element with `tag` (group,
/// element; explicit VR little endian, a 4-byte-length VR) set to `len`.
fn patch_length(bytes: &mut [u8], (group, element): (u16, u16), len: u32) {
    let mut pattern = group.to_le_bytes().to_vec();
    pattern.extend(element.to_le_bytes());
    let at = bytes
        .windows(4)
        .rposition(|w| w == pattern.as_slice())
        .expect("tag in file");
    bytes[at + 8..at + 12].copy_from_slice(&len.to_le_bytes());
}

/// Loads `path` on another thread and returns its error, checking that the
/// load kept the process under 300 MB (a file of a few KB must not cost more).
fn refused_cheaply(path: PathBuf) -> String {
    let before = peak_rss_mb(true);
    let result = std::thread::spawn(move || load_series(&path, None))
        .join()
        .expect("no panic");
    let after = peak_rss_mb(false);
    eprintln!("peak RSS: {before:?} MB before the load, {after:?} MB after");
    if let Some(after) = after {
        assert!(after < 300.0, "peak RSS {after} MB");
    }
    result.expect_err("the load must fail").to_string()
}

#[test]
fn a_pixel_data_length_beyond_the_file_is_refused_without_reading_it() {
    let t = tempfile::tempdir().unwrap();
    let path = t.path().join("huge_length.dcm");
    let mut bytes = std::fs::read(data("MR_small.dcm")).unwrap();
    patch_length(&mut bytes, (0x7fe0, 0x0010), 0xFFFF_FFF0);
    std::fs::write(&path, &bytes).unwrap();
    let before = peak_rss_mb(true);
    let p = path.clone();
    let result = std::thread::spawn(move || load_series(&p, None))
        .join()
        .expect("no panic");
    let after = peak_rss_mb(false);
    eprintln!("peak RSS: {before:?} MB before the load, {after:?} MB after");
    let msg = result.unwrap_err().to_string();
    eprintln!("{msg}");
    assert!(
        msg.contains("huge_length.dcm") && msg.contains("PixelData") && msg.contains("4294967280"),
        "{msg}"
    );
    if let Some(after) = after {
        assert!(after < 300.0, "peak RSS {after} MB");
    }
}

#[test]
fn a_garbled_vr_hiding_a_huge_length_is_refused_without_reading_it() {
    // Found by tests/fuzz.rs: bytes 1156-1159 of a CT slice overwritten, so
    // that (0018,0090) DS becomes (0018,FFF0) with VR bytes FF FF. dicom-rs
    // reads an unknown VR as UN, with a 4-byte length: 776 MB here.
    let t = tempfile::tempdir().unwrap();
    let series = data("series_CT5N_98892001");
    for name in ["2062", "2392", "2693", "3023", "3353"] {
        let mut bytes = std::fs::read(series.join(name)).unwrap();
        if name == "3023" {
            bytes[1156..1160].copy_from_slice(&0xFFFF_FFF0u32.to_le_bytes());
        }
        std::fs::write(t.path().join(name), bytes).unwrap();
    }
    let msg = refused_cheaply(t.path().to_path_buf());
    assert!(msg.contains("3023"), "{msg}");
}

#[test]
fn a_huge_length_inside_a_defined_length_item_is_refused_without_reading_it() {
    // Found by tests/fuzz.rs: in CT_small.dcm the VR of an element inside a
    // defined-length sequence item garbled ("LO" -> "L\x9f"), read as UN with
    // a 875 MB length; the length check must walk into such items too.
    let t = tempfile::tempdir().unwrap();
    let mut bytes = std::fs::read(data("CT_small.dcm")).unwrap();
    assert_eq!(&bytes[1042..1044], b"LO");
    bytes[1043] = 0x9f;
    let path = t.path().join("garbled_item.dcm");
    std::fs::write(&path, bytes).unwrap();
    let msg = refused_cheaply(path);
    assert!(
        msg.contains("garbled_item.dcm") && msg.contains("declares"),
        "{msg}"
    );
}

#[test]
fn a_garbled_delimiter_with_a_huge_length_is_refused_without_reading_it() {
    // Found by tests/fuzz.rs: 4 bytes inserted into an item delimiter of a CT
    // slice made (FFFE,DE0D) with a 3.7 GB length.
    let t = tempfile::tempdir().unwrap();
    let mut bytes = std::fs::read(data("series_CT5N_98892001").join("3023")).unwrap();
    assert_eq!(&bytes[3380..3384], &[0xfe, 0xff, 0x0d, 0xe0]);
    bytes.splice(3383..3383, [0xde, 0x3f, 0xe7, 0xbf]);
    let path = t.path().join("garbled_delimiter.dcm");
    std::fs::write(&path, bytes).unwrap();
    let msg = refused_cheaply(path);
    assert!(
        msg.contains("garbled_delimiter.dcm") && msg.contains("declares"),
        "{msg}"
    );
}

/// A 4 x 3 axial MR slice at `z` (16-bit unsigned, explicit VR little
/// endian, full geometry, RescaleSlope 1), changed by `edit` before it is
/// written.
fn write_slice(
    path: &std::path::Path,
    z: f64,
    edit: impl FnOnce(&mut dicom_object::InMemDicomObject),
) {
    use dicom_core::value::{C, PrimitiveValue};
    use dicom_core::{DataElement, VR};
    use dicom_dictionary_std::{tags, uids};
    let mut obj = dicom_object::InMemDicomObject::new_empty();
    obj.put(DataElement::new(
        tags::SERIES_INSTANCE_UID,
        VR::UI,
        PrimitiveValue::from("2.25.777"),
    ));
    put_pixel_module(&mut obj, "MR", (4, 3), 1, 16);
    for (tag, value) in [
        (tags::IMAGE_POSITION_PATIENT, format!("0\\0\\{z}")),
        (tags::IMAGE_ORIENTATION_PATIENT, "1\\0\\0\\0\\1\\0".into()),
        (tags::PIXEL_SPACING, "0.5\\0.5".into()),
        (tags::SLICE_THICKNESS, "2".into()),
        (tags::RESCALE_SLOPE, "1".into()),
        (tags::RESCALE_INTERCEPT, "0".into()),
    ] {
        let parts: Vec<String> = value.split('\\').map(String::from).collect();
        obj.put(DataElement::new(
            tag,
            VR::DS,
            PrimitiveValue::Strs(parts.into()),
        ));
    }
    obj.put(DataElement::new(
        tags::PIXEL_DATA,
        VR::OW,
        PrimitiveValue::U16(C::from_vec((0..12).collect())),
    ));
    edit(&mut obj);
    write_object(path, uids::MR_IMAGE_STORAGE, obj);
}

/// Sets a US attribute.
fn put_us(obj: &mut dicom_object::InMemDicomObject, tag: dicom_core::Tag, v: u16) {
    use dicom_core::value::PrimitiveValue;
    obj.put(dicom_core::DataElement::new(
        tag,
        dicom_core::VR::US,
        PrimitiveValue::from(v),
    ));
}

/// Sets a DS attribute to `text` as written (values split at `\`).
fn put_ds(obj: &mut dicom_object::InMemDicomObject, tag: dicom_core::Tag, text: &str) {
    use dicom_core::value::PrimitiveValue;
    let parts: Vec<String> = text.split('\\').map(String::from).collect();
    obj.put(dicom_core::DataElement::new(
        tag,
        dicom_core::VR::DS,
        PrimitiveValue::Strs(parts.into()),
    ));
}

/// Loads `path`, expecting an error; runs in a thread so that a panic
/// fails the test with its text instead of aborting the others.
fn load_error(path: &std::path::Path) -> String {
    let p = path.to_path_buf();
    match std::thread::spawn(move || load_series(&p, None)).join() {
        Ok(Ok(_)) => panic!("{} loaded", path.display()),
        Ok(Err(e)) => e.to_string(),
        Err(_) => panic!("{}: the loader panicked", path.display()),
    }
}

#[test]
fn the_slice_writer_gives_a_loadable_slice() {
    let t = tempfile::tempdir().unwrap();
    let path = t.path().join("ok.dcm");
    write_slice(&path, 0.0, |_| {});
    let s = load_series(&path, None).unwrap();
    assert_eq!(s.grid.dims, [3, 4, 1]);
    assert_eq!(s.voxels[11], 11.0);
}

#[test]
fn a_transfer_syntax_that_does_not_match_the_data_is_refused_cheaply() {
    // An explicit VR file whose meta group says implicit VR: value bytes
    // would be read as lengths.
    let t = tempfile::tempdir().unwrap();
    let path = t.path().join("wrong_syntax.dcm");
    write_slice(&path, 0.0, |_| {});
    let mut bytes = std::fs::read(&path).unwrap();
    let explicit = b"1.2.840.10008.1.2.1\0";
    let at = bytes
        .windows(explicit.len())
        .position(|w| w == explicit)
        .unwrap();
    bytes[at..at + explicit.len()].copy_from_slice(b"1.2.840.10008.1.2\0\0\0");
    std::fs::write(&path, &bytes).unwrap();
    let before = peak_rss_mb(true);
    let msg = load_error(&path);
    let after = peak_rss_mb(false);
    eprintln!("peak RSS: {before:?} MB before the load, {after:?} MB after");
    assert!(
        msg.contains("wrong_syntax.dcm: unreadable DICOM file: ")
            && msg.contains("(0008,0016) declares")
            && msg.contains("transfer syntax 1.2.840.10008.1.2 that does not match"),
        "{msg}"
    );
    if let Some(after) = after {
        assert!(after < 300.0, "peak RSS {after} MB");
    }
}

#[test]
fn header_bit_flips_are_refused_naming_the_tags() {
    let t = tempfile::tempdir().unwrap();
    let original = std::fs::read(data("MR_small.dcm")).unwrap();
    // Rows 64 -> 64 | 0x4000 (bit 14 of the US value of (0028,0010)).
    let rows = [0x28, 0x00, 0x10, 0x00, b'U', b'S', 2, 0, 64, 0];
    let at = original.windows(10).position(|w| w == rows).unwrap();
    let mut bytes = original.clone();
    bytes[at + 9] |= 0x40;
    let path = t.path().join("rows_flipped.dcm");
    std::fs::write(&path, &bytes).unwrap();
    let msg = load_error(&path);
    assert!(
        msg.contains(
            "rows_flipped.dcm: PixelData (7FE0,0010) is 8192 bytes, but Rows 16448 x Columns 64"
        ) && msg.contains("= 2105344 bytes"),
        "{msg}"
    );
    // A flipped high bit in PixelData's length: 8192 -> 8192 + 2^30.
    let mut bytes = original.clone();
    patch_length(&mut bytes, (0x7fe0, 0x0010), 8192 | 1 << 30);
    let path = t.path().join("length_flipped.dcm");
    std::fs::write(&path, &bytes).unwrap();
    let before = peak_rss_mb(true);
    let msg = load_error(&path);
    let after = peak_rss_mb(false);
    eprintln!("peak RSS: {before:?} MB before the load, {after:?} MB after");
    assert!(
        msg.contains("length_flipped.dcm")
            && msg.contains("PixelData (7FE0,0010) declares 1073750016 bytes"),
        "{msg}"
    );
    if let Some(after) = after {
        assert!(after < 300.0, "peak RSS {after} MB");
    }
}

#[test]
fn absurd_dimensions_of_compressed_data_are_refused_naming_the_memory() {
    // RLE: the PixelData length says nothing about the decoded size.
    let t = tempfile::tempdir().unwrap();
    let mut bytes = std::fs::read(data("MR_small_RLE.dcm")).unwrap();
    for element in [0x10u8, 0x11] {
        let tag = [0x28, 0x00, element, 0x00, b'U', b'S', 2, 0, 64, 0];
        let at = bytes.windows(10).position(|w| w == tag).unwrap();
        bytes[at + 8..at + 10].copy_from_slice(&[0xFF, 0xFF]);
    }
    let path = t.path().join("huge_rle.dcm");
    std::fs::write(&path, &bytes).unwrap();
    let msg = load_error(&path);
    assert!(
        msg.contains("huge_rle.dcm: Rows 65535 x Columns 65535 x NumberOfFrames 1")
            && msg.contains("4294836225 voxels would take about 25.8 GB to decode")
            && msg.contains("RLE Lossless"),
        "{msg}"
    );
}

#[test]
fn inconsistent_pixel_modules_are_errors_not_panics() {
    use dicom_dictionary_std::tags;
    let t = tempfile::tempdir().unwrap();
    type Case = (
        &'static str,
        &'static [(dicom_core::Tag, u16)],
        &'static str,
    );
    let cases: [Case; 7] = [
        (
            "stored0",
            &[(tags::BITS_STORED, 0)],
            "BitsAllocated 16, BitsStored 0, HighBit 15: BitsStored must be 1 to BitsAllocated",
        ),
        (
            "stored17",
            &[(tags::BITS_STORED, 17), (tags::HIGH_BIT, 16)],
            "BitsAllocated 16, BitsStored 17, HighBit 16: BitsStored must be 1 to BitsAllocated",
        ),
        (
            "highbit",
            &[(tags::BITS_STORED, 12)],
            "BitsAllocated 16, BitsStored 12, HighBit 15: HighBit must be BitsStored - 1",
        ),
        (
            "allocated12",
            &[
                (tags::BITS_ALLOCATED, 12),
                (tags::BITS_STORED, 12),
                (tags::HIGH_BIT, 11),
            ],
            "BitsAllocated 12, BitsStored 12, HighBit 11: BitsAllocated must be 8, 16 or 32",
        ),
        (
            "samples0",
            &[(tags::SAMPLES_PER_PIXEL, 0)],
            "SamplesPerPixel 0",
        ),
        ("rows0", &[(tags::ROWS, 0)], "Rows 0, Columns 3"),
        ("cols0", &[(tags::COLUMNS, 0)], "Rows 4, Columns 0"),
    ];
    for (name, values, expected) in cases {
        let path = t.path().join(format!("{name}.dcm"));
        write_slice(&path, 0.0, |obj| {
            for &(tag, v) in values {
                put_us(obj, tag, v);
            }
        });
        let msg = load_error(&path);
        assert!(
            msg.contains(&format!("{name}.dcm: {expected}")),
            "{name}: {msg}"
        );
    }
}

#[test]
fn a_slice_in_another_pixel_format_is_named_with_the_values() {
    use dicom_core::value::{C, PrimitiveValue};
    use dicom_dictionary_std::tags;
    let t = tempfile::tempdir().unwrap();
    for k in 0..4 {
        write_slice(&t.path().join(format!("s{k}.dcm")), 2.0 * k as f64, |obj| {
            if k == 2 {
                for tag in [tags::BITS_ALLOCATED, tags::BITS_STORED] {
                    put_us(obj, tag, 8);
                }
                put_us(obj, tags::HIGH_BIT, 7);
                obj.put(dicom_core::DataElement::new(
                    tags::PIXEL_DATA,
                    dicom_core::VR::OB,
                    PrimitiveValue::U8(C::from_vec((0..12).collect())),
                ));
            }
        });
    }
    let err = load_series(t.path(), None).unwrap_err();
    assert!(matches!(err, SeriesError::Format(_)), "{err}");
    let msg = err.to_string();
    assert!(
        msg.contains(&format!(
            "{} has BitsAllocated 8, BitsStored 8, but 3 other files have BitsAllocated 16, BitsStored 16",
            t.path().join("s2.dcm").display()
        )),
        "{msg}"
    );
    // Signedness and photometric interpretation count too.
    write_slice(&t.path().join("s2.dcm"), 4.0, |obj| {
        put_us(obj, tags::PIXEL_REPRESENTATION, 1);
        obj.put(dicom_core::DataElement::new(
            tags::PHOTOMETRIC_INTERPRETATION,
            dicom_core::VR::CS,
            PrimitiveValue::from("MONOCHROME1"),
        ));
    });
    let msg = load_series(t.path(), None).unwrap_err().to_string();
    assert!(
        msg.contains("s2.dcm has PixelRepresentation 1, PhotometricInterpretation MONOCHROME1, but 3 other files have PixelRepresentation 0, PhotometricInterpretation MONOCHROME2"),
        "{msg}"
    );
}

#[test]
fn malformed_or_non_finite_numbers_are_errors_naming_the_tag() {
    use dicom_dictionary_std::tags;
    let t = tempfile::tempdir().unwrap();
    let cases = [
        (
            tags::RESCALE_SLOPE,
            "abc",
            "RescaleSlope (0028,1053) is not a number: \"abc\"",
        ),
        (
            tags::RESCALE_SLOPE,
            "nan",
            "RescaleSlope (0028,1053) is not finite: \"nan\"",
        ),
        (
            tags::RESCALE_INTERCEPT,
            "inf",
            "RescaleIntercept (0028,1052) is not finite: \"inf\"",
        ),
        (tags::RESCALE_SLOPE, "0", "RescaleSlope (0028,1053) is 0"),
        (
            tags::PIXEL_SPACING,
            "0.5\\abc",
            "PixelSpacing (0028,0030) is not a number: \"0.5\\\\abc\"",
        ),
        (
            tags::PIXEL_SPACING,
            "1e308\\0.5",
            "PixelSpacing (0028,0030) [1e308, 0.5] must be positive and at most 10000 mm",
        ),
        (
            tags::PIXEL_SPACING,
            "0\\0.5",
            "PixelSpacing (0028,0030) [0, 0.5] must be positive",
        ),
        (
            tags::SLICE_THICKNESS,
            "nan",
            "SliceThickness (0018,0050) is not finite",
        ),
        (
            tags::SLICE_THICKNESS,
            "1e300",
            "SliceThickness (0018,0050) 1e300 mm is absurd",
        ),
        (
            tags::IMAGE_POSITION_PATIENT,
            "0\\x\\0",
            "ImagePositionPatient (0020,0032) is not a number",
        ),
        (
            tags::IMAGE_POSITION_PATIENT,
            "0\\inf\\0",
            "ImagePositionPatient (0020,0032) is not finite",
        ),
        (
            tags::IMAGE_ORIENTATION_PATIENT,
            "1\\0\\0\\0\\nan\\0",
            "ImageOrientationPatient (0020,0037) is not finite",
        ),
        (
            tags::IMAGE_ORIENTATION_PATIENT,
            "1\\0\\0\\0\\2\\0",
            "ImageOrientationPatient (0020,0037) [1, 0, 0, 0, 2, 0] is not two orthogonal unit vectors (lengths 1.0000 and 2.0000",
        ),
        (
            tags::IMAGE_ORIENTATION_PATIENT,
            "1\\0\\0\\0.6\\0.8\\0",
            "ImageOrientationPatient (0020,0037) [1, 0, 0, 0.6, 0.8, 0] is not two orthogonal unit vectors (lengths 1.0000 and 1.0000, dot product 0.6000)",
        ),
        (
            tags::DOSE_GRID_SCALING,
            "abc",
            "DoseGridScaling (3004,000E) is not a number",
        ),
        (
            tags::DOSE_GRID_SCALING,
            "-1",
            "DoseGridScaling (3004,000E) [-1] must be one positive number",
        ),
    ];
    for (i, (tag, text, expected)) in cases.into_iter().enumerate() {
        let path = t.path().join(format!("case{i}.dcm"));
        write_slice(&path, 0.0, |obj| put_ds(obj, tag, text));
        let msg = load_error(&path);
        assert!(
            msg.contains(&format!("case{i}.dcm: {expected}")),
            "{text}: {msg}"
        );
    }
    // GridFrameOffsetVector (RT Dose) with a non-finite offset.
    let path = t.path().join("dose.dcm");
    write_rt_dose(&path, &[0.0, f64::NAN, 5.0], [1.0, 0.0, 0.0, 0.0, 1.0, 0.0]);
    let msg = load_error(&path);
    assert!(
        msg.contains("dose.dcm: GridFrameOffsetVector (3004,000C) is not finite"),
        "{msg}"
    );
}
