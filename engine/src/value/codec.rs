//! Binary encoding of [`Value`]s for the disk cache: little-endian, length-prefixed,
//! every read bounds-checked so a truncated or corrupt buffer is an error, never a
//! panic. Type tags are explicit and stable; changing any layout means bumping
//! [`crate::cache::FORMAT_VERSION`].

use super::*;
use std::path::PathBuf;

/// A buffer that does not decode to a value.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("cannot decode value: {0}")]
pub struct CodecError(pub String);

fn tag(t: ValueType) -> u8 {
    match t {
        ValueType::Volume => 1,
        ValueType::Mask => 2,
        ValueType::Labels => 3,
        ValueType::Image => 4,
        ValueType::Disparity => 5,
        ValueType::Mesh => 6,
        ValueType::PointCloud => 7,
        ValueType::Markers => 8,
        ValueType::Matches => 9,
        ValueType::Camera => 10,
        ValueType::StereoRig => 11,
        ValueType::Rectification => 12,
        ValueType::Transform => 13,
        ValueType::Table => 14,
        ValueType::Scalar => 15,
        ValueType::Path => 16,
    }
}

/// Appends the encoding of `value` to `out`.
pub fn encode_value(value: &Value, out: &mut Vec<u8>) {
    let mut w = Writer(out);
    w.u8(tag(value.value_type()));
    match value {
        Value::Volume(v) => {
            w.grid(&v.grid);
            w.f32s(&v.data);
        }
        Value::Mask(v) => {
            w.grid(&v.grid);
            w.u8s(&v.data);
        }
        Value::Labels(v) => {
            w.grid(&v.grid);
            w.u32s(&v.data);
        }
        Value::Image(v) => {
            w.usize(v.width);
            w.usize(v.height);
            w.usize(v.channels);
            match &v.pixels {
                Pixels::U8(p) => {
                    w.u8(0);
                    w.u8s(p);
                }
                Pixels::F32(p) => {
                    w.u8(1);
                    w.f32s(p);
                }
            }
        }
        Value::Disparity(v) => {
            w.usize(v.width);
            w.usize(v.height);
            w.f32s(&v.data);
        }
        Value::Mesh(v) => {
            w.f32s(&v.vertices);
            w.u32s(&v.triangles);
            w.opt(v.normals.as_deref(), Writer::f32s);
            w.str(&v.frame);
        }
        Value::PointCloud(v) => {
            w.f32s(&v.points);
            w.opt(v.colors.as_deref(), Writer::u8s);
            w.opt(v.normals.as_deref(), Writer::f32s);
            w.str(&v.frame);
        }
        Value::Markers(v) => {
            w.f64s(&v.positions_mm);
            w.u32s(&v.ids);
            w.str(&v.frame);
        }
        Value::Matches(v) => {
            w.f32s(&v.left_px);
            w.f32s(&v.right_px);
            w.f32s(&v.scores);
        }
        Value::Camera(v) => w.camera(v),
        Value::StereoRig(v) => {
            w.camera(&v.left);
            w.camera(&v.right);
            w.f64s(v.rotation.as_flattened());
            w.f64s(&v.translation_mm);
        }
        Value::Rectification(v) => {
            w.usize(v.width);
            w.usize(v.height);
            for m in [&v.r1, &v.r2] {
                w.f64s(m.as_flattened());
            }
            for m in [&v.p1, &v.p2] {
                w.f64s(m.as_flattened());
            }
            w.f64s(v.q.as_flattened());
        }
        Value::Transform(v) => {
            w.f64s(v.matrix.as_flattened());
            w.str(&v.from);
            w.str(&v.to);
        }
        Value::Table(v) => {
            w.usize(v.columns.len());
            v.columns.iter().for_each(|c| w.str(c));
            w.f64s(&v.data);
        }
        Value::Scalar(v) => w.f64(**v),
        Value::Path(v) => {
            w.str(&v.path.to_string_lossy());
            w.str(&v.content_hash);
        }
    }
}

/// Decodes one value from the front of `bytes`, returning it and the bytes used.
pub fn decode_value(bytes: &[u8]) -> Result<(Value, usize), CodecError> {
    let mut r = Reader::new(bytes);
    let t = r.u8()?;
    let ty = ValueType::ALL
        .iter()
        .copied()
        .find(|&t2| tag(t2) == t)
        .ok_or_else(|| CodecError(format!("unknown type tag {t}")))?;
    let shape = |e: ValueError| CodecError(e.0);
    let value = match ty {
        ValueType::Volume => Volume::new(r.grid()?, r.f32s()?).map_err(shape)?.into(),
        ValueType::Mask => Mask::new(r.grid()?, r.u8s()?).map_err(shape)?.into(),
        ValueType::Labels => Labels::new(r.grid()?, r.u32s()?).map_err(shape)?.into(),
        ValueType::Image => {
            let (w, h, c) = (r.usize()?, r.usize()?, r.usize()?);
            let pixels = match r.u8()? {
                0 => Pixels::U8(r.u8s()?.into()),
                1 => Pixels::F32(r.f32s()?.into()),
                k => return Err(CodecError(format!("unknown pixel kind {k}"))),
            };
            Image::new(w, h, c, pixels).map_err(shape)?.into()
        }
        ValueType::Disparity => {
            let (w, h) = (r.usize()?, r.usize()?);
            Disparity::new(w, h, r.f32s()?).map_err(shape)?.into()
        }
        ValueType::Mesh => {
            let (v, t) = (r.f32s()?, r.u32s()?);
            let n = r.opt(Reader::f32s)?.map(Into::into);
            Mesh::new(v, t, n, r.str()?).map_err(shape)?.into()
        }
        ValueType::PointCloud => {
            let p = r.f32s()?;
            let c = r.opt(Reader::u8s)?.map(Into::into);
            let n = r.opt(Reader::f32s)?.map(Into::into);
            PointCloud::new(p, c, n, r.str()?).map_err(shape)?.into()
        }
        ValueType::Markers => {
            let (p, ids) = (r.f64s()?, r.u32s()?);
            Markers::new(p, ids, r.str()?).map_err(shape)?.into()
        }
        ValueType::Matches => Matches::new(r.f32s()?, r.f32s()?, r.f32s()?)
            .map_err(shape)?
            .into(),
        ValueType::Camera => r.camera()?.into(),
        ValueType::StereoRig => StereoRig {
            left: r.camera()?,
            right: r.camera()?,
            rotation: r.mat()?,
            translation_mm: r.array()?,
        }
        .into(),
        ValueType::Rectification => Rectification {
            width: r.usize()?,
            height: r.usize()?,
            r1: r.mat()?,
            r2: r.mat()?,
            p1: r.mat()?,
            p2: r.mat()?,
            q: r.mat()?,
        }
        .into(),
        ValueType::Transform => Transform {
            matrix: r.mat()?,
            from: r.str()?,
            to: r.str()?,
        }
        .into(),
        ValueType::Table => {
            let n = r.usize()?;
            let columns = (0..n).map(|_| r.str()).collect::<Result<Vec<_>, _>>()?;
            Table::new(columns, r.f64s()?).map_err(shape)?.into()
        }
        ValueType::Scalar => r.f64()?.into(),
        ValueType::Path => PathValue {
            path: PathBuf::from(r.str()?),
            content_hash: r.str()?,
        }
        .into(),
    };
    Ok((value, r.pos))
}

/// Little-endian writer shared with the cache entry format.
pub(crate) struct Writer<'a>(pub(crate) &'a mut Vec<u8>);

impl Writer<'_> {
    pub(crate) fn u8(&mut self, v: u8) {
        self.0.push(v);
    }
    pub(crate) fn usize(&mut self, v: usize) {
        self.0.extend_from_slice(&(v as u64).to_le_bytes());
    }
    pub(crate) fn f64(&mut self, v: f64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    pub(crate) fn str(&mut self, s: &str) {
        self.u8s(s.as_bytes());
    }
    pub(crate) fn u8s(&mut self, v: &[u8]) {
        self.usize(v.len());
        self.0.extend_from_slice(v);
    }
    pub(crate) fn f32s(&mut self, v: &[f32]) {
        self.usize(v.len());
        self.0.reserve(v.len() * 4);
        v.iter()
            .for_each(|x| self.0.extend_from_slice(&x.to_le_bytes()));
    }
    pub(crate) fn u32s(&mut self, v: &[u32]) {
        self.usize(v.len());
        self.0.reserve(v.len() * 4);
        v.iter()
            .for_each(|x| self.0.extend_from_slice(&x.to_le_bytes()));
    }
    pub(crate) fn f64s(&mut self, v: &[f64]) {
        self.usize(v.len());
        self.0.reserve(v.len() * 8);
        v.iter()
            .for_each(|x| self.0.extend_from_slice(&x.to_le_bytes()));
    }
    fn opt<T: ?Sized>(&mut self, v: Option<&T>, write: fn(&mut Self, &T)) {
        match v {
            None => self.u8(0),
            Some(v) => {
                self.u8(1);
                write(self, v);
            }
        }
    }
    fn grid(&mut self, g: &Grid) {
        g.dims.iter().for_each(|&d| self.usize(d));
        self.f64s(g.voxel_to_patient.as_flattened());
    }
    fn camera(&mut self, c: &Camera) {
        self.usize(c.width);
        self.usize(c.height);
        self.f64s(c.k.as_flattened());
        self.f64s(&c.distortion);
    }
}

/// Bounds-checked reader shared with the cache entry format.
pub(crate) struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    pub(crate) fn new(bytes: &'a [u8]) -> Self {
        Reader { bytes, pos: 0 }
    }

    /// Whether every byte has been read.
    pub(crate) fn is_empty(&self) -> bool {
        self.pos == self.bytes.len()
    }

    /// Decodes the value at the current position.
    pub(crate) fn value(&mut self) -> Result<Value, CodecError> {
        let (value, used) = decode_value(&self.bytes[self.pos..])?;
        self.pos += used;
        Ok(value)
    }

    fn take(&mut self, n: usize) -> Result<&'a [u8], CodecError> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.bytes.len());
        let end = end.ok_or_else(|| {
            CodecError(format!(
                "truncated: need {n} bytes at offset {}, {} left",
                self.pos,
                self.bytes.len() - self.pos
            ))
        })?;
        let s = &self.bytes[self.pos..end];
        self.pos = end;
        Ok(s)
    }
    pub(crate) fn u8(&mut self) -> Result<u8, CodecError> {
        Ok(self.take(1)?[0])
    }
    pub(crate) fn usize(&mut self) -> Result<usize, CodecError> {
        let v = u64::from_le_bytes(self.take(8)?.try_into().expect("8 bytes"));
        usize::try_from(v).map_err(|_| CodecError(format!("length {v} too large")))
    }
    pub(crate) fn f64(&mut self) -> Result<f64, CodecError> {
        Ok(f64::from_le_bytes(
            self.take(8)?.try_into().expect("8 bytes"),
        ))
    }
    pub(crate) fn str(&mut self) -> Result<String, CodecError> {
        String::from_utf8(self.u8s()?).map_err(|_| CodecError("string is not UTF-8".into()))
    }
    fn elements<const N: usize, T>(
        &mut self,
        from: fn([u8; N]) -> T,
    ) -> Result<Vec<T>, CodecError> {
        let n = self.usize()?;
        let bytes = self.take(
            n.checked_mul(N)
                .ok_or_else(|| CodecError("length overflow".into()))?,
        )?;
        Ok(bytes
            .chunks_exact(N)
            .map(|c| from(c.try_into().expect("chunk of N")))
            .collect())
    }
    pub(crate) fn u8s(&mut self) -> Result<Vec<u8>, CodecError> {
        let n = self.usize()?;
        Ok(self.take(n)?.to_vec())
    }
    pub(crate) fn f32s(&mut self) -> Result<Vec<f32>, CodecError> {
        self.elements(f32::from_le_bytes)
    }
    pub(crate) fn u32s(&mut self) -> Result<Vec<u32>, CodecError> {
        self.elements(u32::from_le_bytes)
    }
    pub(crate) fn f64s(&mut self) -> Result<Vec<f64>, CodecError> {
        self.elements(f64::from_le_bytes)
    }
    fn array<const N: usize>(&mut self) -> Result<[f64; N], CodecError> {
        let v = self.f64s()?;
        let len = v.len();
        v.try_into()
            .map_err(|_| CodecError(format!("expected {N} numbers, found {len}")))
    }
    fn mat<const R: usize, const C: usize>(&mut self) -> Result<[[f64; C]; R], CodecError> {
        let v = self.f64s()?;
        if v.len() != R * C {
            return Err(CodecError(format!(
                "expected a {R}x{C} matrix, found {} numbers",
                v.len()
            )));
        }
        Ok(std::array::from_fn(|r| {
            std::array::from_fn(|c| v[r * C + c])
        }))
    }
    fn opt<T>(
        &mut self,
        read: fn(&mut Self) -> Result<T, CodecError>,
    ) -> Result<Option<T>, CodecError> {
        match self.u8()? {
            0 => Ok(None),
            1 => read(self).map(Some),
            k => Err(CodecError(format!("bad option flag {k}"))),
        }
    }
    fn grid(&mut self) -> Result<Grid, CodecError> {
        let dims = [self.usize()?, self.usize()?, self.usize()?];
        Ok(Grid {
            dims,
            voxel_to_patient: self.mat()?,
        })
    }
    fn camera(&mut self) -> Result<Camera, CodecError> {
        Ok(Camera {
            width: self.usize()?,
            height: self.usize()?,
            k: self.mat()?,
            distortion: self.array()?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> Camera {
        Camera {
            width: 800,
            height: 600,
            k: [[1333.0, 0.0, 400.5], [0.0, 1334.0, 299.5], [0.0, 0.0, 1.0]],
            distortion: [-0.1, 0.02, 0.001, -0.002, 0.0],
        }
    }

    /// One value of every type, so a new type cannot be added without a codec.
    fn samples() -> Vec<Value> {
        let grid = Grid::axis_aligned([2, 2, 1], [0.6, 0.6, 1.0], [1.0, 2.0, 3.0]);
        let rig = StereoRig {
            left: camera(),
            right: camera(),
            rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            translation_mm: [-55.0, 0.0, 0.0],
        };
        let mut rect_p = [[0.0; 4]; 3];
        rect_p[0][0] = 1.5;
        vec![
            Volume::new(grid.clone(), vec![0.5f32, 1.0, -2.0, f32::NAN])
                .unwrap()
                .into(),
            Mask::new(grid.clone(), vec![0u8, 1, 1, 0]).unwrap().into(),
            Labels::new(grid, vec![0u32, 1, 2, 70000]).unwrap().into(),
            Image::new(2, 1, 3, Pixels::U8(vec![1, 2, 3, 4, 5, 6].into()))
                .unwrap()
                .into(),
            Image::new(1, 1, 1, Pixels::F32(vec![0.25].into()))
                .unwrap()
                .into(),
            Disparity::new(2, 1, vec![3.5f32, f32::NAN]).unwrap().into(),
            Mesh::new(
                vec![0f32; 9],
                vec![0u32, 1, 2],
                Some(vec![0f32; 9].into()),
                "mri_lps",
            )
            .unwrap()
            .into(),
            PointCloud::new(
                vec![1f32, 2.0, 3.0],
                Some(vec![9u8, 8, 7].into()),
                None,
                "world",
            )
            .unwrap()
            .into(),
            Markers::new(vec![1.0, 2.0, 3.0], vec![7u32], "camera_left")
                .unwrap()
                .into(),
            Matches::new(vec![1f32, 2.0], vec![3f32, 4.0], vec![0.5f32])
                .unwrap()
                .into(),
            camera().into(),
            rig.into(),
            Rectification {
                width: 800,
                height: 600,
                r1: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
                r2: [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
                p1: rect_p,
                p2: rect_p,
                q: [[2.0; 4]; 4],
            }
            .into(),
            Transform::identity("mri_lps", "camera_left").into(),
            Table::new(vec!["x_mm".into()], vec![1.0, 2.0])
                .unwrap()
                .into(),
            Value::from(-0.0f64),
            PathValue {
                path: "/tmp/x".into(),
                content_hash: "ab".into(),
            }
            .into(),
        ]
    }

    fn same(a: &Value, b: &Value) -> bool {
        // NaN != NaN, so compare encodings.
        let (mut ea, mut eb) = (Vec::new(), Vec::new());
        encode_value(a, &mut ea);
        encode_value(b, &mut eb);
        ea == eb
    }

    #[test]
    fn every_type_round_trips() {
        let values = samples();
        let covered: std::collections::BTreeSet<_> = values.iter().map(Value::value_type).collect();
        assert_eq!(
            covered.len(),
            ValueType::ALL.len(),
            "a value type has no sample"
        );
        for v in &values {
            let mut buf = Vec::new();
            encode_value(v, &mut buf);
            let (back, used) = decode_value(&buf).unwrap();
            assert_eq!(used, buf.len());
            assert!(same(v, &back), "{v:?} != {back:?}");
        }
    }

    #[test]
    fn truncation_is_an_error_at_every_length() {
        for v in samples() {
            let mut buf = Vec::new();
            encode_value(&v, &mut buf);
            for cut in 0..buf.len() {
                assert!(decode_value(&buf[..cut]).is_err(), "{v:?} cut at {cut}");
            }
        }
    }

    #[test]
    fn absurd_lengths_do_not_allocate_or_panic() {
        let mut buf = vec![tag(ValueType::Table)];
        buf.extend_from_slice(&u64::MAX.to_le_bytes());
        assert!(decode_value(&buf).is_err());
        let mut buf = vec![
            tag(ValueType::Disparity),
            1,
            0,
            0,
            0,
            0,
            0,
            0,
            0,
            1,
            0,
            0,
            0,
            0,
            0,
            0,
            0,
        ];
        buf.extend_from_slice(&(u64::MAX / 2).to_le_bytes());
        assert!(decode_value(&buf).is_err());
    }
}
