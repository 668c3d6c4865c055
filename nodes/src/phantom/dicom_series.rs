//! Writes a volume as a DICOM MR series, one file per slice, with dicom-object:
//! 16-bit unsigned MONOCHROME2, explicit VR little endian, full geometry
//! (ImagePositionPatient, ImageOrientationPatient, PixelSpacing, SliceThickness),
//! rescale slope/intercept, and deterministic UIDs. File names and write order are
//! shuffled, and InstanceNumber runs against the slice normal, so a reader must
//! sort slices by position.

use crate::numeric::round_to_u16;
use dicom_core::value::{C, PrimitiveValue};
use dicom_core::{DataElement, VR};
use dicom_dictionary_std::{tags, uids};
use dicom_object::{FileMetaTableBuilder, InMemDicomObject};
use fusegraph_engine::value::Grid;
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// Stored value = signal / RESCALE_SLOPE (so signal 1.0, the gel, is 4000).
pub const RESCALE_SLOPE: f64 = 0.00025;

/// Identity of a written series.
#[derive(Debug, Clone, PartialEq)]
pub struct SeriesIds {
    /// StudyInstanceUID.
    pub study_uid: String,
    /// SeriesInstanceUID.
    pub series_uid: String,
    /// FrameOfReferenceUID.
    pub frame_uid: String,
}

impl SeriesIds {
    /// UIDs derived from `seed` (the 2.25 root takes a 128-bit number).
    pub fn from_seed(seed: u64) -> Self {
        SeriesIds {
            study_uid: uid(seed, "study"),
            series_uid: uid(seed, "series"),
            frame_uid: uid(seed, "frame"),
        }
    }
}

fn uid(seed: u64, what: &str) -> String {
    let h = blake3::hash(format!("fusegraph phantom {seed} {what}").as_bytes());
    let n = u128::from_le_bytes(h.as_bytes()[..16].try_into().expect("16 bytes"));
    format!("2.25.{n}")
}

/// A decimal string (VR DS) of at most 16 characters.
fn ds(x: f64) -> String {
    for decimals in (0..=10).rev() {
        let s = format!("{x:.decimals$}");
        let s = if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        };
        let s = if s == "-0" { "0".to_string() } else { s };
        if s.len() <= 16 {
            return s;
        }
    }
    format!("{x:.0}")
}

fn ds_multi(values: &[f64]) -> PrimitiveValue {
    PrimitiveValue::Strs(values.iter().map(|&v| ds(v)).collect())
}

/// Writes `signal` (on `grid`) into `dir`, one file per slice; returns the files.
pub fn write_series(
    dir: &Path,
    grid: &Grid,
    signal: &[f32],
    ids: &SeriesIds,
    seed: u64,
) -> std::io::Result<Vec<PathBuf>> {
    let [nx, ny, nz] = grid.dims;
    let m = &grid.voxel_to_patient;
    let spacing = grid.spacing_mm();
    let row_dir: Vec<f64> = (0..3).map(|r| m[r][0] / spacing[0]).collect();
    let col_dir: Vec<f64> = (0..3).map(|r| m[r][1] / spacing[1]).collect();
    let mut order: Vec<usize> = (0..nz).collect();
    order.shuffle(&mut ChaCha8Rng::seed_from_u64(seed ^ 0x5EED_D1C0));
    std::fs::create_dir_all(dir)?;
    // Slices are encoded and written in parallel: each file depends on its
    // slice alone, so the files are the same bytes.
    let write_slice = |(name_index, &k): (usize, &usize)| -> std::io::Result<PathBuf> {
        let position = grid.to_patient([0.0, 0.0, k as f64]);
        let pixels: Vec<u16> = signal[k * nx * ny..(k + 1) * nx * ny]
            .iter()
            .map(|&s| round_to_u16(s as f64 / RESCALE_SLOPE))
            .collect();
        let instance = nz - k;
        let sop_uid = format!("{}.{instance}", ids.series_uid);
        let mut obj = InMemDicomObject::new_empty();
        let mut put_str = |tag, vr, value: &str| {
            obj.put(DataElement::new(tag, vr, PrimitiveValue::from(value)));
        };
        put_str(tags::SPECIFIC_CHARACTER_SET, VR::CS, "ISO_IR 100");
        put_str(tags::IMAGE_TYPE, VR::CS, "ORIGINAL\\PRIMARY\\OTHER");
        put_str(tags::SOP_CLASS_UID, VR::UI, uids::MR_IMAGE_STORAGE);
        put_str(tags::SOP_INSTANCE_UID, VR::UI, &sop_uid);
        put_str(tags::STUDY_DATE, VR::DA, "20260101");
        put_str(tags::STUDY_TIME, VR::TM, "120000");
        put_str(tags::ACCESSION_NUMBER, VR::SH, "");
        put_str(tags::MODALITY, VR::CS, "MR");
        put_str(tags::MANUFACTURER, VR::LO, "fusegraph phantom");
        put_str(tags::REFERRING_PHYSICIAN_NAME, VR::PN, "");
        put_str(
            tags::SERIES_DESCRIPTION,
            VR::LO,
            "T1 3D breast phantom (synthetic)",
        );
        put_str(tags::PATIENT_NAME, VR::PN, "Phantom^Breast");
        put_str(tags::PATIENT_ID, VR::LO, &format!("PHANTOM{seed}"));
        put_str(tags::PATIENT_BIRTH_DATE, VR::DA, "");
        put_str(tags::PATIENT_SEX, VR::CS, "F");
        put_str(tags::BODY_PART_EXAMINED, VR::CS, "BREAST");
        put_str(tags::SCANNING_SEQUENCE, VR::CS, "GR");
        put_str(tags::SEQUENCE_VARIANT, VR::CS, "SP");
        put_str(tags::SCAN_OPTIONS, VR::CS, "");
        put_str(tags::MR_ACQUISITION_TYPE, VR::CS, "3D");
        put_str(tags::SLICE_THICKNESS, VR::DS, &ds(spacing[2]));
        put_str(tags::REPETITION_TIME, VR::DS, "5.5");
        put_str(tags::ECHO_TIME, VR::DS, "2.1");
        put_str(tags::MAGNETIC_FIELD_STRENGTH, VR::DS, "1.5");
        put_str(tags::SPACING_BETWEEN_SLICES, VR::DS, &ds(spacing[2]));
        put_str(tags::PATIENT_POSITION, VR::CS, "FFP");
        put_str(tags::STUDY_INSTANCE_UID, VR::UI, &ids.study_uid);
        put_str(tags::SERIES_INSTANCE_UID, VR::UI, &ids.series_uid);
        put_str(tags::STUDY_ID, VR::SH, "1");
        put_str(tags::SERIES_NUMBER, VR::IS, "3");
        put_str(tags::INSTANCE_NUMBER, VR::IS, &instance.to_string());
        put_str(tags::FRAME_OF_REFERENCE_UID, VR::UI, &ids.frame_uid);
        put_str(tags::POSITION_REFERENCE_INDICATOR, VR::LO, "");
        put_str(tags::PHOTOMETRIC_INTERPRETATION, VR::CS, "MONOCHROME2");
        put_str(tags::RESCALE_INTERCEPT, VR::DS, "0");
        put_str(tags::RESCALE_SLOPE, VR::DS, &ds(RESCALE_SLOPE));
        put_str(tags::RESCALE_TYPE, VR::LO, "US");
        obj.put(DataElement::new(
            tags::IMAGE_POSITION_PATIENT,
            VR::DS,
            ds_multi(&position),
        ));
        obj.put(DataElement::new(
            tags::IMAGE_ORIENTATION_PATIENT,
            VR::DS,
            ds_multi(&[row_dir.as_slice(), col_dir.as_slice()].concat()),
        ));
        obj.put(DataElement::new(
            tags::SLICE_LOCATION,
            VR::DS,
            PrimitiveValue::from(ds(position[2]).as_str()),
        ));
        // PixelSpacing is (between rows, between columns) = (j spacing, i spacing).
        obj.put(DataElement::new(
            tags::PIXEL_SPACING,
            VR::DS,
            ds_multi(&[spacing[1], spacing[0]]),
        ));
        let us = |tag, v: u16| DataElement::new(tag, VR::US, PrimitiveValue::from(v));
        obj.put(us(tags::SAMPLES_PER_PIXEL, 1));
        obj.put(us(tags::ROWS, ny as u16));
        obj.put(us(tags::COLUMNS, nx as u16));
        obj.put(us(tags::BITS_ALLOCATED, 16));
        obj.put(us(tags::BITS_STORED, 16));
        obj.put(us(tags::HIGH_BIT, 15));
        obj.put(us(tags::PIXEL_REPRESENTATION, 0));
        obj.put(DataElement::new(
            tags::PIXEL_DATA,
            VR::OW,
            PrimitiveValue::U16(C::from_vec(pixels)),
        ));
        let file = obj
            .with_meta(
                FileMetaTableBuilder::new()
                    .transfer_syntax(uids::EXPLICIT_VR_LITTLE_ENDIAN)
                    .implementation_class_uid("2.25.2026112100")
                    .implementation_version_name("FUSEGRAPH_01"),
            )
            .map_err(std::io::Error::other)?;
        let path = dir.join(format!("IM{:04}.dcm", name_index + 1));
        file.write_to_file(&path).map_err(std::io::Error::other)?;
        Ok(path)
    };
    order.par_iter().enumerate().map(write_slice).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decimal_strings_fit_sixteen_characters() {
        assert_eq!(ds(0.6), "0.6");
        assert_eq!(ds(-0.0), "0");
        assert_eq!(ds(-123.456789012345), "-123.4567890123");
        assert_eq!(ds(0.00025), "0.00025");
        for x in [1e5 + 1.0 / 3.0, -0.9998476951563913, 12345.678901234] {
            let s = ds(x);
            assert!(
                s.len() <= 16 && (s.parse::<f64>().unwrap() - x).abs() < 1e-4,
                "{s}"
            );
        }
    }

    #[test]
    #[allow(clippy::needless_range_loop)] // matrix indices
    fn an_oblique_series_reads_back_with_its_geometry_and_values() {
        let rotation = nalgebra::Rotation3::from_euler_angles(0.35, -0.2, 0.1);
        let spacing = [0.7, 0.9, 1.6];
        let mut m = [[0.0; 4]; 4];
        for r in 0..3 {
            for c in 0..3 {
                m[r][c] = rotation[(r, c)] * spacing[c];
            }
        }
        m[0][3] = -12.5;
        m[1][3] = 40.25;
        m[2][3] = -7.0;
        m[3][3] = 1.0;
        let grid = Grid {
            dims: [8, 6, 5],
            voxel_to_patient: m,
        };
        let signal: Vec<f32> = (0..grid.len()).map(|i| (i % 17) as f32 * 0.05).collect();
        let dir = tempfile::tempdir().unwrap();
        write_series(dir.path(), &grid, &signal, &SeriesIds::from_seed(3), 3).unwrap();
        let back = crate::dicom::load_series(dir.path(), None).unwrap();
        assert_eq!(back.grid.dims, grid.dims);
        for r in 0..4 {
            for c in 0..4 {
                let (a, b) = (back.grid.voxel_to_patient[r][c], m[r][c]);
                assert!((a - b).abs() < 1e-6, "[{r}][{c}] {a} vs {b}");
            }
        }
        for (a, b) in back.voxels.iter().zip(&signal) {
            assert!(
                (a - b).abs() <= 0.5 * RESCALE_SLOPE as f32 + 1e-6,
                "{a} vs {b}"
            );
        }
    }

    #[test]
    fn uids_are_valid_and_deterministic() {
        let a = SeriesIds::from_seed(7);
        assert_eq!(a, SeriesIds::from_seed(7));
        assert_ne!(a.series_uid, SeriesIds::from_seed(8).series_uid);
        for u in [&a.study_uid, &a.series_uid, &a.frame_uid] {
            assert!(u.len() <= 64 - 5 && u.starts_with("2.25."), "{u}");
            assert!(u[5..].chars().all(|c| c.is_ascii_digit()) && !u[5..].starts_with('0'));
        }
    }
}
