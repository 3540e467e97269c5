//! # pf-numpy: numpy interop for streampf
//!
//! Particles, log-weights, estimates and observations in and out as `.npy` files, read and written
//! with the `npyz` crate, so that numpy (`numpy.load`, `numpy.save`) sees exactly what the filter
//! holds.
//!
//! - [`read_f32`] reads float32 or float64 arrays in C or Fortran order into a C-order
//!   [`Array`]; any other dtype, a truncated file or a pickled array is a clear [`NpyError`].
//!   [`read_finite_f32`] also refuses NaN and ±∞.
//! - [`write_f32`] writes a C-order float32 array.
//! - [`npz`]: several named arrays in one `.npz` (numpy's `savez` / `savez_compressed` /
//!   `load`), through the `zip` crate.
//! - [`particles_array`] / [`batch_from_particles`] convert between the filter's batch layout
//!   (`[(t·D + d)·M + m]`) and numpy's natural `(T, M, D)`; [`write_particles`] writes one
//!   frame's cloud and log-weights.

use std::fs::File;
use std::io::{BufReader, BufWriter, Write};
use std::path::{Path, PathBuf};

use npyz::WriterBuilder;
use pf_core::batch::BatchShape;

pub mod npz;

/// What can go wrong with a `.npy` file; every variant names the file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum NpyError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: not a readable .npy file: {message}")]
    Format { path: PathBuf, message: String },
    #[error(
        "{path}: dtype {found} is not supported: save float32 or float64 (numpy: a.astype(numpy.float32))"
    )]
    Dtype { path: PathBuf, found: String },
    #[error("{path}: shape {found:?}, expected {expected}")]
    Shape {
        path: PathBuf,
        expected: String,
        found: Vec<usize>,
    },
    #[error("{path}: value {value} at flat index {index} (C order) is not finite")]
    NotFinite {
        path: PathBuf,
        index: usize,
        value: f64,
    },
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
}

/// An n-dimensional array in C order (the last index varies fastest).
#[derive(Debug, Clone, PartialEq)]
pub struct Array<T> {
    pub shape: Vec<usize>,
    pub data: Vec<T>,
}

impl<T> Array<T> {
    /// Errors unless the shape is `expected` (`None` matches any extent).
    pub fn expect_shape(&self, path: &Path, expected: &[Option<usize>]) -> Result<(), NpyError> {
        let matches = self.shape.len() == expected.len()
            && self
                .shape
                .iter()
                .zip(expected)
                .all(|(s, e)| e.is_none_or(|e| e == *s));
        if matches {
            return Ok(());
        }
        let described: Vec<String> = expected
            .iter()
            .map(|e| e.map_or("any".to_string(), |n| n.to_string()))
            .collect();
        Err(NpyError::Shape {
            path: path.to_path_buf(),
            expected: format!("({})", described.join(", ")),
            found: self.shape.clone(),
        })
    }
}

fn io_error(path: &Path) -> impl FnOnce(std::io::Error) -> NpyError + '_ {
    move |source| NpyError::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn format_error(path: &Path, e: impl std::fmt::Display) -> NpyError {
    NpyError::Format {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

/// Reads a float32 or float64 array (C or Fortran order) as f32 in C order. float64 values
/// beyond f32's range are an error, not infinities.
pub fn read_f32(path: &Path) -> Result<Array<f32>, NpyError> {
    let file = File::open(path).map_err(io_error(path))?;
    read_f32_from(BufReader::new(file), path)
}

/// [`read_f32`] from the bytes of a `.npy` file; errors name `path` (the file, or `archive/name`
/// for a member of an `.npz`).
pub(crate) fn read_f32_from(
    mut reader: impl std::io::Read,
    path: &Path,
) -> Result<Array<f32>, NpyError> {
    let header = read_header_bytes(&mut reader, path)?;
    check_header_shape(&header, path)?;
    let reader = std::io::Read::chain(std::io::Cursor::new(header), reader);
    let npy = npyz::NpyFile::new(reader).map_err(|e| format_error(path, e))?;
    if npy.uses_pickled_array() {
        return Err(NpyError::Dtype {
            path: path.to_path_buf(),
            found: "object (pickled)".into(),
        });
    }
    let shape: Vec<usize> = npy.shape().iter().map(|&s| s as usize).collect();
    // A corrupt header can claim any shape: refuse one whose size overflows before reading.
    let expected = shape
        .iter()
        .try_fold(1usize, |n, &s| n.checked_mul(s))
        .ok_or_else(|| format_error(path, format!("shape {shape:?} overflows")))?;
    let fortran = npy.order() == npyz::Order::Fortran;
    let npyz::DType::Plain(type_str) = npy.dtype() else {
        return Err(NpyError::Dtype {
            path: path.to_path_buf(),
            found: format!("{:?}", npy.dtype()),
        });
    };
    let kind = (type_str.type_char(), type_str.size_field());
    let stored: Vec<f32> = match kind {
        (npyz::TypeChar::Float, 4) => npy.into_vec::<f32>().map_err(|e| truncated(path, e))?,
        (npyz::TypeChar::Float, 8) => {
            let wide = npy.into_vec::<f64>().map_err(|e| truncated(path, e))?;
            narrow(path, &wide, fortran, &shape)?
        }
        _ => {
            return Err(NpyError::Dtype {
                path: path.to_path_buf(),
                found: type_str.to_string(),
            });
        }
    };
    if stored.len() != expected {
        return Err(format_error(
            path,
            format!("{} values for shape {shape:?}", stored.len()),
        ));
    }
    let data = if fortran {
        fortran_to_c(&shape, &stored)
    } else {
        stored
    };
    Ok(Array { shape, data })
}

/// The bytes of a `.npy` header: magic, version, length and the header dict (`npyz` reads them
/// again from these bytes).
fn read_header_bytes(reader: &mut impl std::io::Read, path: &Path) -> Result<Vec<u8>, NpyError> {
    let mut start = [0u8; 10];
    reader
        .read_exact(&mut start)
        .map_err(|e| truncated(path, e))?;
    if &start[..6] != b"\x93NUMPY" {
        return Err(format_error(path, "no .npy magic string (not a .npy file)"));
    }
    // Version 1 has a 2-byte header length; versions 2 and 3 a 4-byte one.
    let (length, mut bytes) = if start[6] == 1 {
        (
            usize::from(u16::from_le_bytes([start[8], start[9]])),
            start.to_vec(),
        )
    } else {
        let mut more = [0u8; 2];
        reader
            .read_exact(&mut more)
            .map_err(|e| truncated(path, e))?;
        let length = u32::from_le_bytes([start[8], start[9], more[0], more[1]]) as usize;
        let mut bytes = start.to_vec();
        bytes.extend(more);
        (length, bytes)
    };
    if length > 1 << 20 {
        return Err(format_error(path, format!("a header of {length} bytes")));
    }
    let at = bytes.len();
    bytes.resize(at + length, 0);
    reader
        .read_exact(&mut bytes[at..])
        .map_err(|e| truncated(path, e))?;
    Ok(bytes)
}

/// Refuses a header whose shape's element count overflows (`npyz` multiplies it unchecked).
fn check_header_shape(header: &[u8], path: &Path) -> Result<(), NpyError> {
    let text = String::from_utf8_lossy(header);
    let Some(at) = text.find("'shape'") else {
        return Ok(()); // npyz reports the missing key
    };
    let tuple = text[at..]
        .split_once('(')
        .and_then(|(_, rest)| rest.split_once(')'))
        .map_or("", |(inside, _)| inside);
    let mut count: u64 = 1;
    for extent in tuple.split(',').map(str::trim).filter(|t| !t.is_empty()) {
        let extent: u64 = extent.trim_end_matches('L').parse().map_err(|_| {
            format_error(
                path,
                format!("shape extent {extent:?} is not a whole number"),
            )
        })?;
        count = count
            .checked_mul(extent)
            .ok_or_else(|| format_error(path, format!("shape ({tuple}) overflows")))?;
    }
    Ok(())
}

fn truncated(path: &Path, e: std::io::Error) -> NpyError {
    format_error(path, format!("{e} (is the file truncated?)"))
}

/// f64 → f32, refusing finite values f32 cannot hold. Indices in errors are C order.
fn narrow(path: &Path, wide: &[f64], fortran: bool, shape: &[usize]) -> Result<Vec<f32>, NpyError> {
    let mut out = Vec::with_capacity(wide.len());
    for (i, &v) in wide.iter().enumerate() {
        let x = v as f32;
        if v.is_finite() && !x.is_finite() {
            let index = if fortran {
                fortran_index_to_c(shape, i)
            } else {
                i
            };
            return Err(NpyError::Invalid {
                path: path.to_path_buf(),
                message: format!("float64 value {v} at flat index {index} does not fit in float32"),
            });
        }
        out.push(x);
    }
    Ok(out)
}

/// The C-order flat index of the element stored at Fortran-order position `i`.
fn fortran_index_to_c(shape: &[usize], mut i: usize) -> usize {
    let mut index = vec![0; shape.len()];
    for (k, &n) in shape.iter().enumerate() {
        index[k] = i % n.max(1);
        i /= n.max(1);
    }
    index
        .iter()
        .zip(shape)
        .fold(0, |acc, (&ix, &n)| acc * n + ix)
}

/// Reorders Fortran-order values to C order.
fn fortran_to_c<T: Copy + Default>(shape: &[usize], stored: &[T]) -> Vec<T> {
    let mut out = vec![T::default(); stored.len()];
    for (i, &v) in stored.iter().enumerate() {
        out[fortran_index_to_c(shape, i)] = v;
    }
    out
}

/// [`read_f32`], refusing NaN and ±∞ (observations, initial clouds).
pub fn read_finite_f32(path: &Path) -> Result<Array<f32>, NpyError> {
    refuse_non_finite(read_f32(path)?, path)
}

pub(crate) fn refuse_non_finite(array: Array<f32>, path: &Path) -> Result<Array<f32>, NpyError> {
    if let Some((index, &value)) = array.data.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(NpyError::NotFinite {
            path: path.to_path_buf(),
            index,
            value: f64::from(value),
        });
    }
    Ok(array)
}

/// Writes `data` (C order) as a float32 array of `shape`.
pub fn write_f32(path: &Path, shape: &[usize], data: &[f32]) -> Result<(), NpyError> {
    check_shape(path, shape, data)?;
    let file = File::create(path).map_err(io_error(path))?;
    let mut out = BufWriter::new(file);
    write_f32_to(&mut out, path, shape, data)?;
    out.flush().map_err(io_error(path))
}

pub(crate) fn check_shape(path: &Path, shape: &[usize], data: &[f32]) -> Result<(), NpyError> {
    let expected: usize = shape.iter().product();
    if expected != data.len() {
        return Err(NpyError::Invalid {
            path: path.to_path_buf(),
            message: format!("{} values for shape {shape:?}", data.len()),
        });
    }
    Ok(())
}

/// The bytes of a float32 `.npy` file of `shape` into `out` (the shape already checked).
pub(crate) fn write_f32_to(
    mut out: impl Write,
    path: &Path,
    shape: &[usize],
    data: &[f32],
) -> Result<(), NpyError> {
    let dims: Vec<u64> = shape.iter().map(|&s| s as u64).collect();
    let mut writer = npyz::WriteOptions::new()
        .default_dtype()
        .shape(&dims)
        .writer(&mut out)
        .begin_nd()
        .map_err(io_error(path))?;
    writer
        .extend(data.iter().copied())
        .map_err(io_error(path))?;
    writer.finish().map_err(io_error(path))
}

/// The batch layout `[(t·D + d)·M + m]` as a `(T, M, D)` C-order array.
pub fn particles_array(shape: &BatchShape, states: &[f32]) -> Array<f32> {
    let (t_count, m_count, d_count) = (shape.targets, shape.particles, shape.dims);
    let mut data = Vec::with_capacity(t_count * m_count * d_count);
    for t in 0..t_count {
        for m in 0..m_count {
            for d in 0..d_count {
                data.push(states[shape.state_index(t, d, m)]);
            }
        }
    }
    Array {
        shape: vec![t_count, m_count, d_count],
        data,
    }
}

/// A `(T, M, D)` array back into the batch layout for `shape`.
pub fn batch_from_particles(
    path: &Path,
    shape: &BatchShape,
    array: &Array<f32>,
) -> Result<Vec<f32>, NpyError> {
    array.expect_shape(
        path,
        &[Some(shape.targets), Some(shape.particles), Some(shape.dims)],
    )?;
    let mut states = vec![0.0; shape.state_len()];
    let (m_count, d_count) = (shape.particles, shape.dims);
    for (i, &v) in array.data.iter().enumerate() {
        let (t, m, d) = (
            i / (m_count * d_count),
            (i / d_count) % m_count,
            i % d_count,
        );
        states[shape.state_index(t, d, m)] = v;
    }
    Ok(states)
}

/// Writes one frame's particles to `dir`: `particles_FRAME.npy`, `(T, M, D)` float32, and
/// `log_weights_FRAME.npy`, `(T, M)` (the frame number zero-padded to six digits).
pub fn write_particles(
    dir: &Path,
    frame: usize,
    shape: &BatchShape,
    states: &[f32],
    log_weights: &[f32],
) -> Result<(), NpyError> {
    let particles = particles_array(shape, states);
    write_f32(
        &dir.join(format!("particles_{frame:06}.npy")),
        &particles.shape,
        &particles.data,
    )?;
    write_f32(
        &dir.join(format!("log_weights_{frame:06}.npy")),
        &[shape.targets, shape.particles],
        log_weights,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A fuzzing finding kept as a regression: a shape whose element count overflows u64 was
    /// multiplied unchecked inside npyz (a panic in debug builds).
    #[test]
    fn a_header_whose_shape_overflows_is_a_format_error() {
        let dict =
            "{'descr': '<f4', 'fortran_order': False, 'shape': (3, 4, 18446744073709551610), }";
        let mut header = format!("{dict:<117}\n").into_bytes();
        let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
        bytes.extend((header.len() as u16).to_le_bytes());
        bytes.append(&mut header);
        let err = read_f32_from(bytes.as_slice(), Path::new("big.npy")).unwrap_err();
        assert!(
            matches!(err, NpyError::Format { .. }) && err.to_string().contains("overflows"),
            "{err}"
        );
        let err = read_f32_from(&b"\x93NUMPY\x01"[..], Path::new("cut.npy")).unwrap_err();
        assert!(err.to_string().contains("truncated"), "{err}");
    }

    #[test]
    fn fortran_order_maps_to_c_order() {
        // shape (2, 3): Fortran stores a00 a10 a01 a11 a02 a12.
        let stored = [0, 3, 1, 4, 2, 5];
        assert_eq!(fortran_to_c(&[2, 3], &stored), vec![0, 1, 2, 3, 4, 5]);
        assert_eq!(fortran_to_c(&[4], &[1, 2, 3, 4]), vec![1, 2, 3, 4]);
    }

    #[test]
    fn particles_round_trip_through_the_tmd_layout() {
        let shape = BatchShape::new(2, 3, 4).unwrap();
        let states: Vec<f32> = (0..shape.state_len()).map(|i| i as f32).collect();
        let array = particles_array(&shape, &states);
        assert_eq!(array.shape, vec![2, 3, 4]);
        // Target 1, particle 2, dimension 3.
        assert_eq!(
            array.data[(3 + 2) * 4 + 3],
            states[shape.state_index(1, 3, 2)]
        );
        let back = batch_from_particles(Path::new("x.npy"), &shape, &array).unwrap();
        assert_eq!(back, states);
    }
}
