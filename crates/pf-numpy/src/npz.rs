//! Several named float32 arrays in one `.npz` file: what numpy's `savez` and `savez_compressed`
//! write and `numpy.load` reads (a zip archive of `NAME.npy` members). The archive is the `zip`
//! crate's; each member is read and written as [`crate::read_f32`] and [`crate::write_f32`] do.

use std::fs::File;
use std::io::{BufReader, BufWriter, Write};
use std::path::{Path, PathBuf};

use zip::write::SimpleFileOptions;

use crate::{
    Array, NpyError, check_shape, io_error, read_f32_from, refuse_non_finite, write_f32_to,
};

/// The path errors name for member `name` of `archive`.
fn member_path(archive: &Path, name: &str) -> PathBuf {
    archive.join(format!("{name}.npy"))
}

fn zip_error(path: &Path, e: zip::result::ZipError) -> NpyError {
    NpyError::Format {
        path: path.to_path_buf(),
        message: format!("not a readable .npz (zip) archive: {e}"),
    }
}

/// Writes `arrays` — (name, shape, C-order values) — as one deflate-compressed `.npz`
/// (`numpy.load(path)["name"]`). Names must be unique, non-empty and free of `/`.
pub fn write_npz(path: &Path, arrays: &[(&str, &[usize], &[f32])]) -> Result<(), NpyError> {
    for (k, (name, shape, data)) in arrays.iter().enumerate() {
        if name.is_empty() || name.contains('/') || arrays[..k].iter().any(|(n, ..)| n == name) {
            return Err(NpyError::Invalid {
                path: path.to_path_buf(),
                message: format!("array name {name:?} is empty, has a '/' or is repeated"),
            });
        }
        check_shape(&member_path(path, name), shape, data)?;
    }
    let file = File::create(path).map_err(io_error(path))?;
    let mut zip = zip::ZipWriter::new(BufWriter::new(file));
    let options = SimpleFileOptions::default().compression_method(zip::CompressionMethod::Deflated);
    for (name, shape, data) in arrays {
        let member = member_path(path, name);
        zip.start_file(format!("{name}.npy"), options)
            .map_err(|e| zip_error(path, e))?;
        write_f32_to(&mut zip, &member, shape, data)?;
    }
    let mut out = zip.finish().map_err(|e| zip_error(path, e))?;
    out.flush().map_err(io_error(path))
}

/// A `.npz` opened for reading its arrays by name.
pub struct NpzReader {
    path: PathBuf,
    archive: zip::ZipArchive<BufReader<File>>,
}

impl NpzReader {
    /// Opens `path`; an error when it is not a zip archive (numpy's `.npz`).
    pub fn open(path: &Path) -> Result<Self, NpyError> {
        let file = File::open(path).map_err(io_error(path))?;
        let archive = zip::ZipArchive::new(BufReader::new(file)).map_err(|e| zip_error(path, e))?;
        Ok(Self {
            path: path.to_path_buf(),
            archive,
        })
    }

    /// The names of its arrays (the members' names less `.npy`), in archive order.
    pub fn names(&self) -> Vec<String> {
        self.archive
            .file_names()
            .filter_map(|n| n.ok())
            .filter_map(|n| n.strip_suffix(".npy").map(str::to_string))
            .collect()
    }

    /// Array `name` as [`crate::read_f32`] reads a `.npy` (float32 or float64, C or Fortran
    /// order); an error names the archive, the array and, for a missing one, those it has.
    pub fn read_f32(&mut self, name: &str) -> Result<Array<f32>, NpyError> {
        let member = member_path(&self.path, name);
        let names = self.names();
        let entry =
            self.archive
                .by_name(&format!("{name}.npy"))
                .map_err(|_| NpyError::Invalid {
                    path: self.path.clone(),
                    message: format!("no array named {name:?} (it has {names:?})"),
                })?;
        read_f32_from(entry, &member)
    }

    /// [`NpzReader::read_f32`], refusing NaN and ±∞.
    pub fn read_finite_f32(&mut self, name: &str) -> Result<Array<f32>, NpyError> {
        let member = member_path(&self.path, name);
        refuse_non_finite(self.read_f32(name)?, &member)
    }
}
