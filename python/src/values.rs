//! Engine values to and from Python, in the plain form the package's
//! `fusegraph._values` turns into its classes: a dict with a `type` key and
//! numpy arrays (a Volume is `{"type": "Volume", "array": (nz, ny, nx),
//! "affine": 4 x 4}`), an Image or a Disparity a bare array, a Scalar a
//! float, a Table a dict of columns, a Path a string.
//!
//! Out of the engine, every array is a read-only numpy view of the value's
//! own buffer, kept alive by it: no copy. Into the engine, arrays are copied
//! (the engine's values are immutable and may outlive the Python objects).

use fusegraph_engine::value::{
    Camera, Disparity, Grid, Image, Labels, Markers, Mask, Matches, Mesh, PathValue, Pixels,
    PointCloud, Rectification, StereoRig, Table, Transform, Volume,
};
use fusegraph_engine::{Value, ValueType};
use numpy::ndarray::{ArrayView, IxDyn};
use numpy::npyffi::flags::NPY_ARRAY_WRITEABLE;
use numpy::{Element, PyArray, PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use std::sync::Arc;

/// Keeps an engine buffer alive while numpy views of it exist.
#[pyclass(frozen, name = "BufferOwner", module = "fusegraph._native")]
struct Keep(#[allow(dead_code)] Box<dyn std::any::Any + Send + Sync>);

/// A read-only numpy view of `data` with `shape` (C order).
fn view<'py, T: Element + Send + Sync + 'static>(
    py: Python<'py>,
    data: &Arc<[T]>,
    shape: &[usize],
) -> PyResult<Bound<'py, PyAny>> {
    let array = ArrayView::from_shape(IxDyn(shape), &data[..])
        .map_err(|e| pyo3::exceptions::PyValueError::new_err(format!("shape {shape:?}: {e}")))?;
    let owner = Bound::new(py, Keep(Box::new(data.clone())))?;
    // SAFETY: `owner` holds the Arc whose memory the view points into, and
    // numpy keeps `owner` alive as the array's base for as long as the array
    // (or any view of it) lives; the buffer is never written (the flag below).
    let array = unsafe { PyArray::<T, IxDyn>::borrow_from_array(&array, owner.into_any()) };
    // SAFETY: clearing the writeable flag of an array we just made.
    unsafe {
        (*array.as_array_ptr()).fields.flags &= !NPY_ARRAY_WRITEABLE;
    }
    Ok(array.into_any())
}

/// A small fixed matrix as a new numpy array.
fn matrix<'py, const R: usize, const C: usize>(
    py: Python<'py>,
    m: &[[f64; C]; R],
) -> PyResult<Bound<'py, PyAny>> {
    let flat: Arc<[f64]> = m.iter().flatten().copied().collect();
    view(py, &flat, &[R, C])
}

fn camera<'py>(py: Python<'py>, c: &Camera) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("type", "Camera")?;
    d.set_item("width", c.width)?;
    d.set_item("height", c.height)?;
    d.set_item("k", matrix(py, &c.k)?)?;
    d.set_item("distortion", view(py, &Arc::from(&c.distortion[..]), &[5])?)?;
    Ok(d)
}

/// `value` in the plain Python form (see the module doc).
pub fn to_py<'py>(py: Python<'py>, value: &Value) -> PyResult<Bound<'py, PyAny>> {
    let d = PyDict::new(py);
    d.set_item("type", value.value_type().name())?;
    let grid = |d: &Bound<'py, PyDict>, g: &Grid| -> PyResult<[usize; 3]> {
        d.set_item("affine", matrix(py, &g.voxel_to_patient)?)?;
        Ok([g.dims[2], g.dims[1], g.dims[0]])
    };
    match value {
        Value::Volume(v) => {
            let shape = grid(&d, &v.grid)?;
            d.set_item("array", view(py, &v.data, &shape)?)?;
        }
        Value::Mask(v) => {
            let shape = grid(&d, &v.grid)?;
            d.set_item("array", view(py, &v.data, &shape)?)?;
        }
        Value::Labels(v) => {
            let shape = grid(&d, &v.grid)?;
            d.set_item("array", view(py, &v.data, &shape)?)?;
        }
        Value::Image(im) => {
            let mut shape = vec![im.height, im.width];
            if im.channels == 3 {
                shape.push(3);
            }
            return match &im.pixels {
                Pixels::U8(p) => view(py, p, &shape),
                Pixels::F32(p) => view(py, p, &shape),
            };
        }
        Value::Disparity(m) => return view(py, &m.data, &[m.height, m.width]),
        Value::Mesh(m) => {
            d.set_item("vertices", view(py, &m.vertices, &[m.vertex_count(), 3])?)?;
            d.set_item(
                "triangles",
                view(py, &m.triangles, &[m.triangle_count(), 3])?,
            )?;
            match &m.normals {
                Some(n) => d.set_item("normals", view(py, n, &[m.vertex_count(), 3])?)?,
                None => d.set_item("normals", py.None())?,
            }
            d.set_item("frame", &m.frame)?;
        }
        Value::PointCloud(c) => {
            d.set_item("points", view(py, &c.points, &[c.len(), 3])?)?;
            match &c.colors {
                Some(x) => d.set_item("colors", view(py, x, &[c.len(), 3])?)?,
                None => d.set_item("colors", py.None())?,
            }
            match &c.normals {
                Some(x) => d.set_item("normals", view(py, x, &[c.len(), 3])?)?,
                None => d.set_item("normals", py.None())?,
            }
            d.set_item("frame", &c.frame)?;
        }
        Value::Markers(m) => {
            d.set_item("positions_mm", view(py, &m.positions_mm, &[m.len(), 3])?)?;
            d.set_item("ids", view(py, &m.ids, &[m.len()])?)?;
            d.set_item("frame", &m.frame)?;
        }
        Value::Matches(m) => {
            d.set_item("left_px", view(py, &m.left_px, &[m.len(), 2])?)?;
            d.set_item("right_px", view(py, &m.right_px, &[m.len(), 2])?)?;
            d.set_item("scores", view(py, &m.scores, &[m.len()])?)?;
        }
        Value::Camera(c) => return Ok(camera(py, c)?.into_any()),
        Value::StereoRig(r) => {
            d.set_item("left", camera(py, &r.left)?)?;
            d.set_item("right", camera(py, &r.right)?)?;
            d.set_item("rotation", matrix(py, &r.rotation)?)?;
            d.set_item(
                "translation_mm",
                view(py, &Arc::from(&r.translation_mm[..]), &[3])?,
            )?;
        }
        Value::Rectification(r) => {
            d.set_item("width", r.width)?;
            d.set_item("height", r.height)?;
            d.set_item("r1", matrix(py, &r.r1)?)?;
            d.set_item("r2", matrix(py, &r.r2)?)?;
            d.set_item("p1", matrix(py, &r.p1)?)?;
            d.set_item("p2", matrix(py, &r.p2)?)?;
            d.set_item("q", matrix(py, &r.q)?)?;
        }
        Value::Transform(t) => {
            d.set_item("matrix", matrix(py, &t.matrix)?)?;
            d.set_item("from_frame", &t.from)?;
            d.set_item("to_frame", &t.to)?;
        }
        Value::Table(t) => {
            let columns = PyDict::new(py);
            for name in &t.columns {
                let column: Arc<[f64]> = t.column(name).unwrap_or_default().into();
                columns.set_item(name, view(py, &column, &[t.row_count()])?)?;
            }
            return Ok(columns.into_any());
        }
        Value::Scalar(x) => return Ok(x.into_pyobject(py)?.into_any()),
        Value::Path(p) => return Ok(p.path.to_string_lossy().into_pyobject(py)?.into_any()),
    }
    Ok(d.into_any())
}

/// What went wrong reading a Python value as an engine value.
type Why = String;

fn field<'py>(d: &Bound<'py, PyDict>, key: &str) -> Result<Bound<'py, PyAny>, Why> {
    d.get_item(key)
        .map_err(|e| e.to_string())?
        .filter(|v| !v.is_none())
        .ok_or_else(|| format!("has no `{key}`"))
}

fn optional<'py>(d: &Bound<'py, PyDict>, key: &str) -> Result<Option<Bound<'py, PyAny>>, Why> {
    Ok(d.get_item(key)
        .map_err(|e| e.to_string())?
        .filter(|v| !v.is_none()))
}

/// A numpy array of element type `T` (the package converts dtypes first):
/// its shape and a copy of its elements in C order.
fn array<T: Element + Copy>(
    obj: &Bound<'_, PyAny>,
    what: &str,
) -> Result<(Vec<usize>, Vec<T>), Why> {
    let array = obj.cast::<PyArrayDyn<T>>().map_err(|_| {
        format!(
            "`{what}` must be a numpy array of {} (got {})",
            std::any::type_name::<T>(),
            obj.get_type()
                .name()
                .map(|n| n.to_string())
                .unwrap_or_else(|_| "?".into())
        )
    })?;
    let shape = array.shape().to_vec();
    let view = array.readonly();
    // One memcpy where numpy's layout is C order already (the package makes
    // it so); element by element otherwise.
    let data = match view.as_slice() {
        Ok(slice) => slice.to_vec(),
        Err(_) => view.as_array().iter().copied().collect(),
    };
    Ok((shape, data))
}

/// An array of shape (N, `width`) flattened, N any.
fn rows<T: Element + Copy>(d: &Bound<'_, PyDict>, key: &str, width: usize) -> Result<Vec<T>, Why> {
    let (shape, data) = array::<T>(&field(d, key)?, key)?;
    if shape.len() != 2 || shape[1] != width {
        return Err(format!(
            "`{key}` must have shape (N, {width}), not {shape:?}"
        ));
    }
    Ok(data)
}

/// [`rows`] of an optional field: `None` when absent or `None`.
fn optional_rows<T: Element + Copy>(
    d: &Bound<'_, PyDict>,
    key: &str,
    width: usize,
) -> Result<Option<Arc<[T]>>, Why> {
    Ok(match optional(d, key)? {
        Some(_) => Some(rows::<T>(d, key, width)?.into()),
        None => None,
    })
}

fn fixed<const R: usize, const C: usize>(
    d: &Bound<'_, PyDict>,
    key: &str,
) -> Result<[[f64; C]; R], Why> {
    let (shape, data) = array::<f64>(&field(d, key)?, key)?;
    if shape != [R, C] {
        return Err(format!("`{key}` must have shape ({R}, {C}), not {shape:?}"));
    }
    Ok(std::array::from_fn(|r| {
        std::array::from_fn(|c| data[r * C + c])
    }))
}

fn text(d: &Bound<'_, PyDict>, key: &str, default: &str) -> Result<String, Why> {
    match optional(d, key)? {
        Some(v) => v.extract().map_err(|_| format!("`{key}` must be a string")),
        None => Ok(default.into()),
    }
}

fn count(d: &Bound<'_, PyDict>, key: &str) -> Result<usize, Why> {
    field(d, key)?
        .extract()
        .map_err(|_| format!("`{key}` must be a non-negative integer"))
}

fn camera_from(d: &Bound<'_, PyAny>) -> Result<Camera, Why> {
    let d = d
        .cast::<PyDict>()
        .map_err(|_| "a camera must be a Camera".to_string())?;
    let (shape, distortion) = array::<f64>(&field(d, "distortion")?, "distortion")?;
    if shape != [5] {
        return Err(format!(
            "`distortion` must hold 5 numbers (k1, k2, p1, p2, k3), not {shape:?}"
        ));
    }
    Ok(Camera {
        width: count(d, "width")?,
        height: count(d, "height")?,
        k: fixed(d, "k")?,
        distortion: std::array::from_fn(|i| distortion[i]),
    })
}

fn grid_from<'py>(d: &Bound<'py, PyDict>) -> Result<(Grid, Bound<'py, PyAny>), Why> {
    let affine = fixed::<4, 4>(d, "affine")?;
    let array = field(d, "array")?;
    let shape: Vec<usize> = array
        .getattr("shape")
        .and_then(|s| s.extract())
        .map_err(|_| "`array` must be a numpy array".to_string())?;
    if shape.len() != 3 {
        return Err(format!(
            "`array` must have shape (nz, ny, nx), not {shape:?}"
        ));
    }
    let grid = Grid {
        dims: [shape[2], shape[1], shape[0]],
        voxel_to_patient: affine,
    };
    Ok((grid, array))
}

/// The Python value `obj` (in the plain form, see the module doc) as an
/// engine value of type `ty`; the error says what does not fit.
pub fn from_py(obj: &Bound<'_, PyAny>, ty: ValueType) -> Result<Value, Why> {
    let bad = |e: fusegraph_engine::value::ValueError| e.0;
    let dict = || {
        obj.cast::<PyDict>()
            .map_err(|_| format!("a {ty} must be a fusegraph.{ty} (or its dict form)"))
    };
    Ok(match ty {
        ValueType::Volume => {
            let d = dict()?;
            let (grid, a) = grid_from(d)?;
            Volume::new(grid, array::<f32>(&a, "array")?.1)
                .map_err(bad)?
                .into()
        }
        ValueType::Mask => {
            let d = dict()?;
            let (grid, a) = grid_from(d)?;
            Mask::new(grid, array::<u8>(&a, "array")?.1)
                .map_err(bad)?
                .into()
        }
        ValueType::Labels => {
            let d = dict()?;
            let (grid, a) = grid_from(d)?;
            Labels::new(grid, array::<u32>(&a, "array")?.1)
                .map_err(bad)?
                .into()
        }
        ValueType::Image => {
            let dtype: String = obj
                .getattr("dtype")
                .and_then(|t| t.str())
                .map(|s| s.to_string())
                .map_err(|_| "an Image must be a numpy array (H, W) or (H, W, 3)".to_string())?;
            let (shape, pixels) = if dtype == "uint8" {
                let (s, p) = array::<u8>(obj, "image")?;
                (s, Pixels::U8(p.into()))
            } else {
                let (s, p) = array::<f32>(obj, "image")?;
                (s, Pixels::F32(p.into()))
            };
            let channels = match shape.as_slice() {
                [_, _] => 1,
                [_, _, c] => *c,
                _ => {
                    return Err(format!(
                        "an Image must be (H, W) or (H, W, 3), not {shape:?}"
                    ));
                }
            };
            Image::new(shape[1], shape[0], channels, pixels)
                .map_err(bad)?
                .into()
        }
        ValueType::Disparity => {
            let (shape, data) = array::<f32>(obj, "disparity")?;
            if shape.len() != 2 {
                return Err(format!("a Disparity must be (H, W), not {shape:?}"));
            }
            Disparity::new(shape[1], shape[0], data)
                .map_err(bad)?
                .into()
        }
        ValueType::Mesh => {
            let d = dict()?;
            Mesh::new(
                rows::<f32>(d, "vertices", 3)?,
                rows::<u32>(d, "triangles", 3)?,
                optional_rows(d, "normals", 3)?,
                text(d, "frame", "")?,
            )
            .map_err(bad)?
            .into()
        }
        ValueType::PointCloud => {
            let d = dict()?;
            let colors = match optional(d, "colors")? {
                Some(_) => Some(rows::<u8>(d, "colors", 3)?.into()),
                None => None,
            };
            let normals = match optional(d, "normals")? {
                Some(_) => Some(rows::<f32>(d, "normals", 3)?.into()),
                None => None,
            };
            PointCloud::new(
                rows::<f32>(d, "points", 3)?,
                colors,
                normals,
                text(d, "frame", "")?,
            )
            .map_err(bad)?
            .into()
        }
        ValueType::Markers => {
            let d = dict()?;
            let (_, ids) = array::<u32>(&field(d, "ids")?, "ids")?;
            Markers::new(
                rows::<f64>(d, "positions_mm", 3)?,
                ids,
                text(d, "frame", "")?,
            )
            .map_err(bad)?
            .into()
        }
        ValueType::Matches => {
            let d = dict()?;
            let (_, scores) = array::<f32>(&field(d, "scores")?, "scores")?;
            Matches::new(
                rows::<f32>(d, "left_px", 2)?,
                rows::<f32>(d, "right_px", 2)?,
                scores,
            )
            .map_err(bad)?
            .into()
        }
        ValueType::Camera => camera_from(obj)?.into(),
        ValueType::StereoRig => {
            let d = dict()?;
            let (shape, t) = array::<f64>(&field(d, "translation_mm")?, "translation_mm")?;
            if shape != [3] {
                return Err(format!(
                    "`translation_mm` must hold 3 numbers, not {shape:?}"
                ));
            }
            StereoRig {
                left: camera_from(&field(d, "left")?)?,
                right: camera_from(&field(d, "right")?)?,
                rotation: fixed(d, "rotation")?,
                translation_mm: [t[0], t[1], t[2]],
            }
            .into()
        }
        ValueType::Rectification => {
            let d = dict()?;
            Rectification {
                width: count(d, "width")?,
                height: count(d, "height")?,
                r1: fixed(d, "r1")?,
                r2: fixed(d, "r2")?,
                p1: fixed(d, "p1")?,
                p2: fixed(d, "p2")?,
                q: fixed(d, "q")?,
            }
            .into()
        }
        ValueType::Transform => {
            let d = dict()?;
            Transform {
                matrix: fixed(d, "matrix")?,
                from: text(d, "from_frame", "")?,
                to: text(d, "to_frame", "")?,
            }
            .into()
        }
        ValueType::Table => {
            let d = obj
                .cast::<PyDict>()
                .map_err(|_| "a Table must be a dict of equally long columns".to_string())?;
            let mut names = Vec::new();
            let mut columns = Vec::new();
            for (k, v) in d.iter() {
                let name: String = k
                    .extract()
                    .map_err(|_| "Table column names must be strings")?;
                let (shape, data) = array::<f64>(&v, &name)?;
                if shape.len() != 1 {
                    return Err(format!("Table column `{name}` must be 1-D, not {shape:?}"));
                }
                names.push(name);
                columns.push(data);
            }
            let n = columns.first().map_or(0, Vec::len);
            if let Some((name, c)) = names.iter().zip(&columns).find(|(_, c)| c.len() != n) {
                return Err(format!(
                    "Table column `{name}` has {} rows, the first {n}",
                    c.len()
                ));
            }
            let data: Vec<f64> = (0..n)
                .flat_map(|r| columns.iter().map(move |c| c[r]))
                .collect();
            Table::new(names, data).map_err(bad)?.into()
        }
        ValueType::Scalar => {
            let x: f64 = obj
                .extract()
                .map_err(|_| "a Scalar must be a number".to_string())?;
            x.into()
        }
        ValueType::Path => {
            let p: std::path::PathBuf = obj
                .extract()
                .map_err(|_| "a Path must be a str or pathlib.Path".to_string())?;
            let hash = fusegraph_engine::hash::hash_path(&p)
                .map_err(|e| format!("{}: {e}", p.display()))?;
            PathValue {
                path: p,
                content_hash: hash.to_hex().to_string(),
            }
            .into()
        }
    })
}

/// A parameter's value as a Python object.
pub fn param_to_py<'py>(
    py: Python<'py>,
    value: &fusegraph_engine::ParamValue,
) -> PyResult<Bound<'py, PyAny>> {
    use fusegraph_engine::ParamValue as P;
    Ok(match value {
        P::Float(x) => x.into_pyobject(py)?.into_any(),
        P::Int(x) => x.into_pyobject(py)?.into_any(),
        P::Bool(x) => x.into_pyobject(py)?.to_owned().into_any(),
        P::String(x) => x.into_pyobject(py)?.into_any(),
        P::Path(x) => x.to_string_lossy().into_pyobject(py)?.into_any(),
        P::FloatList(x) => PyList::new(py, x)?.into_any(),
        P::IntList(x) => PyList::new(py, x)?.into_any(),
        P::StringList(x) => PyList::new(py, x)?.into_any(),
    })
}
