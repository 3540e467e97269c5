//! Checking the numpy arrays a caller passes, before any work: a wrong type, dtype, shape,
//! memory order or a non-finite value is a `ValueError` that names the argument.

use face_tracker::GrayImage;
use numpy::{
    Element, IntoPyArray, PyArrayDescrMethods, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn,
    PyUntypedArray, PyUntypedArrayMethods, dtype,
};
use pyo3::prelude::*;

use crate::errors::value_error;

/// `obj` as a read-only C-ordered array of `T`; `dtype_name` is numpy's name for `T`.
pub fn contiguous<'py, T: Element>(
    obj: &Bound<'py, PyAny>,
    what: &str,
    dtype_name: &str,
) -> PyResult<PyReadonlyArrayDyn<'py, T>> {
    let py = obj.py();
    let untyped = obj.cast::<PyUntypedArray>().map_err(|_| {
        let type_name = obj
            .get_type()
            .name()
            .map(|n| n.to_string())
            .unwrap_or_else(|_| "an unknown type".into());
        value_error(format!(
            "{what} must be a numpy array of {dtype_name}, got {type_name}"
        ))
    })?;
    if !untyped.dtype().is_equiv_to(&dtype::<T>(py)) {
        return Err(value_error(format!(
            "{what} must have dtype {dtype_name}, got {} (convert with .astype(numpy.{dtype_name}))",
            untyped.dtype()
        )));
    }
    if !untyped.is_c_contiguous() {
        return Err(value_error(format!(
            "{what} is not C-contiguous (a slice, a transpose or a stride?): pass \
             numpy.ascontiguousarray({what})"
        )));
    }
    let typed = obj
        .cast::<PyArrayDyn<T>>()
        .map_err(|e| value_error(format!("{what}: {e}")))?;
    typed
        .try_readonly()
        .map_err(|e| value_error(format!("{what} cannot be read: {e}")))
}

/// The shape of `array`, checked against `expected` (`None`: any length in that axis).
pub fn check_shape(shape: &[usize], expected: &[Option<usize>], what: &str) -> PyResult<()> {
    let fits = shape.len() == expected.len()
        && shape
            .iter()
            .zip(expected)
            .all(|(s, e)| e.is_none_or(|e| e == *s));
    if fits {
        return Ok(());
    }
    let wanted: Vec<String> = expected
        .iter()
        .map(|e| e.map_or("n".to_string(), |e| e.to_string()))
        .collect();
    Err(value_error(format!(
        "{what} must have shape ({}), got {shape:?}",
        wanted.join(", ")
    )))
}

/// A `ValueError` at the first NaN or infinity of `values`.
pub fn check_finite(values: &[f32], what: &str) -> PyResult<()> {
    match values.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(i) => Err(value_error(format!(
            "{what} holds a non-finite value ({}) at flat index {i}",
            values[i]
        ))),
    }
}

/// `obj` as a C-ordered float32 array of the given shape with finite values, copied out.
pub fn finite_f32(
    obj: &Bound<'_, PyAny>,
    expected: &[Option<usize>],
    what: &str,
) -> PyResult<(Vec<usize>, Vec<f32>)> {
    let array = contiguous::<f32>(obj, what, "float32")?;
    let shape = array.shape().to_vec();
    check_shape(&shape, expected, what)?;
    let values = array
        .as_slice()
        .map_err(|e| value_error(format!("{what}: {e}")))?;
    check_finite(values, what)?;
    Ok((shape, values.to_vec()))
}

/// The order of a colour frame's channels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ChannelOrder {
    Rgb,
    Bgr,
}

impl ChannelOrder {
    pub fn parse(name: &str) -> PyResult<Self> {
        match name.to_ascii_lowercase().as_str() {
            "rgb" => Ok(Self::Rgb),
            "bgr" => Ok(Self::Bgr),
            other => Err(value_error(format!(
                "channel_order must be \"rgb\" or \"bgr\" (OpenCV's), got {other:?}"
            ))),
        }
    }
}

/// ITU-R BT.601 luma, as OpenCV's `COLOR_RGB2GRAY` and FFmpeg's RGB-to-gray conversion:
/// Y = 0.299 R + 0.587 G + 0.114 B, rounded to the nearest level.
pub fn luma(r: u8, g: u8, b: u8) -> u8 {
    ((299 * u32::from(r) + 587 * u32::from(g) + 114 * u32::from(b) + 500) / 1000) as u8
}

/// A frame (`uint8`, H×W gray or H×W×3 colour) as the tracker's gray image of `size`, reusing
/// `buffer`'s allocation.
pub fn gray_frame(
    frame: &Bound<'_, PyAny>,
    size: (u32, u32),
    order: ChannelOrder,
    buffer: Vec<u8>,
) -> PyResult<GrayImage> {
    let array = contiguous::<u8>(frame, "frame", "uint8")?;
    let (w, h) = (size.0 as usize, size.1 as usize);
    let shape = array.shape().to_vec();
    let colour = match shape.as_slice() {
        [rows, cols] if (*rows, *cols) == (h, w) => false,
        [rows, cols, 3] if (*rows, *cols) == (h, w) => true,
        _ => {
            return Err(value_error(format!(
                "frame must have shape ({h}, {w}) (gray) or ({h}, {w}, 3) (colour), the \
                 tracker's frame size; got {shape:?}"
            )));
        }
    };
    let pixels = array
        .as_slice()
        .map_err(|e| value_error(format!("frame: {e}")))?;
    let mut data = buffer;
    data.clear();
    if colour {
        let (r, b) = match order {
            ChannelOrder::Rgb => (0, 2),
            ChannelOrder::Bgr => (2, 0),
        };
        data.extend(pixels.chunks_exact(3).map(|p| luma(p[r], p[1], p[b])));
    } else {
        data.extend_from_slice(pixels);
    }
    GrayImage::new(size.0, size.1, data).map_err(crate::errors::face)
}

/// `data` (row-major) as a numpy array of `shape`.
pub fn to_numpy<'py, T: Element>(
    py: Python<'py>,
    data: Vec<T>,
    shape: &[usize],
) -> PyResult<Bound<'py, PyAny>> {
    // One numpy array that takes over the Vec (no copy, one C-API call).
    let array = numpy::ndarray::ArrayD::from_shape_vec(numpy::ndarray::IxDyn(shape), data)
        .map_err(|e| value_error(format!("an output of shape {shape:?}: {e}")))?;
    Ok(array.into_pyarray(py).into_any())
}
