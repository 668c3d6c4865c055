//! Frames -> one volume: choosing the series, checking that the frames form a
//! regular grid (one orientation, one size, evenly spaced along the normal), and
//! building the voxel -> patient affine.

use super::frames::{FileContent, Frame, dicom_encoding, read_file};
use super::header::PixelFormat;
use fusegraph_engine::value::Grid;
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Why frames do not make one volume.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SeriesError {
    /// A file cannot be read or decoded (the message names it).
    #[error("{0}")]
    File(String),
    /// No DICOM image was found; `skipped` says what the folder held instead.
    #[error("{}: no DICOM image found{}", dir.display(), skipped_list(skipped))]
    Empty {
        /// The folder or file.
        dir: PathBuf,
        /// One line per skipped file: the file and why.
        skipped: Vec<String>,
    },
    /// Several series and no choice.
    #[error("{dir}: holds {count} series; choose one with series_uid: {list}")]
    SeveralSeries {
        /// The folder.
        dir: PathBuf,
        /// How many.
        count: usize,
        /// UID, description and file count of each.
        list: String,
    },
    /// The requested series is not there.
    #[error("{dir}: no series with UID {uid}; it holds: {list}")]
    NoSuchSeries {
        /// The folder.
        dir: PathBuf,
        /// The requested UID.
        uid: String,
        /// What is there.
        list: String,
    },
    /// Frames are not parallel.
    #[error("slices have different orientations (a localiser or mixed series?): {0}")]
    MixedOrientation(String),
    /// Frames are unevenly spaced or missing.
    #[error("slices are not evenly spaced along the normal: {0}")]
    Spacing(String),
    /// Two different images at one position.
    #[error("duplicate slices: {0}")]
    Duplicate(String),
    /// Files differ in pixel format (BitsAllocated, BitsStored,
    /// PixelRepresentation, SamplesPerPixel, PhotometricInterpretation, Rows,
    /// Columns).
    #[error("slices differ in pixel format: {0}")]
    Format(String),
    /// Frames differ in size or pixel spacing, or are sheared.
    #[error("slices do not form one grid: {0}")]
    Grid(String),
}

impl SeriesError {
    /// The error with the folder (or file) it was found in named, for the
    /// geometry checks that see frames but not where they came from.
    pub fn in_folder(self, dir: &Path) -> Self {
        let named = |msg: String| format!("{msg} (in {})", dir.display());
        match self {
            SeriesError::MixedOrientation(m) => SeriesError::MixedOrientation(named(m)),
            SeriesError::Spacing(m) => SeriesError::Spacing(named(m)),
            SeriesError::Duplicate(m) => SeriesError::Duplicate(named(m)),
            SeriesError::Format(m) => SeriesError::Format(named(m)),
            SeriesError::Grid(m) => SeriesError::Grid(named(m)),
            other => other,
        }
    }
}

/// A volume read from a series.
#[derive(Debug, Clone, PartialEq)]
pub struct LoadedSeries {
    /// Geometry: voxel (column i, row j, slice k) -> patient LPS mm.
    pub grid: Grid,
    /// Rescaled voxel values in [`Grid::index`] order.
    pub voxels: Vec<f32>,
    /// SeriesInstanceUID.
    pub series_uid: String,
    /// Number of files read.
    pub files: usize,
    /// Things worth knowing that did not stop the load, for the user: each
    /// skipped file (named, relative to the folder, with the reason; at most
    /// [`MAX_NAMED_SKIPS`], then a count), then remarks on the geometry.
    pub warnings: Vec<String>,
}

fn describe(groups: &BTreeMap<String, Vec<Frame>>) -> String {
    groups
        .iter()
        .map(|(uid, frames)| {
            let desc = &frames[0].series_description;
            let desc = if desc.is_empty() {
                String::new()
            } else {
                format!(" \"{desc}\"")
            };
            let files: std::collections::BTreeSet<_> = frames.iter().map(|f| &f.file).collect();
            format!(
                "{}{desc} ({} files)",
                if uid.is_empty() { "(no UID)" } else { uid },
                files.len()
            )
        })
        .collect::<Vec<_>>()
        .join("; ")
}

fn skipped_list(skipped: &[String]) -> String {
    match skipped.len() {
        0 => String::new(),
        n if n <= MAX_NAMED_SKIPS => format!("; skipped: {}", skipped.join("; ")),
        n => format!(
            "; skipped {n} files: {}; and {} more",
            skipped[..MAX_NAMED_SKIPS].join("; "),
            n - MAX_NAMED_SKIPS
        ),
    }
}

/// At most this many skipped files are named one by one; the rest are counted.
pub const MAX_NAMED_SKIPS: usize = 20;

/// `file` as the user gave it: relative to the folder read, if inside it.
fn shown(file: &Path, root: &Path) -> String {
    file.strip_prefix(root)
        .ok()
        .filter(|r| !r.as_os_str().is_empty())
        .unwrap_or(file)
        .display()
        .to_string()
}

/// How [`load_series_with`] treats what it finds.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LoadOptions {
    /// SeriesInstanceUID to read when the folder holds several.
    pub series_uid: Option<String>,
    /// Whether a DICOM file that cannot be read fails the load (true) or is
    /// skipped with a note (false, the default: a skipped slice inside the
    /// stack is still refused by the spacing check, so nothing is lost
    /// silently).
    pub strict: bool,
}

/// [`load_series_with`] with the default options and an optional series.
pub fn load_series(path: &Path, series_uid: Option<&str>) -> Result<LoadedSeries, SeriesError> {
    load_series_with(
        path,
        &LoadOptions {
            series_uid: series_uid.map(str::to_string),
            strict: false,
        },
    )
}

/// Reads a folder of slices (or one single- or multi-frame file) as a volume.
///
/// What a CD or PACS export puts beside the images is skipped, one warning per
/// file naming it and why: files that are neither DICOM Part 10 (128-byte
/// preamble and "DICM") nor a bare implicit VR data set, DICOMDIR, and objects
/// without pixel data (structured reports, RT structure sets and plans,
/// presentation states, ...). Exact copies of a file (same bytes) are dropped
/// with a note. A DICOM file that fails to parse or decode is skipped with a
/// note naming it and why, or is an error with [`LoadOptions::strict`]; one
/// given alone, and a folder with no image at all (naming what was skipped),
/// are errors.
pub fn load_series_with(path: &Path, options: &LoadOptions) -> Result<LoadedSeries, SeriesError> {
    let series_uid = options.series_uid.as_deref();
    let mut skipped = Vec::new();
    let files: Vec<PathBuf> = if path.is_dir() {
        let mut files = Vec::new();
        collect_files(path, &mut files)
            .map_err(|e| SeriesError::File(format!("{}: {e}", path.display())))?;
        files.sort();
        let (dicom, other): (Vec<_>, Vec<_>) =
            files.into_iter().partition(|f| dicom_encoding(f).is_some());
        for f in &other {
            skipped.push(format!(
                "{}: skipped: not a DICOM file (no 128-byte preamble and \"DICM\", nor a bare data set)",
                shown(f, path)
            ));
        }
        drop_exact_copies(dicom, path, &mut skipped)
    } else {
        vec![path.to_path_buf()]
    };
    let single = !path.is_dir();
    let contents: Vec<Result<FileContent, String>> =
        files.par_iter().map(|f| read_file(f)).collect();
    let mut groups: BTreeMap<String, Vec<Frame>> = BTreeMap::new();
    let mut overlays = 0;
    let mut unreadable = Vec::new();
    for (file, content) in files.iter().zip(contents) {
        let content = match content {
            Ok(c) => c,
            Err(e) if options.strict || single => return Err(SeriesError::File(e)),
            Err(e) => {
                skipped.push(format!(
                    "{}: skipped: {}",
                    shown(file, path),
                    e.strip_prefix(&format!("{}: ", file.display()))
                        .unwrap_or(&e)
                ));
                unreadable.push(e);
                continue;
            }
        };
        match content {
            FileContent::Frames(frames) => {
                overlays += usize::from(frames.first().is_some_and(|f| f.has_overlay));
                for frame in frames {
                    groups
                        .entry(frame.series_uid.clone())
                        .or_default()
                        .push(frame);
                }
            }
            FileContent::NotImage(why) => {
                skipped.push(format!("{}: skipped: {why}", shown(file, path)));
            }
        }
    }
    if groups.is_empty() && !unreadable.is_empty() {
        // Nothing loaded: the files' own errors say more than "no image".
        let n = unreadable.len();
        let mut first = unreadable.remove(0);
        if n > 1 {
            first += &format!(" (and {} other DICOM files could not be read)", n - 1);
        }
        return Err(SeriesError::File(first));
    }
    if groups.is_empty() {
        return Err(SeriesError::Empty {
            dir: path.to_path_buf(),
            skipped,
        });
    }
    let frames = match series_uid {
        Some(uid) => groups
            .remove(uid)
            .ok_or_else(|| SeriesError::NoSuchSeries {
                dir: path.to_path_buf(),
                uid: uid.to_string(),
                list: describe(&groups),
            })?,
        None if groups.len() > 1 => {
            return Err(SeriesError::SeveralSeries {
                dir: path.to_path_buf(),
                count: groups.len(),
                list: describe(&groups),
            });
        }
        None => groups.into_values().next().expect("one group"),
    };
    let uid = frames[0].series_uid.clone();
    let file_count = frames
        .iter()
        .map(|f| &f.file)
        .collect::<std::collections::BTreeSet<_>>()
        .len();
    let (grid, voxels, more) = assemble(frames).map_err(|e| {
        let e = e.in_folder(path);
        match e {
            // A gap where an unreadable file was skipped: say which and why.
            SeriesError::Spacing(msg) if !unreadable.is_empty() => SeriesError::Spacing(format!(
                "{msg}; {} unreadable file(s) were skipped: {}",
                unreadable.len(),
                unreadable[..unreadable.len().min(MAX_NAMED_SKIPS)].join("; ")
            )),
            other => other,
        }
    })?;
    let mut warnings = Vec::new();
    if overlays > 0 {
        warnings.push(format!(
            "{overlays} file(s) carry overlay planes (60xx,3000: graphics or ROIs burnt over the image); they are not loaded"
        ));
    }
    if skipped.len() > MAX_NAMED_SKIPS {
        let n = skipped.len() - MAX_NAMED_SKIPS;
        skipped.truncate(MAX_NAMED_SKIPS);
        skipped.push(format!("and {n} more files skipped"));
    }
    warnings.append(&mut skipped);
    warnings.extend(more);
    Ok(LoadedSeries {
        grid,
        voxels,
        series_uid: uid,
        files: file_count,
        warnings,
    })
}

/// `files` without exact copies (the same bytes, so the same SOP instance: a
/// folder copied into itself, a file exported twice), each dropped with a
/// note naming the file it copies. Only files of equal size are compared.
fn drop_exact_copies(files: Vec<PathBuf>, root: &Path, notes: &mut Vec<String>) -> Vec<PathBuf> {
    let sizes: Vec<Option<u64>> = files
        .iter()
        .map(|f| std::fs::metadata(f).ok().map(|m| m.len()))
        .collect();
    let mut by_size: BTreeMap<u64, usize> = BTreeMap::new();
    for s in sizes.iter().flatten() {
        *by_size.entry(*s).or_default() += 1;
    }
    let hashes: Vec<Option<blake3::Hash>> = files
        .par_iter()
        .zip(&sizes)
        .map(|(f, s)| {
            s.filter(|s| by_size[s] > 1)
                .and_then(|_| fusegraph_engine::hash::hash_path(f).ok())
        })
        .collect();
    let mut first_of: BTreeMap<[u8; 32], usize> = BTreeMap::new();
    let mut kept = Vec::with_capacity(files.len());
    for (i, (file, hash)) in files.iter().zip(&hashes).enumerate() {
        if let Some(h) = hash {
            if let Some(&j) = first_of.get(h.as_bytes()) {
                notes.push(format!(
                    "{}: dropped: an exact copy of {}",
                    shown(file, root),
                    shown(&files[j], root)
                ));
                continue;
            }
            first_of.insert(*h.as_bytes(), i);
        }
        kept.push(file.clone());
    }
    kept
}

fn collect_files(dir: &Path, out: &mut Vec<PathBuf>) -> std::io::Result<()> {
    for entry in std::fs::read_dir(dir)? {
        let path = entry?.path();
        let hidden = path
            .file_name()
            .is_some_and(|n| n.to_string_lossy().starts_with('.'));
        if hidden {
            continue;
        }
        if path.is_dir() {
            collect_files(&path, out)?;
        } else {
            out.push(path);
        }
    }
    Ok(())
}

/// A spacing error lists every position for stacks of at most this many slices.
const MAX_LISTED_SLICES: usize = 12;

/// Shear below this is rounding in the positions, not worth a note.
const MAX_UNNOTED_SHEAR_DEG: f64 = 0.01;

/// The angle between the slice step and the slice normal, degrees: 0 for a
/// stack of slices straight above each other.
fn shear_deg(step: [f64; 3], normal: [f64; 3]) -> f64 {
    let along = dot(step, normal).abs();
    let len = dot(step, step).sqrt();
    if len == 0.0 {
        return 0.0;
    }
    (along / len).clamp(-1.0, 1.0).acos().to_degrees()
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn fmt3(v: &[f64]) -> String {
    let parts: Vec<String> = v.iter().map(|x| format!("{x:.4}")).collect();
    format!("[{}]", parts.join(", "))
}

/// Checks that every file of a series has one pixel format (bits, sign,
/// samples, photometric interpretation, size): an 8-bit slice among 16-bit
/// ones would otherwise load with values on another scale. The error names
/// the first file that differs from the most common format, its values and
/// those of the others.
fn check_formats(frames: &[Frame]) -> Result<(), SeriesError> {
    let mut files: Vec<(&Path, &PixelFormat)> = Vec::new();
    for f in frames {
        if !files.iter().any(|(p, _)| *p == f.file.as_path()) {
            files.push((&f.file, &f.format));
        }
    }
    let mut counts: Vec<(&PixelFormat, usize)> = Vec::new();
    for (_, format) in &files {
        match counts.iter_mut().find(|(c, _)| c == format) {
            Some((_, n)) => *n += 1,
            None => counts.push((format, 1)),
        }
    }
    if counts.len() < 2 {
        return Ok(());
    }
    // The most common format (the first seen on a tie) is taken as the series'.
    let (common, n) = counts
        .iter()
        .fold(counts[0], |best, &c| if c.1 > best.1 { c } else { best });
    let (odd, format) = files
        .iter()
        .find(|(_, f)| *f != common)
        .expect("two formats");
    let (mine, theirs) = format.differences(common);
    let others = if n == 1 {
        "another file has".to_string()
    } else {
        format!("{n} other files have")
    };
    Err(SeriesError::Format(format!(
        "{} has {mine}, but {others} {theirs}{}",
        odd.display(),
        if counts.len() > 2 {
            format!(" ({} different formats in the series)", counts.len())
        } else {
            String::new()
        }
    )))
}

/// Checks that `frames` (one series) form a regular grid and stacks them in order
/// along the slice normal. Returns the grid, voxels and warnings.
pub fn assemble(mut frames: Vec<Frame>) -> Result<(Grid, Vec<f32>, Vec<String>), SeriesError> {
    let mut warnings = Vec::new();
    let first = frames
        .first()
        .ok_or_else(|| SeriesError::Grid("no frames".into()))?
        .clone();
    let name = |f: &Frame| {
        if f.frame == 0 {
            f.file.display().to_string()
        } else {
            format!("{} frame {}", f.file.display(), f.frame)
        }
    };
    check_formats(&frames)?;
    // Orientation: every frame parallel to the first.
    let mut orientations: Vec<(&[f64; 6], String)> = Vec::new();
    for f in &frames {
        if !orientations.iter().any(|(o, _)| {
            o.iter()
                .zip(&f.orientation)
                .all(|(a, b)| (a - b).abs() < 1e-4)
        }) {
            orientations.push((&f.orientation, name(f)));
        }
    }
    if orientations.len() > 1 {
        let list: Vec<String> = orientations
            .iter()
            .take(4)
            .map(|(o, file)| format!("{} in {file}", fmt3(&o[..])))
            .collect();
        let more = if orientations.len() > 4 {
            format!(" and {} more", orientations.len() - 4)
        } else {
            String::new()
        };
        return Err(SeriesError::MixedOrientation(format!(
            "{} different ImageOrientationPatient values: {}{more}",
            orientations.len(),
            list.join("; ")
        )));
    }
    if let Some(f) = frames.iter().find(|f| {
        f.rows != first.rows
            || f.cols != first.cols
            || (0..2).any(|a| (f.pixel_spacing[a] - first.pixel_spacing[a]).abs() > 1e-4)
    }) {
        return Err(SeriesError::Grid(format!(
            "{} is {} x {} with pixel spacing {:?}, but {} is {} x {} with {:?}",
            name(f),
            f.rows,
            f.cols,
            f.pixel_spacing,
            name(&first),
            first.rows,
            first.cols,
            first.pixel_spacing
        )));
    }
    let row_dir = [
        first.orientation[0],
        first.orientation[1],
        first.orientation[2],
    ];
    let col_dir = [
        first.orientation[3],
        first.orientation[4],
        first.orientation[5],
    ];
    let normal = cross(row_dir, col_dir);
    let norm = dot(normal, normal).sqrt();
    if (norm - 1.0).abs() > 1e-3 || dot(row_dir, col_dir).abs() > 1e-3 {
        return Err(SeriesError::Grid(format!(
            "ImageOrientationPatient {} is not two orthogonal unit vectors",
            fmt3(&first.orientation)
        )));
    }
    let normal = normal.map(|x| x / norm);
    frames.sort_by(|a, b| dot(a.position, normal).total_cmp(&dot(b.position, normal)));
    let depths: Vec<f64> = frames.iter().map(|f| dot(f.position, normal)).collect();
    let n = frames.len();
    let slice_vector: [f64; 3] = if n == 1 {
        let t = first.slice_thickness.unwrap_or_else(|| {
            warnings.push("one slice and no SliceThickness: slice spacing set to 1 mm".into());
            1.0
        });
        normal.map(|x| x * t)
    } else {
        let gaps: Vec<f64> = depths.windows(2).map(|w| w[1] - w[0]).collect();
        let mut sorted = gaps.clone();
        sorted.sort_by(f64::total_cmp);
        // The lower median: a missing slice makes a gap larger, never smaller.
        let median = sorted[(sorted.len() - 1) / 2];
        if let Some(i) = gaps.iter().position(|&g| g < 1e-3) {
            return Err(SeriesError::Duplicate(format!(
                "{} and {} are two different images at the same position, {:.4} mm along the normal \
                 (two acquisitions or exports of one slice, or two series under one UID?)",
                name(&frames[i]),
                name(&frames[i + 1]),
                depths[i]
            )));
        }
        let tolerance = (0.01 * median).max(1e-3);
        let worst = gaps
            .iter()
            .enumerate()
            .max_by(|a, b| (a.1 - median).abs().total_cmp(&(b.1 - median).abs()))
            .filter(|(_, g)| (*g - median).abs() > tolerance);
        if let Some((i, gap)) = worst {
            // Every position and gap, for a short stack; a long one's list
            // would bury the gap.
            let listed = if n <= MAX_LISTED_SLICES {
                let positions: Vec<String> = depths.iter().map(|d| format!("{d:.3}")).collect();
                let gap_list: Vec<String> = gaps.iter().map(|g| format!("{g:.3}")).collect();
                format!(
                    "; positions {} mm, gaps {} mm",
                    positions.join(", "),
                    gap_list.join(", ")
                )
            } else {
                let odd = gaps
                    .iter()
                    .filter(|g| (*g - median).abs() > tolerance)
                    .count();
                format!("; {odd} of {} gaps differ", gaps.len())
            };
            return Err(SeriesError::Spacing(format!(
                "a gap of {gap:.3} mm between {} ({:.3} mm) and {} ({:.3} mm), where slices are {median:.3} mm apart \
                 (a missing slice, or a different series?){listed}",
                name(&frames[i]),
                depths[i],
                name(&frames[i + 1]),
                depths[i + 1],
            )));
        }
        let (p0, pn) = (frames[0].position, frames[n - 1].position);
        let step = [0, 1, 2].map(|a| (pn[a] - p0[a]) / (n - 1) as f64);
        // Every position must lie on the line from the first along `step`.
        for (k, f) in frames.iter().enumerate() {
            let expected = [0, 1, 2].map(|a| p0[a] + step[a] * k as f64);
            let off = (0..3)
                .map(|a| (f.position[a] - expected[a]).powi(2))
                .sum::<f64>()
                .sqrt();
            if off > 0.01 * median.max(first.pixel_spacing[0]) {
                return Err(SeriesError::Grid(format!(
                    "{} is {off:.3} mm off the line through the other slice positions (sheared or gantry-tilted stack)",
                    name(f)
                )));
            }
        }
        let shear = shear_deg(step, normal);
        if shear > MAX_UNNOTED_SHEAR_DEG {
            warnings.push(format!(
                "the stack is sheared by {shear:.3} deg (gantry tilt, or slices offset in-plane): \
                 its voxel grid is not orthogonal; NRRD keeps it exactly, and io.write_volume \
                 resamples it to an orthogonal grid for NIfTI (ITK reads no sheared NIfTI)"
            ));
        }
        if let Some(t) = first
            .slice_thickness
            .filter(|t| (t - median).abs() > 0.01 * median)
        {
            warnings.push(format!("slice spacing {median:.4} mm differs from SliceThickness {t:.4} mm (gaps or overlap)"));
        }
        step
    };
    let (ds_row, ds_col) = (first.pixel_spacing[0], first.pixel_spacing[1]);
    let mut m = [[0.0; 4]; 4];
    for r in 0..3 {
        m[r][0] = row_dir[r] * ds_col;
        m[r][1] = col_dir[r] * ds_row;
        m[r][2] = slice_vector[r];
        m[r][3] = frames[0].position[r];
    }
    m[3][3] = 1.0;
    let grid = Grid {
        dims: [first.cols, first.rows, n],
        voxel_to_patient: m,
    };
    let mut voxels = Vec::with_capacity(first.cols * first.rows * n);
    for f in &frames {
        voxels.extend_from_slice(&f.pixels);
    }
    Ok((grid, voxels, warnings))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(z: f64, orientation: [f64; 6]) -> Frame {
        Frame {
            file: PathBuf::from(format!("slice_{z}.dcm")),
            frame: 0,
            series_uid: "1.2.3".into(),
            series_description: String::new(),
            rows: 2,
            cols: 3,
            position: [10.0, 20.0, z],
            orientation,
            pixel_spacing: [0.5, 0.25],
            slice_thickness: Some(2.0),
            format: format(16),
            pixels: vec![z as f32; 6],
            has_overlay: false,
        }
    }

    fn format(bits: u16) -> PixelFormat {
        PixelFormat {
            rows: 2,
            cols: 3,
            samples_per_pixel: 1,
            bits_allocated: bits,
            bits_stored: bits,
            pixel_representation: 0,
            photometric: "MONOCHROME2".into(),
        }
    }

    #[test]
    fn a_slice_in_another_pixel_format_is_named() {
        let mut frames: Vec<Frame> = (0..4).map(|k| frame(2.0 * k as f64, AXIAL)).collect();
        frames[2].format = format(8);
        let err = assemble(frames).unwrap_err();
        assert!(matches!(err, SeriesError::Format(_)), "{err}");
        assert_eq!(
            err.to_string(),
            "slices differ in pixel format: slice_4.dcm has BitsAllocated 8, BitsStored 8, \
             but 3 other files have BitsAllocated 16, BitsStored 16"
        );
    }

    const AXIAL: [f64; 6] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0];

    #[test]
    fn slices_are_ordered_by_position_along_the_normal() {
        let frames = vec![frame(4.0, AXIAL), frame(0.0, AXIAL), frame(2.0, AXIAL)];
        let (grid, voxels, warnings) = assemble(frames).unwrap();
        assert_eq!(grid.dims, [3, 2, 3]);
        assert_eq!(grid.spacing_mm(), [0.25, 0.5, 2.0]);
        assert_eq!(grid.to_patient([2.0, 1.0, 2.0]), [10.5, 20.5, 4.0]);
        assert_eq!(voxels[0], 0.0);
        assert_eq!(voxels[6 * 2], 4.0);
        assert!(warnings.is_empty());
    }

    #[test]
    fn a_reversed_normal_still_gives_a_right_handed_stack() {
        // Row direction -x: the normal points to -z; slices still go along it.
        let flipped = [-1.0, 0.0, 0.0, 0.0, 1.0, 0.0];
        let (grid, _, _) = assemble(vec![frame(0.0, flipped), frame(2.0, flipped)]).unwrap();
        // The normal is -z, so the first slice along it is the one at z = 2.
        assert_eq!(grid.to_patient([0.0, 0.0, 0.0])[2], 2.0);
        assert_eq!(grid.to_patient([0.0, 0.0, 1.0])[2], 0.0);
    }

    #[test]
    fn gaps_repeats_and_mixed_orientations_are_errors() {
        let err = assemble(vec![
            frame(0.0, AXIAL),
            frame(2.0, AXIAL),
            frame(6.0, AXIAL),
        ])
        .unwrap_err();
        assert!(
            matches!(err, SeriesError::Spacing(_))
                && err.to_string().contains("gaps 2.000, 4.000")
                && err
                    .to_string()
                    .contains("between slice_2.dcm (2.000 mm) and slice_6.dcm"),
            "{err}"
        );
        let err = assemble(vec![frame(0.0, AXIAL), frame(0.0, AXIAL)]).unwrap_err();
        assert!(matches!(err, SeriesError::Duplicate(_)), "{err}");
        assert!(err.to_string().contains("same position"), "{err}");
        let tilted = [1.0, 0.0, 0.0, 0.0, 0.8, 0.6];
        let err = assemble(vec![frame(0.0, AXIAL), frame(2.0, tilted)]).unwrap_err();
        assert!(matches!(err, SeriesError::MixedOrientation(_)), "{err}");
        assert!(err.to_string().contains("slice_2.dcm"), "{err}");
    }

    #[test]
    fn a_sheared_stack_loads_with_its_shear_noted() {
        // Each slice 2 mm above the last and 1 mm to the side: 26.565 deg.
        let frames: Vec<Frame> = (0..4)
            .map(|k| {
                let mut f = frame(2.0 * k as f64, AXIAL);
                f.position[0] += k as f64;
                f
            })
            .collect();
        let (grid, _, warnings) = assemble(frames).unwrap();
        assert_eq!(grid.to_patient([0.0, 0.0, 3.0]), [13.0, 20.0, 6.0]);
        assert_eq!(warnings.len(), 1, "{warnings:?}");
        assert!(
            warnings[0].contains("sheared by 26.565 deg"),
            "{warnings:?}"
        );
        let straight: Vec<Frame> = (0..4).map(|k| frame(2.0 * k as f64, AXIAL)).collect();
        assert!(assemble(straight).unwrap().2.is_empty());
    }

    #[test]
    fn a_single_slice_takes_its_thickness() {
        let (grid, _, _) = assemble(vec![frame(5.0, AXIAL)]).unwrap();
        assert_eq!(grid.dims[2], 1);
        assert_eq!(grid.spacing_mm()[2], 2.0);
    }
}
