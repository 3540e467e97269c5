//! Point clouds in PLY (ASCII and binary little-endian): the per-frame input of the tracker.
//!
//! Only the `vertex` element's `x`, `y`, `z` are read; other vertex properties (colours,
//! normals, of any scalar type) are skipped, and elements after the vertices are ignored. Every
//! malformed file is an error that says what is wrong and where; a non-finite point is an error
//! naming its vertex.

use std::path::Path;

use nalgebra::Vector3;

use crate::error::BodyError;

#[derive(Debug, Clone, Copy, PartialEq)]
enum Format {
    Ascii,
    BinaryLittleEndian,
}

/// A scalar property type and its size in bytes.
fn scalar_size(ty: &str) -> Option<usize> {
    Some(match ty {
        "char" | "uchar" | "int8" | "uint8" => 1,
        "short" | "ushort" | "int16" | "uint16" => 2,
        "int" | "uint" | "int32" | "uint32" | "float" | "float32" => 4,
        "double" | "float64" => 8,
        _ => return None,
    })
}

struct Header {
    format: Format,
    vertices: usize,
    /// (type, name) of each vertex property, in order.
    properties: Vec<(String, String)>,
    /// Byte offset of the data.
    data_start: usize,
}

fn bad(message: impl Into<String>) -> BodyError {
    BodyError::InvalidInput(format!("PLY: {}", message.into()))
}

/// The header's text (from `ply` to before `end_header`) and where the data starts.
fn header_text(bytes: &[u8]) -> Result<(&str, usize), BodyError> {
    if bytes.is_empty() {
        return Err(bad("the file is empty"));
    }
    let end = bytes
        .windows(10)
        .position(|w| w == b"end_header")
        .ok_or_else(|| bad("no end_header line (not a PLY file, or truncated)"))?;
    let mut data_start = end + 10;
    // The header ends with a newline (\n or \r\n).
    if bytes.get(data_start) == Some(&b'\r') {
        data_start += 1;
    }
    if bytes.get(data_start) == Some(&b'\n') {
        data_start += 1;
    }
    let text = std::str::from_utf8(&bytes[..end]).map_err(|_| bad("the header is not text"))?;
    Ok((text, data_start))
}

fn parse_header(bytes: &[u8]) -> Result<Header, BodyError> {
    let (text, data_start) = header_text(bytes)?;
    let mut lines = text.lines().map(str::trim);
    if lines.next() != Some("ply") {
        return Err(bad("the first line is not \"ply\""));
    }
    let mut format = None;
    let mut vertices = None;
    let mut properties = Vec::new();
    let mut in_vertex = false;
    let mut seen_other_element_first = false;
    for (n, line) in lines.enumerate() {
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            [] | ["comment", ..] | ["obj_info", ..] => {}
            ["format", "ascii", _] => format = Some(Format::Ascii),
            ["format", "binary_little_endian", _] => format = Some(Format::BinaryLittleEndian),
            ["format", other, ..] => {
                return Err(bad(format!(
                    "format {other} is not supported (ascii or binary_little_endian)"
                )));
            }
            ["element", "vertex", count] => {
                if vertices.is_some() {
                    return Err(bad("two vertex elements"));
                }
                if seen_other_element_first {
                    return Err(bad("the vertex element must come first"));
                }
                vertices = Some(
                    count
                        .parse::<usize>()
                        .map_err(|_| bad(format!("vertex count {count:?} is not a number")))?,
                );
                in_vertex = true;
            }
            ["element", ..] => {
                if vertices.is_none() {
                    seen_other_element_first = true;
                }
                in_vertex = false;
            }
            ["property", "list", ..] if in_vertex => {
                return Err(bad("list properties on vertices are not supported"));
            }
            ["property", ty, name] if in_vertex => {
                if scalar_size(ty).is_none() {
                    return Err(bad(format!("vertex property {name} has unknown type {ty}")));
                }
                properties.push((ty.to_string(), name.to_string()));
            }
            ["property", ..] => {}
            _ => {
                return Err(bad(format!(
                    "header line {} is not understood: {line:?}",
                    n + 2
                )));
            }
        }
    }
    let format = format.ok_or_else(|| bad("no format line"))?;
    let vertices = vertices.ok_or_else(|| bad("no vertex element"))?;
    for axis in ["x", "y", "z"] {
        if !properties.iter().any(|(_, name)| name == axis) {
            return Err(bad(format!("the vertices have no {axis} property")));
        }
    }
    Ok(Header {
        format,
        vertices,
        properties,
        data_start,
    })
}

fn read_scalar(ty: &str, b: &[u8]) -> f64 {
    match ty {
        "char" | "int8" => f64::from(b[0] as i8),
        "uchar" | "uint8" => f64::from(b[0]),
        "short" | "int16" => f64::from(i16::from_le_bytes([b[0], b[1]])),
        "ushort" | "uint16" => f64::from(u16::from_le_bytes([b[0], b[1]])),
        "int" | "int32" => f64::from(i32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        "uint" | "uint32" => f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        "float" | "float32" => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        _ => f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]),
    }
}

/// Parses a PLY file's bytes into points.
pub fn parse_ply(bytes: &[u8]) -> Result<Vec<Vector3<f32>>, BodyError> {
    let header = parse_header(bytes)?;
    let index = |axis: &str| {
        header
            .properties
            .iter()
            .position(|(_, n)| n == axis)
            .unwrap_or(0)
    };
    let (ix, iy, iz) = (index("x"), index("y"), index("z"));
    let data = &bytes[header.data_start..];
    let points = match header.format {
        Format::Ascii => ascii_vertices(&header, data, [ix, iy, iz])?,
        Format::BinaryLittleEndian => binary_vertices(&header, data, [ix, iy, iz])?,
    };
    if let Some(v) = points.iter().position(|p| !p.iter().all(|x| x.is_finite())) {
        let p = points[v];
        return Err(bad(format!(
            "vertex {v} is not finite: ({}, {}, {})",
            p.x, p.y, p.z
        )));
    }
    Ok(points)
}

/// The vertices of an ASCII body, one per line; `xyz` are the x, y, z properties' indices.
fn ascii_vertices(
    header: &Header,
    data: &[u8],
    [ix, iy, iz]: [usize; 3],
) -> Result<Vec<Vector3<f32>>, BodyError> {
    let mut points = Vec::with_capacity(header.vertices.min(1 << 24));
    let text = std::str::from_utf8(data).map_err(|_| bad("the vertex data is not text"))?;
    let mut lines = text.lines().filter(|l| !l.trim().is_empty());
    for v in 0..header.vertices {
        let line = lines.next().ok_or_else(|| {
            bad(format!(
                "the file ends after {v} of {} vertices",
                header.vertices
            ))
        })?;
        let values: Vec<&str> = line.split_whitespace().collect();
        if values.len() < header.properties.len() {
            return Err(bad(format!(
                "vertex {v} has {} values, expected {}",
                values.len(),
                header.properties.len()
            )));
        }
        let get = |i: usize| -> Result<f32, BodyError> {
            values[i]
                .parse::<f32>()
                .map_err(|_| bad(format!("vertex {v}: {:?} is not a number", values[i])))
        };
        points.push(Vector3::new(get(ix)?, get(iy)?, get(iz)?));
    }
    Ok(points)
}

/// The vertices of a binary little-endian body, fixed-size records; `xyz` as above.
fn binary_vertices(
    header: &Header,
    data: &[u8],
    [ix, iy, iz]: [usize; 3],
) -> Result<Vec<Vector3<f32>>, BodyError> {
    let sizes: Vec<usize> = header
        .properties
        .iter()
        .map(|(ty, _)| scalar_size(ty).unwrap_or(4))
        .collect();
    let stride: usize = sizes.iter().sum();
    let needed = stride
        .checked_mul(header.vertices)
        .ok_or_else(|| bad("the vertex count is too large"))?;
    if data.len() < needed {
        return Err(bad(format!(
            "the file holds {} bytes of vertex data, {} vertices need {needed}",
            data.len(),
            header.vertices
        )));
    }
    let offsets: Vec<usize> = sizes
        .iter()
        .scan(0, |acc, s| {
            let o = *acc;
            *acc += s;
            Some(o)
        })
        .collect();
    let record = |v: usize| &data[v * stride..(v + 1) * stride];
    Ok((0..header.vertices)
        .map(|v| {
            let get =
                |i: usize| read_scalar(&header.properties[i].0, &record(v)[offsets[i]..]) as f32;
            Vector3::new(get(ix), get(iy), get(iz))
        })
        .collect())
}

/// Reads a PLY point cloud.
pub fn read_ply(path: &Path) -> Result<Vec<Vector3<f32>>, BodyError> {
    let file_error = |message: String| BodyError::File {
        path: path.display().to_string(),
        message,
    };
    let bytes = std::fs::read(path).map_err(|e| file_error(e.to_string()))?;
    // The parser's message already says "PLY: ..."; the file's name leads it once.
    parse_ply(&bytes).map_err(|e| match e {
        BodyError::InvalidInput(message) => file_error(message),
        other => file_error(other.to_string()),
    })
}

/// Writes points as a binary little-endian PLY (x, y, z as float).
pub fn write_ply_binary(path: &Path, points: &[Vector3<f32>]) -> Result<(), BodyError> {
    let mut bytes = format!(
        "ply\nformat binary_little_endian 1.0\ncomment streampf\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nend_header\n",
        points.len()
    )
    .into_bytes();
    for p in points {
        for x in p.iter() {
            bytes.extend_from_slice(&x.to_le_bytes());
        }
    }
    std::fs::write(path, bytes)
        .map_err(|e| BodyError::InvalidInput(format!("writing {}: {e}", path.display())))
}

/// The points as an ASCII PLY text.
pub fn ply_ascii(points: &[Vector3<f32>]) -> String {
    let mut text = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nend_header\n",
        points.len()
    );
    for p in points {
        text.push_str(&format!("{} {} {}\n", p.x, p.y, p.z));
    }
    text
}
