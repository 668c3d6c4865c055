//! What a plugin op returns: [`Outputs`] collects values, metrics and notes
//! in Rust types; [`into_result`] hands them to the host as an
//! [`FgResult`] whose memory the plugin keeps until the host frees it.

use crate::abi::{FgArray, FgMetric, FgOutput, FgResult, FgStr, dtype, value_type};

/// An owned element buffer.
#[derive(Debug, Clone, PartialEq)]
enum Buffer {
    U8(Vec<u8>),
    U32(Vec<u32>),
    F32(Vec<f32>),
    F64(Vec<f64>),
}

impl Buffer {
    fn raw(&self) -> (u32, *const u8, usize) {
        match self {
            Buffer::U8(v) => (dtype::U8, v.as_ptr(), v.len()),
            Buffer::U32(v) => (dtype::U32, v.as_ptr() as *const u8, v.len() * 4),
            Buffer::F32(v) => (dtype::F32, v.as_ptr() as *const u8, v.len() * 4),
            Buffer::F64(v) => (dtype::F64, v.as_ptr() as *const u8, v.len() * 8),
        }
    }
}

/// An owned value on its way to the host.
#[derive(Debug, Clone, PartialEq)]
struct OwnedValue {
    value_type: u32,
    shape: Vec<u64>,
    data: Buffer,
    affine: [f64; 16],
    labels: String,
}

/// The values, metrics and notes of one run of an op.
#[derive(Debug, Default)]
pub struct Outputs {
    values: Vec<(String, OwnedValue)>,
    metrics: Vec<(String, f64)>,
    notes: Vec<String>,
}

impl Outputs {
    fn push(&mut self, port: &str, value: OwnedValue) {
        self.values.retain(|(p, _)| p != port);
        self.values.push((port.into(), value));
    }

    fn plain(value_type: u32, shape: Vec<u64>, data: Buffer) -> OwnedValue {
        OwnedValue {
            value_type,
            shape,
            data,
            affine: [0.0; 16],
            labels: String::new(),
        }
    }

    /// A disparity map on `port`: `width * height` px values, NaN = no match.
    pub fn disparity(&mut self, port: &str, width: usize, height: usize, data: Vec<f32>) {
        let shape = vec![height as u64, width as u64];
        self.push(
            port,
            Self::plain(value_type::DISPARITY, shape, Buffer::F32(data)),
        );
    }

    /// An 8-bit image on `port`: `width * height * channels` samples.
    pub fn image_u8(
        &mut self,
        port: &str,
        width: usize,
        height: usize,
        channels: usize,
        data: Vec<u8>,
    ) {
        let shape = vec![height as u64, width as u64, channels as u64];
        self.push(
            port,
            Self::plain(value_type::IMAGE, shape, Buffer::U8(data)),
        );
    }

    /// A float image on `port`.
    pub fn image_f32(
        &mut self,
        port: &str,
        width: usize,
        height: usize,
        channels: usize,
        data: Vec<f32>,
    ) {
        let shape = vec![height as u64, width as u64, channels as u64];
        self.push(
            port,
            Self::plain(value_type::IMAGE, shape, Buffer::F32(data)),
        );
    }

    /// A number on `port`.
    pub fn scalar(&mut self, port: &str, value: f64) {
        self.push(
            port,
            Self::plain(value_type::SCALAR, vec![], Buffer::F64(vec![value])),
        );
    }

    /// A table on `port`: `data.len() / columns.len()` rows.
    pub fn table(&mut self, port: &str, columns: &[&str], data: Vec<f64>) {
        let rows = if columns.is_empty() {
            0
        } else {
            data.len() / columns.len()
        };
        let mut v = Self::plain(
            value_type::TABLE,
            vec![rows as u64, columns.len() as u64],
            Buffer::F64(data),
        );
        v.labels = columns.join("\n");
        self.push(port, v);
    }

    fn grid(
        &mut self,
        port: &str,
        value_type: u32,
        dims: [usize; 3],
        affine: [f64; 16],
        data: Buffer,
    ) {
        let shape = vec![dims[2] as u64, dims[1] as u64, dims[0] as u64];
        let mut v = Self::plain(value_type, shape, data);
        v.affine = affine;
        self.push(port, v);
    }

    /// Voxels on `port`: `dims = [nx, ny, nz]`, x fastest, with the row-major
    /// voxel -> patient (LPS, mm) matrix.
    pub fn volume(&mut self, port: &str, dims: [usize; 3], affine: [f64; 16], data: Vec<f32>) {
        self.grid(port, value_type::VOLUME, dims, affine, Buffer::F32(data));
    }

    /// A mask (0/1) on `port`, as [`Outputs::volume`].
    pub fn mask(&mut self, port: &str, dims: [usize; 3], affine: [f64; 16], data: Vec<u8>) {
        self.grid(port, value_type::MASK, dims, affine, Buffer::U8(data));
    }

    /// Labels on `port`, as [`Outputs::volume`].
    pub fn labels(&mut self, port: &str, dims: [usize; 3], affine: [f64; 16], data: Vec<u32>) {
        self.grid(port, value_type::LABELS, dims, affine, Buffer::U32(data));
    }

    /// A metric (unit in the name: `coverage_pct`).
    pub fn metric(&mut self, name: &str, value: f64) {
        self.metrics.retain(|(n, _)| n != name);
        self.metrics.push((name.into(), value));
    }

    /// A note for the user: an input refused or repaired, and why.
    pub fn note(&mut self, text: impl Into<String>) {
        self.notes.push(text.into());
    }
}

/// The memory behind an [`FgResult`]'s pointers.
struct Owned {
    message: String,
    outputs: Outputs,
    raw_outputs: Vec<FgOutput>,
    raw_metrics: Vec<FgMetric>,
    raw_notes: Vec<FgStr>,
}

/// Fills `result` with `status`, `message` and (on success) `outputs`; the
/// memory is released by [`free_result`].
pub fn into_result(status: u32, message: String, outputs: Outputs, result: &mut FgResult) {
    let mut owned = Box::new(Owned {
        message,
        outputs,
        raw_outputs: Vec::new(),
        raw_metrics: Vec::new(),
        raw_notes: Vec::new(),
    });
    let o = &mut *owned;
    for (port, v) in &o.outputs.values {
        let (dt, data, byte_len) = v.data.raw();
        let mut shape = [0u64; 4];
        shape[..v.shape.len()].copy_from_slice(&v.shape);
        o.raw_outputs.push(FgOutput {
            port: FgStr::new(port),
            value: FgArray {
                value_type: v.value_type,
                dtype: dt,
                ndim: v.shape.len() as u32,
                shape,
                data,
                byte_len,
                affine: v.affine,
                labels: FgStr::new(&v.labels),
            },
        });
    }
    o.raw_metrics = o
        .outputs
        .metrics
        .iter()
        .map(|(n, v)| FgMetric {
            name: FgStr::new(n),
            value: *v,
        })
        .collect();
    o.raw_notes = o.outputs.notes.iter().map(|n| FgStr::new(n)).collect();
    *result = FgResult {
        status,
        message: FgStr::new(&o.message),
        outputs: o.raw_outputs.as_ptr(),
        n_outputs: o.raw_outputs.len(),
        metrics: o.raw_metrics.as_ptr(),
        n_metrics: o.raw_metrics.len(),
        notes: o.raw_notes.as_ptr(),
        n_notes: o.raw_notes.len(),
        owner: Box::into_raw(owned) as *mut std::ffi::c_void,
    };
}

/// Releases what [`into_result`] put in `result`, and empties it.
///
/// # Safety
/// `result` must have been filled by [`into_result`] and not freed since.
pub unsafe fn free_result(result: &mut FgResult) {
    if !result.owner.is_null() {
        // SAFETY: `owner` came from `Box::into_raw` in `into_result`.
        drop(unsafe { Box::from_raw(result.owner as *mut Owned) });
    }
    *result = FgResult::empty();
}
