//! A plugin op's inputs and parameters, read safely from the host's borrowed
//! arrays: every access checks the value type, dtype, shape and length
//! before handing out a slice.

use crate::abi::{FgArray, FgInput, FgParam, dtype, param_kind, value_type};

/// Pixels of an [`ImageView`], borrowed from the host.
#[derive(Debug, Clone, Copy)]
pub enum PixelsView<'a> {
    /// 8-bit samples.
    U8(&'a [u8]),
    /// Float samples (usually 0..=1).
    F32(&'a [f32]),
}

/// An image, row-major, channels interleaved.
#[derive(Debug, Clone, Copy)]
pub struct ImageView<'a> {
    /// Width, px.
    pub width: usize,
    /// Height, px.
    pub height: usize,
    /// 1 (grey) or 3 (RGB).
    pub channels: usize,
    /// `width * height * channels` samples.
    pub pixels: PixelsView<'a>,
}

/// A table: `rows x columns.len()` numbers, row-major.
#[derive(Debug, Clone)]
pub struct TableView<'a> {
    /// Column names.
    pub columns: Vec<&'a str>,
    /// The numbers.
    pub data: &'a [f64],
}

/// The values on the op's connected input ports.
#[derive(Debug, Clone, Copy)]
pub struct Inputs<'a> {
    raw: &'a [FgInput],
}

/// The elements of `a` as `T`, checked against its dtype and length.
///
/// # Safety
/// `a.data` must point to `a.byte_len` readable bytes outliving `'a`.
unsafe fn elements<'a, T>(a: &FgArray, want_dtype: u32) -> Result<&'a [T], String> {
    if a.dtype != want_dtype {
        return Err(format!("dtype {} where {want_dtype} was expected", a.dtype));
    }
    let size = std::mem::size_of::<T>();
    let count: u64 = a.shape[..a.ndim.min(4) as usize].iter().product();
    let count = usize::try_from(count).map_err(|_| "shape too large".to_string())?;
    if count.checked_mul(size) != Some(a.byte_len) {
        return Err(format!(
            "{} bytes for {count} elements of {size} bytes",
            a.byte_len
        ));
    }
    if count == 0 {
        return Ok(&[]);
    }
    if a.data.is_null() || !(a.data as usize).is_multiple_of(std::mem::align_of::<T>()) {
        return Err("data pointer is null or misaligned".into());
    }
    // SAFETY: checked non-null, aligned, and `count * size == byte_len`; the
    // caller guarantees the bytes are readable for `'a`.
    Ok(unsafe { std::slice::from_raw_parts(a.data as *const T, count) })
}

impl<'a> Inputs<'a> {
    /// Views of the host's inputs.
    ///
    /// # Safety
    /// `raw` must be the host's inputs of this call (pointers valid for `'a`).
    pub unsafe fn new(raw: &'a [FgInput]) -> Inputs<'a> {
        Inputs { raw }
    }

    /// Whether a value is on `port`.
    pub fn is_connected(&self, port: &str) -> bool {
        self.find(port).is_some()
    }

    fn find(&self, port: &str) -> Option<&'a FgArray> {
        self.raw
            .iter()
            // SAFETY: port names are the host's, valid for the call.
            .find(|i| unsafe { i.port.as_str() } == Some(port))
            .map(|i| &i.value)
    }

    fn typed(&self, port: &str, ty: u32) -> Result<Option<&'a FgArray>, String> {
        match self.find(port) {
            None => Ok(None),
            Some(a) if a.value_type == ty => Ok(Some(a)),
            Some(a) => Err(format!(
                "input `{port}` is a {}, expected {}",
                value_type::name(a.value_type).unwrap_or("value of an unknown type"),
                value_type::name(ty).unwrap_or("?")
            )),
        }
    }

    fn required<T>(&self, port: &str, v: Result<Option<T>, String>) -> Result<T, String> {
        v?.ok_or_else(|| format!("input `{port}` is not connected"))
    }

    /// The image on `port`, `None` when unconnected.
    pub fn optional_image(&self, port: &str) -> Result<Option<ImageView<'a>>, String> {
        let Some(a) = self.typed(port, value_type::IMAGE)? else {
            return Ok(None);
        };
        let bad = |why: String| format!("input `{port}`: {why}");
        if a.ndim != 3 || !(a.shape[2] == 1 || a.shape[2] == 3) {
            return Err(bad(format!(
                "image of shape {:?}",
                &a.shape[..a.ndim as usize]
            )));
        }
        // SAFETY: the host's array, valid for the call.
        let pixels = unsafe {
            match a.dtype {
                dtype::U8 => PixelsView::U8(elements(a, dtype::U8).map_err(bad)?),
                _ => PixelsView::F32(elements(a, dtype::F32).map_err(bad)?),
            }
        };
        Ok(Some(ImageView {
            height: a.shape[0] as usize,
            width: a.shape[1] as usize,
            channels: a.shape[2] as usize,
            pixels,
        }))
    }

    /// The image on a required `port`.
    pub fn image(&self, port: &str) -> Result<ImageView<'a>, String> {
        self.required(port, self.optional_image(port))
    }

    /// The number on `port`, `None` when unconnected.
    pub fn optional_scalar(&self, port: &str) -> Result<Option<f64>, String> {
        let Some(a) = self.typed(port, value_type::SCALAR)? else {
            return Ok(None);
        };
        // SAFETY: the host's array, valid for the call.
        let v: &[f64] =
            unsafe { elements(a, dtype::F64) }.map_err(|e| format!("input `{port}`: {e}"))?;
        v.first()
            .copied()
            .map(Some)
            .ok_or_else(|| format!("input `{port}`: an empty scalar"))
    }

    /// The number on a required `port`.
    pub fn scalar(&self, port: &str) -> Result<f64, String> {
        self.required(port, self.optional_scalar(port))
    }

    /// The disparity map on `port` as (width, height, px values).
    pub fn disparity(&self, port: &str) -> Result<(usize, usize, &'a [f32]), String> {
        let a = self.required(port, self.typed(port, value_type::DISPARITY))?;
        // SAFETY: the host's array, valid for the call.
        let d = unsafe { elements(a, dtype::F32) }.map_err(|e| format!("input `{port}`: {e}"))?;
        Ok((a.shape[1] as usize, a.shape[0] as usize, d))
    }

    /// The table on `port`.
    pub fn table(&self, port: &str) -> Result<TableView<'a>, String> {
        let a = self.required(port, self.typed(port, value_type::TABLE))?;
        // SAFETY: the host's array and labels, valid for the call.
        let (data, labels) = unsafe { (elements(a, dtype::F64), a.labels.as_str()) };
        let data = data.map_err(|e| format!("input `{port}`: {e}"))?;
        let labels = labels.ok_or_else(|| format!("input `{port}`: column names not UTF-8"))?;
        Ok(TableView {
            columns: if labels.is_empty() {
                Vec::new()
            } else {
                labels.split('\n').collect()
            },
            data,
        })
    }
}

/// The op's parameters (every declared one: the graph's value or the default).
#[derive(Debug, Clone, Copy)]
pub struct Params<'a> {
    raw: &'a [FgParam],
}

impl<'a> Params<'a> {
    /// Views of the host's parameters.
    ///
    /// # Safety
    /// `raw` must be the host's parameters of this call.
    pub unsafe fn new(raw: &'a [FgParam]) -> Params<'a> {
        Params { raw }
    }

    /// The [`param_kind`] code of parameter `name`, `None` when not passed.
    pub fn kind(&self, name: &str) -> Option<u32> {
        self.raw
            .iter()
            // SAFETY: the host's names, valid for the call.
            .find(|p| unsafe { p.name.as_str() } == Some(name))
            .map(|p| p.kind)
    }

    fn find(&self, name: &str, kind: u32) -> Result<&'a FgParam, String> {
        let p = self
            .raw
            .iter()
            // SAFETY: the host's names, valid for the call.
            .find(|p| unsafe { p.name.as_str() } == Some(name))
            .ok_or_else(|| format!("parameter `{name}` was not passed (is it declared?)"))?;
        if p.kind != kind {
            return Err(format!(
                "parameter `{name}` is of kind {}, read as {kind}",
                p.kind
            ));
        }
        Ok(p)
    }

    /// An `int` parameter.
    pub fn int(&self, name: &str) -> Result<i64, String> {
        Ok(self.find(name, param_kind::INT)?.int)
    }

    /// A `float` parameter.
    pub fn float(&self, name: &str) -> Result<f64, String> {
        Ok(self.find(name, param_kind::FLOAT)?.float)
    }

    /// A `bool` parameter.
    pub fn bool(&self, name: &str) -> Result<bool, String> {
        Ok(self.find(name, param_kind::BOOL)?.int != 0)
    }

    /// A `string` (or choice) parameter.
    pub fn string(&self, name: &str) -> Result<&'a str, String> {
        let p = self.find(name, param_kind::STRING)?;
        // SAFETY: the host's text, valid for the call.
        unsafe { p.text.as_str() }.ok_or_else(|| format!("parameter `{name}` is not UTF-8"))
    }

    fn list<T>(
        &self,
        name: &str,
        kind: u32,
        ptr: impl Fn(&FgParam) -> *const T,
    ) -> Result<&'a [T], String> {
        let p = self.find(name, kind)?;
        if p.len == 0 {
            return Ok(&[]);
        }
        let ptr = ptr(p);
        if ptr.is_null() || !(ptr as usize).is_multiple_of(std::mem::align_of::<T>()) {
            return Err(format!("parameter `{name}`: null or misaligned list"));
        }
        // SAFETY: the host passes `len` values at a valid, aligned pointer.
        Ok(unsafe { std::slice::from_raw_parts(ptr, p.len) })
    }

    /// An `int_list` parameter.
    pub fn int_list(&self, name: &str) -> Result<&'a [i64], String> {
        self.list(name, param_kind::INT_LIST, |p| p.ints)
    }

    /// A `float_list` parameter.
    pub fn float_list(&self, name: &str) -> Result<&'a [f64], String> {
        self.list(name, param_kind::FLOAT_LIST, |p| p.floats)
    }
}
