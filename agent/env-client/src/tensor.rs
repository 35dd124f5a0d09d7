//! Typed tensors: the API's `{dtype, shape, bytes}` little-endian row-major arrays.
//!
//! The payload stays in the `bytes::Bytes` the message was decoded into: slicing
//! rows and cloning are reference-count bumps, and `data()` hands the raw
//! little-endian bytes to a consumer such as `tch::Tensor::from_data_size`
//! without an intermediate copy. Conversions to `Vec<f32>` etc. copy once.
use std::fmt;
use std::ops::Range;

use bytes::{Bytes, BytesMut};

use crate::proto;

/// Element type of a tensor (mirrors `proto::DType` without the unspecified value).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize)]
pub enum DType {
    Float32,
    Float64,
    Int8,
    Int16,
    Int32,
    Int64,
    UInt8,
    Bool,
    String,
}

impl DType {
    /// Bytes per element in `data`; 0 for strings, which travel in `strings`.
    pub fn item_size(self) -> usize {
        match self {
            DType::Float64 | DType::Int64 => 8,
            DType::Float32 | DType::Int32 => 4,
            DType::Int16 => 2,
            DType::Int8 | DType::UInt8 | DType::Bool => 1,
            DType::String => 0,
        }
    }

    pub fn is_float(self) -> bool {
        matches!(self, DType::Float32 | DType::Float64)
    }

    pub fn from_proto(value: i32) -> Result<Self, String> {
        match proto::DType::try_from(value) {
            Ok(proto::DType::DtypeFloat32) => Ok(DType::Float32),
            Ok(proto::DType::DtypeFloat64) => Ok(DType::Float64),
            Ok(proto::DType::DtypeInt8) => Ok(DType::Int8),
            Ok(proto::DType::DtypeInt16) => Ok(DType::Int16),
            Ok(proto::DType::DtypeInt32) => Ok(DType::Int32),
            Ok(proto::DType::DtypeInt64) => Ok(DType::Int64),
            Ok(proto::DType::DtypeUint8) => Ok(DType::UInt8),
            Ok(proto::DType::DtypeBool) => Ok(DType::Bool),
            Ok(proto::DType::DtypeString) => Ok(DType::String),
            Ok(proto::DType::DtypeUnspecified) => Err("dtype is DTYPE_UNSPECIFIED".into()),
            Err(_) => Err(format!("unknown dtype number {value}")),
        }
    }

    pub fn to_proto(self) -> proto::DType {
        match self {
            DType::Float32 => proto::DType::DtypeFloat32,
            DType::Float64 => proto::DType::DtypeFloat64,
            DType::Int8 => proto::DType::DtypeInt8,
            DType::Int16 => proto::DType::DtypeInt16,
            DType::Int32 => proto::DType::DtypeInt32,
            DType::Int64 => proto::DType::DtypeInt64,
            DType::UInt8 => proto::DType::DtypeUint8,
            DType::Bool => proto::DType::DtypeBool,
            DType::String => proto::DType::DtypeString,
        }
    }
}

impl fmt::Display for DType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let name = match self {
            DType::Float32 => "float32",
            DType::Float64 => "float64",
            DType::Int8 => "int8",
            DType::Int16 => "int16",
            DType::Int32 => "int32",
            DType::Int64 => "int64",
            DType::UInt8 => "uint8",
            DType::Bool => "bool",
            DType::String => "string",
        };
        f.write_str(name)
    }
}

/// A validated n-dimensional array: `data` always holds exactly
/// `prod(shape) * dtype.item_size()` bytes (or `strings` holds `prod(shape)`
/// strings for `DType::String`).
#[derive(Clone, Debug, PartialEq)]
pub struct Tensor {
    dtype: DType,
    shape: Vec<usize>,
    data: Bytes,
    strings: Vec<String>,
}

/// Number of elements of a shape (1 for a scalar).
pub fn numel(shape: &[usize]) -> usize {
    shape.iter().product()
}

impl Tensor {
    /// Builds a numeric tensor from raw little-endian bytes, checking the length.
    pub fn from_bytes(dtype: DType, shape: Vec<usize>, data: Bytes) -> Result<Self, String> {
        if dtype == DType::String {
            return Err("a string tensor carries strings, not bytes".into());
        }
        let expected = numel(&shape) * dtype.item_size();
        if data.len() != expected {
            return Err(format!(
                "{dtype} tensor of shape {shape:?} needs {expected} bytes, got {}",
                data.len()
            ));
        }
        Ok(Tensor {
            dtype,
            shape,
            data,
            strings: Vec::new(),
        })
    }

    pub fn from_strings(shape: Vec<usize>, strings: Vec<String>) -> Result<Self, String> {
        if strings.len() != numel(&shape) {
            return Err(format!(
                "string tensor of shape {shape:?} needs {} strings, got {}",
                numel(&shape),
                strings.len()
            ));
        }
        Ok(Tensor {
            dtype: DType::String,
            shape,
            data: Bytes::new(),
            strings,
        })
    }

    pub fn from_f32(shape: Vec<usize>, values: &[f32]) -> Result<Self, String> {
        Self::from_bytes(DType::Float32, shape, encode(values, |v| v.to_le_bytes()))
    }

    pub fn from_f64(shape: Vec<usize>, values: &[f64]) -> Result<Self, String> {
        Self::from_bytes(DType::Float64, shape, encode(values, |v| v.to_le_bytes()))
    }

    pub fn from_i64(shape: Vec<usize>, values: &[i64]) -> Result<Self, String> {
        Self::from_bytes(DType::Int64, shape, encode(values, |v| v.to_le_bytes()))
    }

    pub fn from_i8(shape: Vec<usize>, values: &[i8]) -> Result<Self, String> {
        Self::from_bytes(DType::Int8, shape, encode(values, |v| v.to_le_bytes()))
    }

    pub fn from_bool(shape: Vec<usize>, values: &[bool]) -> Result<Self, String> {
        Self::from_bytes(DType::Bool, shape, encode(values, |v| [u8::from(*v)]))
    }

    /// All-zero (false, "") tensor.
    pub fn zeros(dtype: DType, shape: Vec<usize>) -> Self {
        let n = numel(&shape);
        if dtype == DType::String {
            return Tensor {
                dtype,
                shape,
                data: Bytes::new(),
                strings: vec![String::new(); n],
            };
        }
        Tensor {
            dtype,
            data: Bytes::from(vec![0u8; n * dtype.item_size()]),
            shape,
            strings: Vec::new(),
        }
    }

    /// Takes over a decoded message's payload without copying it.
    pub fn from_proto(t: proto::Tensor) -> Result<Self, String> {
        let dtype = DType::from_proto(t.dtype)?;
        let shape = t
            .shape
            .iter()
            .map(|&d| {
                usize::try_from(d).map_err(|_| format!("negative dimension in shape {:?}", t.shape))
            })
            .collect::<Result<Vec<_>, _>>()?;
        if dtype == DType::String {
            if !t.data.is_empty() {
                return Err("string tensor with non-empty data".into());
            }
            Self::from_strings(shape, t.strings)
        } else {
            if !t.strings.is_empty() {
                return Err(format!("{dtype} tensor with strings"));
            }
            Self::from_bytes(dtype, shape, t.data)
        }
    }

    pub fn to_proto(&self) -> proto::Tensor {
        proto::Tensor {
            dtype: self.dtype.to_proto() as i32,
            shape: self.shape.iter().map(|&d| d as i64).collect(),
            data: self.data.clone(),
            strings: self.strings.clone(),
        }
    }

    pub fn dtype(&self) -> DType {
        self.dtype
    }

    pub fn shape(&self) -> &[usize] {
        &self.shape
    }

    pub fn numel(&self) -> usize {
        numel(&self.shape)
    }

    /// Size of the leading (batch) dimension; 1 for a scalar.
    pub fn rows(&self) -> usize {
        self.shape.first().copied().unwrap_or(1)
    }

    /// Shape of one row (the shape without its batch dimension).
    pub fn row_shape(&self) -> &[usize] {
        self.shape.get(1..).unwrap_or(&[])
    }

    /// Raw little-endian, row-major element bytes (empty for strings).
    pub fn data(&self) -> &Bytes {
        &self.data
    }

    pub fn strings(&self) -> &[String] {
        &self.strings
    }

    /// The same elements with another shape of equal element count.
    pub fn reshape(mut self, shape: Vec<usize>) -> Result<Self, String> {
        if numel(&shape) != self.numel() {
            return Err(format!("cannot reshape {:?} to {shape:?}", self.shape));
        }
        self.shape = shape;
        Ok(self)
    }

    /// Rows `range` of the batch dimension; shares the payload.
    pub fn slice_rows(&self, range: Range<usize>) -> Result<Self, String> {
        if self.shape.is_empty() || range.end > self.rows() || range.start > range.end {
            return Err(format!(
                "rows {range:?} out of a tensor of shape {:?}",
                self.shape
            ));
        }
        let per_row = numel(self.row_shape());
        let mut shape = self.shape.clone();
        shape[0] = range.len();
        if self.dtype == DType::String {
            let strings = self.strings[range.start * per_row..range.end * per_row].to_vec();
            return Self::from_strings(shape, strings);
        }
        let row_bytes = per_row * self.dtype.item_size();
        let data = self
            .data
            .slice(range.start * row_bytes..range.end * row_bytes);
        Self::from_bytes(self.dtype, shape, data)
    }

    /// Stacks tensors along the batch dimension. One part is returned as is
    /// (no copy); several must agree on dtype and row shape.
    pub fn concat_rows(parts: &[Tensor]) -> Result<Self, String> {
        let first = parts.first().ok_or("nothing to concatenate")?;
        if parts.len() == 1 {
            return Ok(first.clone());
        }
        if first.shape.is_empty() {
            return Err("cannot concatenate scalars along a batch dimension".into());
        }
        let mut rows = 0;
        for p in parts {
            if p.dtype != first.dtype || p.row_shape() != first.row_shape() || p.shape.is_empty() {
                return Err(format!(
                    "cannot concatenate {} {:?} with {} {:?}",
                    first.dtype, first.shape, p.dtype, p.shape
                ));
            }
            rows += p.rows();
        }
        let mut shape = first.shape.clone();
        shape[0] = rows;
        if first.dtype == DType::String {
            let strings = parts
                .iter()
                .flat_map(|p| p.strings.iter().cloned())
                .collect();
            return Self::from_strings(shape, strings);
        }
        let mut data = BytesMut::with_capacity(parts.iter().map(|p| p.data.len()).sum());
        for p in parts {
            data.extend_from_slice(&p.data);
        }
        Self::from_bytes(first.dtype, shape, data.freeze())
    }

    /// The elements of a float32 tensor as a slice of the received payload, with
    /// no copy, where the payload happens to be 4-byte aligned (None otherwise,
    /// or for other dtypes; `to_f32_vec` then copies).
    pub fn as_f32_slice(&self) -> Option<&[f32]> {
        if self.dtype != DType::Float32 || cfg!(target_endian = "big") {
            return None;
        }
        // SAFETY: every bit pattern is a valid f32, and align_to only yields the
        // aligned middle part; the payload is little-endian like the host.
        let (head, body, tail) = unsafe { self.data.align_to::<f32>() };
        (head.is_empty() && tail.is_empty()).then_some(body)
    }

    /// Every element converted to f64 (strings are an error).
    pub fn to_f64_vec(&self) -> Result<Vec<f64>, String> {
        let d = &self.data[..];
        Ok(match self.dtype {
            DType::Float32 => decode(d, |b| f64::from(f32::from_le_bytes(b))),
            DType::Float64 => decode(d, f64::from_le_bytes),
            DType::Int8 => decode(d, |b| f64::from(i8::from_le_bytes(b))),
            DType::Int16 => decode(d, |b| f64::from(i16::from_le_bytes(b))),
            DType::Int32 => decode(d, |b| f64::from(i32::from_le_bytes(b))),
            DType::Int64 => decode(d, |b| i64::from_le_bytes(b) as f64),
            DType::UInt8 | DType::Bool => d.iter().map(|&b| f64::from(b)).collect(),
            DType::String => return Err("string tensor has no numeric values".into()),
        })
    }

    /// Every element converted to f32, the agent's working precision.
    pub fn to_f32_vec(&self) -> Result<Vec<f32>, String> {
        let mut out = vec![0.0; self.numel()];
        self.copy_to_f32(&mut out)?;
        Ok(out)
    }

    /// Writes every element, converted to f32, into `out` (which must have
    /// `numel()` slots), e.g. straight into a preallocated batch buffer.
    pub fn copy_to_f32(&self, out: &mut [f32]) -> Result<(), String> {
        if out.len() != self.numel() {
            return Err(format!(
                "output has {} slots for {} elements",
                out.len(),
                self.numel()
            ));
        }
        let d = &self.data[..];
        match self.dtype {
            DType::Float32 => fill(out, d, f32::from_le_bytes),
            DType::Float64 => fill(out, d, |b| f64::from_le_bytes(b) as f32),
            DType::Int8 => fill(out, d, |b: [u8; 1]| f32::from(i8::from_le_bytes(b))),
            DType::Int16 => fill(out, d, |b| f32::from(i16::from_le_bytes(b))),
            DType::Int32 => fill(out, d, |b| i32::from_le_bytes(b) as f32),
            DType::Int64 => fill(out, d, |b| i64::from_le_bytes(b) as f32),
            DType::UInt8 | DType::Bool => fill(out, d, |b: [u8; 1]| f32::from(b[0])),
            DType::String => return Err("string tensor has no numeric values".into()),
        }
        Ok(())
    }

    /// Integer elements (floats must hold integral values).
    pub fn to_i64_vec(&self) -> Result<Vec<i64>, String> {
        let d = &self.data[..];
        match self.dtype {
            DType::Int64 => Ok(decode(d, i64::from_le_bytes)),
            DType::Int32 => Ok(decode(d, |b| i64::from(i32::from_le_bytes(b)))),
            DType::Int16 => Ok(decode(d, |b| i64::from(i16::from_le_bytes(b)))),
            DType::Int8 => Ok(decode(d, |b| i64::from(i8::from_le_bytes(b)))),
            DType::UInt8 | DType::Bool => Ok(d.iter().map(|&b| i64::from(b)).collect()),
            DType::Float32 | DType::Float64 => self
                .to_f64_vec()?
                .into_iter()
                .map(|v| {
                    if v.fract() == 0.0 && v.is_finite() {
                        Ok(v as i64)
                    } else {
                        Err(format!("{v} is not an integer"))
                    }
                })
                .collect(),
            DType::String => Err("string tensor has no numeric values".into()),
        }
    }

    /// Elements as booleans (non-zero is true).
    pub fn to_bool_vec(&self) -> Result<Vec<bool>, String> {
        Ok(self.to_f64_vec()?.into_iter().map(|v| v != 0.0).collect())
    }
}

fn encode<T, const N: usize>(values: &[T], to_le: impl Fn(&T) -> [u8; N]) -> Bytes {
    let mut out = Vec::with_capacity(values.len() * N);
    for v in values {
        out.extend_from_slice(&to_le(v));
    }
    Bytes::from(out)
}

fn decode<T, const N: usize>(data: &[u8], from_le: impl Fn([u8; N]) -> T) -> Vec<T> {
    data.chunks_exact(N)
        .map(|c| from_le(c.try_into().expect("chunks_exact yields N bytes")))
        .collect()
}

fn fill<const N: usize>(out: &mut [f32], data: &[u8], from_le: impl Fn([u8; N]) -> f32) {
    for (o, c) in out.iter_mut().zip(data.chunks_exact(N)) {
        *o = from_le(c.try_into().expect("chunks_exact yields N bytes"));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_through_proto_without_touching_values() {
        let t = Tensor::from_f64(vec![2, 2], &[1.5, -2.0, 3.25, 1e300]).unwrap();
        let back = Tensor::from_proto(t.to_proto()).unwrap();
        assert_eq!(back, t);
        assert_eq!(back.to_f64_vec().unwrap(), vec![1.5, -2.0, 3.25, 1e300]);
        assert_eq!(back.to_f32_vec().unwrap()[..3], [1.5, -2.0, 3.25]);
    }

    #[test]
    fn rejects_payload_of_wrong_length() {
        let mut p = Tensor::from_f32(vec![3], &[1.0, 2.0, 3.0])
            .unwrap()
            .to_proto();
        p.data = p.data.slice(0..8);
        let err = Tensor::from_proto(p).unwrap_err();
        assert!(err.contains("needs 12 bytes, got 8"), "{err}");
        let mut p = Tensor::from_f32(vec![1], &[1.0]).unwrap().to_proto();
        p.dtype = 0;
        assert!(Tensor::from_proto(p).unwrap_err().contains("UNSPECIFIED"));
    }

    #[test]
    fn slices_and_concatenates_rows() {
        let t = Tensor::from_i64(vec![3, 2], &[0, 1, 2, 3, 4, 5]).unwrap();
        let a = t.slice_rows(0..1).unwrap();
        let b = t.slice_rows(1..3).unwrap();
        assert_eq!(b.shape(), &[2, 2]);
        assert_eq!(b.to_i64_vec().unwrap(), vec![2, 3, 4, 5]);
        assert_eq!(Tensor::concat_rows(&[a, b]).unwrap(), t);
        let s = Tensor::from_strings(vec![2], vec!["a".into(), "b".into()]).unwrap();
        let joined = Tensor::concat_rows(&[s.clone(), s.slice_rows(1..2).unwrap()]).unwrap();
        assert_eq!(joined.strings(), ["a", "b", "b"]);
        let other = Tensor::from_f32(vec![1, 2], &[0.0, 0.0]).unwrap();
        assert!(Tensor::concat_rows(&[t, other]).is_err());
    }

    #[test]
    fn f32_payloads_are_viewed_without_copy_when_aligned() {
        let t = Tensor::from_f32(vec![2, 2], &[1.0, 2.0, 3.0, 4.0]).unwrap();
        if let Some(view) = t.as_f32_slice() {
            assert_eq!(view, &[1.0, 2.0, 3.0, 4.0]);
            assert_eq!(view.as_ptr() as *const u8, t.data().as_ptr(), "no copy");
        }
        let row = t.slice_rows(1..2).unwrap();
        assert_eq!(row.to_f32_vec().unwrap(), vec![3.0, 4.0]);
        assert!(
            Tensor::from_f64(vec![1], &[1.0])
                .unwrap()
                .as_f32_slice()
                .is_none()
        );
    }

    #[test]
    fn float_to_integer_conversion_refuses_fractions() {
        let t = Tensor::from_f32(vec![2], &[1.0, 2.5]).unwrap();
        assert!(t.to_i64_vec().unwrap_err().contains("2.5"));
        let z = Tensor::zeros(DType::Bool, vec![2, 3]);
        assert_eq!(z.to_bool_vec().unwrap(), vec![false; 6]);
    }
}
