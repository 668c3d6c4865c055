//! Volume files: a volume or mask with its geometry as NRRD (`.nrrd`) or
//! NIfTI-1 (`.nii`, `.nii.gz`), for 3D Slicer, ITK-SNAP, SimpleITK, nibabel
//! (what `io.write_volume` writes).
//!
//! Both carry the full voxel -> patient affine. NRRD keeps our frame (DICOM LPS,
//! mm, `space: left-posterior-superior`) and writes numbers in full precision.
//! NIfTI is RAS by definition: the affine is converted LPS -> RAS (x and y
//! negated) and stored as float32 in both the sform and (for orthogonal axes)
//! the qform, with millimetre units; float32 limits it to about 1e-7 relative
//! (4e-6 mm at 100 mm from the origin).
//!
//! The small readers here read back what the writers write (and plain files of
//! other tools in the same layouts); they are used by the tests.

use fusegraph_engine::value::Grid;
use std::io::{Read, Write};
use std::path::Path;

/// Voxel values to write, in [`Grid::index`] order.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Voxels<'a> {
    /// Intensities (a [`Volume`](fusegraph_engine::value::Volume)), written as float32.
    F32(&'a [f32]),
    /// Mask values 0/1 (a [`Mask`](fusegraph_engine::value::Mask)), written as uint8.
    U8(&'a [u8]),
}

impl Voxels<'_> {
    fn len(&self) -> usize {
        match self {
            Voxels::F32(v) => v.len(),
            Voxels::U8(v) => v.len(),
        }
    }

    /// Little-endian bytes.
    fn to_le_bytes(self) -> Vec<u8> {
        match self {
            Voxels::F32(v) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
            Voxels::U8(v) => v.to_vec(),
        }
    }
}

/// Voxel values read back.
#[derive(Debug, Clone, PartialEq)]
pub enum VoxelBuf {
    /// float32 samples.
    F32(Vec<f32>),
    /// uint8 samples.
    U8(Vec<u8>),
}

impl VoxelBuf {
    fn from_le_bytes(bytes: &[u8], float: bool, count: usize) -> Result<Self, String> {
        let size = if float { 4 } else { 1 };
        if bytes.len() < count * size {
            return Err(format!(
                "{} bytes of voxel data, expected {} ({count} voxels of {size} bytes; truncated?)",
                bytes.len(),
                count * size
            ));
        }
        let bytes = &bytes[..count * size];
        Ok(if float {
            VoxelBuf::F32(
                bytes
                    .chunks_exact(4)
                    .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                    .collect(),
            )
        } else {
            VoxelBuf::U8(bytes.to_vec())
        })
    }
}

fn check_len(grid: &Grid, voxels: Voxels<'_>) -> std::io::Result<()> {
    if voxels.len() != grid.len() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!(
                "{} voxel values for a {:?} grid of {}",
                voxels.len(),
                grid.dims,
                grid.len()
            ),
        ));
    }
    Ok(())
}

fn gzip(bytes: &[u8]) -> std::io::Result<Vec<u8>> {
    // Level 1: float volumes hardly compress better at higher levels, and the
    // full phantom (20 MB) then takes a fraction of a second.
    let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    enc.write_all(bytes)?;
    enc.finish()
}

fn gunzip(bytes: &[u8]) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    flate2::read::MultiGzDecoder::new(bytes)
        .read_to_end(&mut out)
        .map_err(|e| format!("gzip data: {e}"))?;
    Ok(out)
}

/// Writes `voxels` on `grid` as a NRRD file (attached header): type float or
/// uint8, little-endian, `space: left-posterior-superior`, `space directions`
/// (the affine's columns, mm per voxel step along i, j, k), `space origin` (LPS
/// mm of voxel (0, 0, 0)), `space units` mm; `gzip_data` compresses the data.
/// [`read_nrrd`] reads it back.
///
/// # Examples
///
/// ```
/// use fusegraph_engine::value::Grid;
/// use fusegraph_nodes::io::{VoxelBuf, Voxels, read_nrrd, write_nrrd};
///
/// // 2 x 2 x 1 voxels of 0.5 x 0.5 x 2 mm, voxel (0, 0, 0) at LPS (10, -20, 30) mm.
/// let grid = Grid::axis_aligned([2, 2, 1], [0.5, 0.5, 2.0], [10.0, -20.0, 30.0]);
/// let folder = tempfile::tempdir().unwrap();
/// let path = folder.path().join("v.nrrd");
/// write_nrrd(&path, &grid, Voxels::F32(&[0.0, 1.5, -2.0, 4.25]), true).unwrap();
/// let (back, voxels) = read_nrrd(&path).unwrap();
/// assert_eq!(back, grid);
/// assert_eq!(voxels, VoxelBuf::F32(vec![0.0, 1.5, -2.0, 4.25]));
/// ```
pub fn write_nrrd(
    path: &Path,
    grid: &Grid,
    voxels: Voxels<'_>,
    gzip_data: bool,
) -> std::io::Result<()> {
    check_len(grid, voxels)?;
    let m = &grid.voxel_to_patient;
    let vector = |c: usize| format!("({},{},{})", m[0][c], m[1][c], m[2][c]);
    let (kind, endian) = match voxels {
        Voxels::F32(_) => ("float", "endian: little\n"),
        Voxels::U8(_) => ("uint8", ""),
    };
    let header = format!(
        "NRRD0004\n\
         # Complete NRRD file format specification at:\n\
         # http://teem.sourceforge.net/nrrd/format.html\n\
         # written by fusegraph: voxel (i, j, k) -> patient LPS mm\n\
         type: {kind}\n\
         dimension: 3\n\
         space: left-posterior-superior\n\
         sizes: {} {} {}\n\
         space directions: {} {} {}\n\
         kinds: domain domain domain\n\
         {endian}\
         encoding: {}\n\
         space origin: ({},{},{})\n\
         space units: \"mm\" \"mm\" \"mm\"\n\n",
        grid.dims[0],
        grid.dims[1],
        grid.dims[2],
        vector(0),
        vector(1),
        vector(2),
        if gzip_data { "gzip" } else { "raw" },
        m[0][3],
        m[1][3],
        m[2][3],
    );
    let data = voxels.to_le_bytes();
    let data = if gzip_data { gzip(&data)? } else { data };
    let mut w = std::io::BufWriter::new(std::fs::File::create(path)?);
    w.write_all(header.as_bytes())?;
    w.write_all(&data)?;
    w.flush()
}

fn parse_vector(text: &str) -> Option<[f64; 3]> {
    let inner = text.trim().strip_prefix('(')?.strip_suffix(')')?;
    let v: Vec<f64> = inner
        .split(',')
        .map(|x| x.trim().parse().ok())
        .collect::<Option<_>>()?;
    (v.len() == 3).then(|| [v[0], v[1], v[2]])
}

/// Reads a 3D NRRD file with an attached header in LPS space (as
/// [`write_nrrd`] writes it: float or uint8, raw or gzip, little-endian).
pub fn read_nrrd(path: &Path) -> Result<(Grid, VoxelBuf), String> {
    let fail = |msg: String| format!("{}: {msg}", path.display());
    let bytes = std::fs::read(path).map_err(|e| fail(e.to_string()))?;
    let end = bytes
        .windows(2)
        .position(|w| w == b"\n\n")
        .ok_or_else(|| fail("no end of header (blank line)".into()))?;
    let header = std::str::from_utf8(&bytes[..end]).map_err(|e| fail(e.to_string()))?;
    if !header.starts_with("NRRD") {
        return Err(fail("not a NRRD file".into()));
    }
    let mut fields = std::collections::BTreeMap::new();
    for line in header.lines().skip(1).filter(|l| !l.starts_with('#')) {
        if let Some((k, v)) = line.split_once(": ") {
            fields.insert(k.trim().to_string(), v.trim().to_string());
        }
    }
    let field = |k: &str| {
        fields
            .get(k)
            .map(String::as_str)
            .ok_or_else(|| fail(format!("no `{k}` field")))
    };
    if field("dimension")? != "3" {
        return Err(fail(format!(
            "dimension {}, expected 3",
            field("dimension")?
        )));
    }
    if field("space")? != "left-posterior-superior" {
        return Err(fail(format!(
            "space {}, expected left-posterior-superior",
            field("space")?
        )));
    }
    let float = match field("type")? {
        "float" => true,
        "uint8" | "uchar" | "unsigned char" => false,
        t => return Err(fail(format!("type {t} is not read here (float, uint8)"))),
    };
    if float && fields.get("endian").is_some_and(|e| e != "little") {
        return Err(fail("big-endian data is not read here".into()));
    }
    let sizes: Vec<usize> = field("sizes")?
        .split_whitespace()
        .map(|s| s.parse().map_err(|_| fail(format!("bad size {s:?}"))))
        .collect::<Result<_, _>>()?;
    let dirs_text = field("space directions")?;
    let dirs: Vec<[f64; 3]> = dirs_text
        .split(')')
        .filter(|s| !s.trim().is_empty())
        .map(|s| parse_vector(&format!("{})", s.trim())))
        .collect::<Option<_>>()
        .ok_or_else(|| fail(format!("bad space directions {dirs_text:?}")))?;
    let origin =
        parse_vector(field("space origin")?).ok_or_else(|| fail("bad space origin".into()))?;
    if sizes.len() != 3 || dirs.len() != 3 {
        return Err(fail("expected 3 sizes and 3 space directions".into()));
    }
    let mut m = [[0.0; 4]; 4];
    for r in 0..3 {
        for c in 0..3 {
            m[r][c] = dirs[c][r];
        }
        m[r][3] = origin[r];
    }
    m[3][3] = 1.0;
    let grid = Grid {
        dims: [sizes[0], sizes[1], sizes[2]],
        voxel_to_patient: m,
    };
    let data = &bytes[end + 2..];
    let data = match field("encoding")? {
        "raw" => data.to_vec(),
        "gzip" | "gz" => gunzip(data).map_err(fail)?,
        e => return Err(fail(format!("encoding {e} is not read here (raw, gzip)"))),
    };
    let voxels = VoxelBuf::from_le_bytes(&data, float, grid.len()).map_err(fail)?;
    Ok((grid, voxels))
}

/// The affine in NIfTI's RAS frame from ours in LPS (x and y negated), or back.
pub fn lps_to_ras(m: &[[f64; 4]; 4]) -> [[f64; 4]; 4] {
    let mut out = *m;
    for row in out.iter_mut().take(2) {
        for x in row.iter_mut() {
            *x = -*x;
        }
    }
    out
}

/// NIfTI's quaternion (b, c, d) and qfac for the rotation part of `m` (RAS), as
/// nifti1_io's `nifti_mat44_to_quatern` computes it; `None` when the axes are
/// not orthogonal (then only the sform is written).
fn quaternion(m: &[[f64; 4]; 4], spacing: [f64; 3]) -> Option<([f64; 3], f64)> {
    let mut r = [[0.0; 3]; 3];
    for row in 0..3 {
        for col in 0..3 {
            r[row][col] = m[row][col] / spacing[col];
        }
    }
    let dot = |a: usize, b: usize| (0..3).map(|i| r[i][a] * r[i][b]).sum::<f64>();
    if dot(0, 1).abs() > 1e-5 || dot(0, 2).abs() > 1e-5 || dot(1, 2).abs() > 1e-5 {
        return None;
    }
    let det = r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1])
        - r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0])
        + r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0]);
    let qfac = if det < 0.0 {
        for row in &mut r {
            row[2] = -row[2];
        }
        -1.0
    } else {
        1.0
    };
    let (a, b, c, d);
    let trace = r[0][0] + r[1][1] + r[2][2] + 1.0;
    if trace > 0.5 {
        a = 0.5 * trace.sqrt();
        b = 0.25 * (r[2][1] - r[1][2]) / a;
        c = 0.25 * (r[0][2] - r[2][0]) / a;
        d = 0.25 * (r[1][0] - r[0][1]) / a;
    } else {
        let xd = 1.0 + r[0][0] - (r[1][1] + r[2][2]);
        let yd = 1.0 + r[1][1] - (r[0][0] + r[2][2]);
        let zd = 1.0 + r[2][2] - (r[0][0] + r[1][1]);
        if xd > 1.0 {
            b = 0.5 * xd.sqrt();
            c = 0.25 * (r[0][1] + r[1][0]) / b;
            d = 0.25 * (r[0][2] + r[2][0]) / b;
            a = 0.25 * (r[2][1] - r[1][2]) / b;
        } else if yd > 1.0 {
            c = 0.5 * yd.sqrt();
            b = 0.25 * (r[0][1] + r[1][0]) / c;
            d = 0.25 * (r[1][2] + r[2][1]) / c;
            a = 0.25 * (r[0][2] - r[2][0]) / c;
        } else {
            d = 0.5 * zd.sqrt();
            b = 0.25 * (r[0][2] + r[2][0]) / d;
            c = 0.25 * (r[1][2] + r[2][1]) / d;
            a = 0.25 * (r[1][0] - r[0][1]) / d;
        }
    }
    let s = if a < 0.0 { -1.0 } else { 1.0 };
    Some(([s * b, s * c, s * d], qfac))
}

/// The affine (RAS) of a NIfTI qform: quaternion (b, c, d), qfac, voxel sizes
/// and offset, as nifti1_io's `nifti_quatern_to_mat44`.
fn qform_affine(q: [f64; 3], qfac: f64, pixdim: [f64; 3], offset: [f64; 3]) -> [[f64; 4]; 4] {
    let [b, c, d] = q;
    let a = (1.0 - (b * b + c * c + d * d)).max(0.0).sqrt();
    let r = [
        [
            a * a + b * b - c * c - d * d,
            2.0 * (b * c - a * d),
            2.0 * (b * d + a * c),
        ],
        [
            2.0 * (b * c + a * d),
            a * a + c * c - b * b - d * d,
            2.0 * (c * d - a * b),
        ],
        [
            2.0 * (b * d - a * c),
            2.0 * (c * d + a * b),
            a * a + d * d - c * c - b * b,
        ],
    ];
    let scale = [pixdim[0], pixdim[1], pixdim[2] * qfac];
    let mut m = [[0.0; 4]; 4];
    for row in 0..3 {
        for col in 0..3 {
            m[row][col] = r[row][col] * scale[col];
        }
        m[row][3] = offset[row];
    }
    m[3][3] = 1.0;
    m
}

/// NIfTI-1 datatype codes.
const DT_UINT8: i16 = 2;
const DT_FLOAT32: i16 = 16;
/// NIFTI_XFORM_SCANNER_ANAT: coordinates of the scanner (here: the DICOM
/// patient frame, turned to RAS).
const XFORM_SCANNER_ANAT: i16 = 1;
/// NIFTI_UNITS_MM.
const UNITS_MM: u8 = 2;
/// Header (348 bytes) and an empty extension flag (4 bytes).
const VOX_OFFSET: usize = 352;

/// Writes `voxels` on `grid` as a single-file NIfTI-1 (`n+1`), gzipped when
/// `gzip_file` (the `.nii.gz` convention): datatype float32 or uint8, the
/// affine converted LPS -> RAS into the sform and, for orthogonal axes, the
/// qform (both code 1, scanner anatomical), pixdim the voxel sizes in mm,
/// xyzt_units mm.
pub fn write_nifti(
    path: &Path,
    grid: &Grid,
    voxels: Voxels<'_>,
    gzip_file: bool,
) -> std::io::Result<()> {
    check_len(grid, voxels)?;
    let too_big = grid.dims.iter().any(|&d| d > i16::MAX as usize);
    if too_big {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!(
                "grid {:?}: NIfTI-1 allows at most 32767 voxels per axis",
                grid.dims
            ),
        ));
    }
    let ras = lps_to_ras(&grid.voxel_to_patient);
    let spacing = grid.spacing_mm();
    let mut h = vec![0u8; VOX_OFFSET];
    let put_i16 =
        |h: &mut Vec<u8>, at: usize, v: i16| h[at..at + 2].copy_from_slice(&v.to_le_bytes());
    let put_i32 =
        |h: &mut Vec<u8>, at: usize, v: i32| h[at..at + 4].copy_from_slice(&v.to_le_bytes());
    let put_f32 = |h: &mut Vec<u8>, at: usize, v: f64| {
        h[at..at + 4].copy_from_slice(&(v as f32).to_le_bytes())
    };
    put_i32(&mut h, 0, 348);
    h[38] = b'r';
    let dims = [3, grid.dims[0], grid.dims[1], grid.dims[2], 1, 1, 1, 1];
    for (n, &d) in dims.iter().enumerate() {
        put_i16(&mut h, 40 + 2 * n, d as i16);
    }
    let (datatype, bitpix) = match voxels {
        Voxels::F32(_) => (DT_FLOAT32, 32),
        Voxels::U8(_) => (DT_UINT8, 8),
    };
    put_i16(&mut h, 70, datatype);
    put_i16(&mut h, 72, bitpix);
    let q = quaternion(&ras, spacing);
    put_f32(&mut h, 76, q.map_or(1.0, |(_, qfac)| qfac));
    for (a, &s) in spacing.iter().enumerate() {
        put_f32(&mut h, 80 + 4 * a, s);
    }
    put_f32(&mut h, 108, VOX_OFFSET as f64);
    put_f32(&mut h, 112, 1.0); // scl_slope: values as stored
    h[123] = UNITS_MM;
    let descrip = b"fusegraph: patient LPS mm turned to NIfTI RAS";
    h[148..148 + descrip.len()].copy_from_slice(descrip);
    if let Some((quat, _)) = q {
        put_i16(&mut h, 252, XFORM_SCANNER_ANAT);
        for a in 0..3 {
            put_f32(&mut h, 256 + 4 * a, quat[a]);
            put_f32(&mut h, 268 + 4 * a, ras[a][3]);
        }
    }
    put_i16(&mut h, 254, XFORM_SCANNER_ANAT);
    for (r, row) in ras.iter().take(3).enumerate() {
        for (c, &x) in row.iter().enumerate() {
            put_f32(&mut h, 280 + 16 * r + 4 * c, x);
        }
    }
    h[344..348].copy_from_slice(b"n+1\0");
    h.extend_from_slice(&voxels.to_le_bytes());
    let bytes = if gzip_file { gzip(&h)? } else { h };
    std::fs::write(path, bytes)
}

/// A NIfTI-1 file read back by [`read_nifti`].
#[derive(Debug, Clone, PartialEq)]
pub struct NiftiVolume {
    /// Geometry from the sform (or the qform when there is no sform),
    /// converted back to LPS.
    pub grid: Grid,
    /// The qform's affine, converted to LPS, when the file has one.
    pub qform_voxel_to_patient: Option<[[f64; 4]; 4]>,
    /// xyzt_units (2 = mm).
    pub xyzt_units: u8,
    /// The voxel values.
    pub voxels: VoxelBuf,
}

/// Reads a single-file NIfTI-1 (`.nii`, or gzipped `.nii.gz`), little-endian,
/// uint8 or float32, with an sform or a qform.
pub fn read_nifti(path: &Path) -> Result<NiftiVolume, String> {
    let fail = |msg: String| format!("{}: {msg}", path.display());
    let raw = std::fs::read(path).map_err(|e| fail(e.to_string()))?;
    let bytes = if raw.starts_with(&[0x1f, 0x8b]) {
        gunzip(&raw).map_err(fail)?
    } else {
        raw
    };
    if bytes.len() < 348 {
        return Err(fail(format!(
            "{} bytes, shorter than a NIfTI-1 header",
            bytes.len()
        )));
    }
    let i16_at = |at: usize| i16::from_le_bytes([bytes[at], bytes[at + 1]]);
    let i32_at = |at: usize| i32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"));
    let f32_at =
        |at: usize| f32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes")) as f64;
    if i32_at(0) != 348 {
        return Err(fail(
            "sizeof_hdr is not 348 (big-endian, or not NIfTI-1)".into(),
        ));
    }
    if &bytes[344..348] != b"n+1\0" {
        return Err(fail("magic is not \"n+1\" (a single-file NIfTI-1)".into()));
    }
    let ndim = i16_at(40);
    let size = |axis: usize| i16_at(40 + 2 * axis);
    if !(1..=7).contains(&ndim) || (4..=ndim as usize).any(|a| size(a) > 1) {
        return Err(fail(format!("{ndim} dimensions; a 3D volume is read here")));
    }
    let dims: [usize; 3] = std::array::from_fn(|a| {
        if a < ndim as usize {
            size(a + 1).max(1) as usize
        } else {
            1
        }
    });
    let float = match i16_at(70) {
        DT_FLOAT32 => true,
        DT_UINT8 => false,
        t => {
            return Err(fail(format!(
                "datatype {t} is not read here (2 uint8, 16 float32)"
            )));
        }
    };
    let vox_offset = f32_at(108) as usize;
    let pixdim: [f64; 3] = std::array::from_fn(|a| f32_at(80 + 4 * a));
    let qfac = if f32_at(76) < 0.0 { -1.0 } else { 1.0 };
    let qform = (i16_at(252) > 0).then(|| {
        lps_to_ras(&qform_affine(
            std::array::from_fn(|a| f32_at(256 + 4 * a)),
            qfac,
            pixdim,
            std::array::from_fn(|a| f32_at(268 + 4 * a)),
        ))
    });
    let affine = if i16_at(254) > 0 {
        let mut m = [[0.0; 4]; 4];
        for (r, row) in m.iter_mut().take(3).enumerate() {
            for (c, x) in row.iter_mut().enumerate() {
                *x = f32_at(280 + 16 * r + 4 * c);
            }
        }
        m[3][3] = 1.0;
        lps_to_ras(&m)
    } else {
        qform.ok_or_else(|| fail("neither an sform nor a qform".into()))?
    };
    let data = bytes
        .get(vox_offset..)
        .ok_or_else(|| fail(format!("vox_offset {vox_offset} is past the end")))?;
    let grid = Grid {
        dims,
        voxel_to_patient: affine,
    };
    let voxels = VoxelBuf::from_le_bytes(data, float, grid.len()).map_err(fail)?;
    Ok(NiftiVolume {
        grid,
        qform_voxel_to_patient: qform,
        xyzt_units: bytes[123],
        voxels,
    })
}

/// A volume file format.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum VolumeFormat {
    /// NRRD (`.nrrd`), see [`write_nrrd`].
    Nrrd,
    /// Single-file NIfTI-1 (`.nii`, or `.nii.gz` gzipped), see [`write_nifti`].
    Nifti {
        /// Whether the whole file is gzipped.
        gzip: bool,
    },
}

/// The format a file name's extension names (any case), `None` for others.
pub(crate) fn volume_format(file: &str) -> Option<VolumeFormat> {
    let lower = file.to_ascii_lowercase();
    if lower.ends_with(".nrrd") {
        Some(VolumeFormat::Nrrd)
    } else if lower.ends_with(".nii.gz") {
        Some(VolumeFormat::Nifti { gzip: true })
    } else if lower.ends_with(".nii") {
        Some(VolumeFormat::Nifti { gzip: false })
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An oblique grid with spacing 0.7 x 1.3 x 2.9 mm (rotated 30 deg about z,
    /// then 20 deg about x) and a far-off origin.
    fn oblique() -> Grid {
        let (a, b) = (30f64.to_radians(), 20f64.to_radians());
        let rz = [
            [a.cos(), -a.sin(), 0.0],
            [a.sin(), a.cos(), 0.0],
            [0.0, 0.0, 1.0],
        ];
        let rx = [
            [1.0, 0.0, 0.0],
            [0.0, b.cos(), -b.sin()],
            [0.0, b.sin(), b.cos()],
        ];
        let spacing = [0.7, 1.3, 2.9];
        let mut m = [[0.0; 4]; 4];
        for r in 0..3 {
            for c in 0..3 {
                let rot: f64 = (0..3).map(|k| rx[r][k] * rz[k][c]).sum();
                m[r][c] = rot * spacing[c];
            }
        }
        m[0][3] = -83.9063;
        m[1][3] = 112.25;
        m[2][3] = -40.125;
        m[3][3] = 1.0;
        Grid {
            dims: [5, 4, 3],
            voxel_to_patient: m,
        }
    }

    fn values(n: usize) -> Vec<f32> {
        (0..n).map(|i| i as f32 * 0.37 - 5.0).collect()
    }

    fn max_diff(a: &[[f64; 4]; 4], b: &[[f64; 4]; 4]) -> f64 {
        (0..4)
            .flat_map(|r| (0..4).map(move |c| (a[r][c] - b[r][c]).abs()))
            .fold(0.0, f64::max)
    }

    #[test]
    fn nrrd_keeps_the_affine_exactly_and_the_values() {
        let t = tempfile::tempdir().unwrap();
        let grid = oblique();
        let v = values(grid.len());
        for gzip in [false, true] {
            let path = t.path().join(format!("v{gzip}.nrrd"));
            write_nrrd(&path, &grid, Voxels::F32(&v), gzip).unwrap();
            let (back, data) = read_nrrd(&path).unwrap();
            assert_eq!(back.dims, grid.dims);
            let d = max_diff(&back.voxel_to_patient, &grid.voxel_to_patient);
            assert!(d < 1e-9, "affine off by {d} mm");
            assert_eq!(data, VoxelBuf::F32(v.clone()));
        }
        let text = std::fs::read(t.path().join("vfalse.nrrd")).unwrap();
        let end = text.windows(2).position(|w| w == b"\n\n").unwrap();
        let header = String::from_utf8_lossy(&text[..end]);
        assert!(
            header.contains("space: left-posterior-superior\n"),
            "{header}"
        );
        assert!(
            header.contains("space origin: (-83.9063,112.25,-40.125)"),
            "{header}"
        );
    }

    #[test]
    fn nifti_turns_lps_to_ras_with_sform_and_qform_in_mm() {
        let t = tempfile::tempdir().unwrap();
        let grid = oblique();
        let v = values(grid.len());
        for name in ["v.nii", "v.nii.gz"] {
            let path = t.path().join(name);
            write_nifti(&path, &grid, Voxels::F32(&v), name.ends_with(".gz")).unwrap();
            let back = read_nifti(&path).unwrap();
            assert_eq!(back.grid.dims, grid.dims);
            // float32 in the file: the sform is each number rounded to float32
            // (relative error <= 2^-24), the qform within 1e-6 mm of that.
            let (a, b) = (&back.grid.voxel_to_patient, &grid.voxel_to_patient);
            for r in 0..4 {
                for c in 0..4 {
                    let tol = b[r][c].abs() * 2f64.powi(-24);
                    assert!((a[r][c] - b[r][c]).abs() <= tol, "{name}: sform {a:?}");
                }
            }
            let d = max_diff(a, b);
            assert!(d < 4e-6, "{name}: sform off by {d} mm");
            let q = back.qform_voxel_to_patient.expect("a qform");
            let dq = max_diff(&q, a);
            assert!(dq < 1e-6, "{name}: qform off the sform by {dq} mm");
            assert_eq!(back.xyzt_units, 2);
            assert_eq!(back.voxels, VoxelBuf::F32(v.clone()));
        }
        // The file's own numbers are RAS: x and y negated.
        let raw = std::fs::read(t.path().join("v.nii")).unwrap();
        let srow_x3 = f32::from_le_bytes(raw[292..296].try_into().unwrap());
        assert_eq!(srow_x3, 83.9063);
        let bytes = std::fs::read(t.path().join("v.nii.gz")).unwrap();
        assert_eq!(&bytes[..2], &[0x1f, 0x8b], "gzipped");
    }

    #[test]
    fn qform_handles_a_left_handed_grid_and_half_turns() {
        // DICOM axial with rows along +x (L), columns along +y (P), slices
        // along -z: det < 0 in RAS, and a 180 deg rotation about z.
        for third in [-1.0, 1.0] {
            let mut m = [[0.0; 4]; 4];
            m[0][0] = 0.5;
            m[1][1] = 0.5;
            m[2][2] = 2.0 * third;
            m[3][3] = 1.0;
            let ras = lps_to_ras(&m);
            let (q, qfac) = quaternion(&ras, [0.5, 0.5, 2.0]).unwrap();
            let back = qform_affine(q, qfac, [0.5, 0.5, 2.0], [0.0; 3]);
            assert!(max_diff(&back, &ras) < 1e-12, "{back:?} vs {ras:?}");
        }
    }

    #[test]
    fn a_wrong_voxel_count_is_an_error_not_a_short_file() {
        let t = tempfile::tempdir().unwrap();
        let err = write_nrrd(
            &t.path().join("x.nrrd"),
            &oblique(),
            Voxels::U8(&[1, 2]),
            false,
        )
        .unwrap_err();
        assert!(err.to_string().contains("2 voxel values"), "{err}");
    }
}
