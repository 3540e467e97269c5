//! A reader for dlib's binary serialisation, as far as a `shape_predictor` needs it.
//!
//! dlib writes an integer as one header byte (the number of value bytes that follow, with 0x80
//! set for a negative value) and then those bytes, little end first. A float is an `int64`
//! mantissa and an `int16` exponent in that integer format (value = m·2^e); the exponents
//! 32000/32001/32002 stand for +∞, −∞ and NaN. A `std::vector` is its length (an unsigned
//! integer) and then its elements; a `matrix` is −rows, −cols (negative since dlib 18.x, to tell
//! the new layout from the old) and then its elements in row order.

/// What went wrong, and where (byte offset), while reading.
#[derive(Debug, Clone, PartialEq)]
pub struct FormatError {
    pub offset: usize,
    pub message: String,
}

impl std::fmt::Display for FormatError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "at byte {}: {}", self.offset, self.message)
    }
}

/// Reads dlib-serialised values from a byte slice, front to back.
pub struct Reader<'a> {
    bytes: &'a [u8],
    offset: usize,
}

impl<'a> Reader<'a> {
    pub fn new(bytes: &'a [u8]) -> Self {
        Self { bytes, offset: 0 }
    }

    /// Bytes not read yet.
    pub fn remaining(&self) -> usize {
        self.bytes.len() - self.offset
    }

    pub fn error(&self, message: impl Into<String>) -> FormatError {
        FormatError {
            offset: self.offset,
            message: message.into(),
        }
    }

    /// An integer of at most `max_bytes` value bytes, as i64 (sign from the header).
    fn int(&mut self, max_bytes: u8, what: &str) -> Result<i64, FormatError> {
        let Some(&header) = self.bytes.get(self.offset) else {
            return Err(self.error(format!("the file ends where {what} should be")));
        };
        let size = header & 0x0f;
        if header & 0x70 != 0 || size == 0 || size > max_bytes {
            return Err(self.error(format!(
                "{what}: 0x{header:02x} is not a dlib integer header of at most {max_bytes} bytes"
            )));
        }
        let start = self.offset + 1;
        let Some(body) = self.bytes.get(start..start + size as usize) else {
            return Err(self.error(format!("the file ends inside {what}")));
        };
        let magnitude = body
            .iter()
            .rev()
            .fold(0u64, |acc, &b| (acc << 8) | u64::from(b));
        if magnitude > i64::MAX as u64 {
            return Err(self.error(format!("{what} does not fit in 64 bits")));
        }
        self.offset = start + size as usize;
        let value = magnitude as i64;
        Ok(if header & 0x80 != 0 { -value } else { value })
    }

    /// A non-negative integer (a count or an index).
    pub fn unsigned(&mut self, what: &str) -> Result<u64, FormatError> {
        let start = self.offset;
        let value = self.int(8, what)?;
        u64::try_from(value).map_err(|_| FormatError {
            offset: start,
            message: format!("{what} is negative ({value})"),
        })
    }

    /// A signed integer.
    pub fn signed(&mut self, what: &str) -> Result<i64, FormatError> {
        self.int(8, what)
    }

    /// A float, as dlib's (mantissa, exponent) pair.
    pub fn float(&mut self, what: &str) -> Result<f32, FormatError> {
        let mantissa = self.int(8, what)?;
        let exponent = self.int(2, what)?;
        Ok(match exponent {
            32000 => f32::INFINITY,
            32001 => f32::NEG_INFINITY,
            32002 => f32::NAN,
            e => (mantissa as f64 * 2f64.powi(e as i32)) as f32,
        })
    }

    /// A length that must be plausible for what follows: at most `limit` and at most one element
    /// per remaining byte (every element takes at least one), so a corrupt count fails here
    /// instead of asking for gigabytes.
    pub fn length(&mut self, what: &str, limit: u64) -> Result<usize, FormatError> {
        let start = self.offset;
        let n = self.unsigned(what)?;
        if n > limit || n > self.remaining() as u64 {
            return Err(FormatError {
                offset: start,
                message: format!("{what} is {n}, more than this file can hold"),
            });
        }
        Ok(n as usize)
    }

    /// A column vector of floats (`matrix<float,0,1>`).
    pub fn float_column(&mut self, what: &str) -> Result<Vec<f32>, FormatError> {
        let start = self.offset;
        let rows = self.signed(what)?;
        let cols = self.signed(what)?;
        // The new layout writes negated sizes; dlib still reads the old (positive) one.
        let (rows, cols) = (rows.unsigned_abs(), cols.unsigned_abs());
        if cols != 1 {
            return Err(FormatError {
                offset: start,
                message: format!("{what}: expected a column vector, found a {rows}x{cols} matrix"),
            });
        }
        // Every float takes at least one byte: more rows than bytes left is a cut file.
        if rows > self.remaining() as u64 {
            return Err(FormatError {
                offset: start,
                message: format!(
                    "{what}: a column of {rows} values, but only {} bytes are left (is the file truncated?)",
                    self.remaining()
                ),
            });
        }
        (0..rows).map(|_| self.float(what)).collect()
    }
}

/// dlib's integer writer (`pack_int`), for tests that build model files.
#[cfg(test)]
pub(crate) fn pack(value: i64) -> Vec<u8> {
    let mut magnitude = value.unsigned_abs();
    let mut body = Vec::new();
    loop {
        body.push((magnitude & 0xff) as u8);
        magnitude >>= 8;
        if magnitude == 0 {
            break;
        }
    }
    let mut out = vec![body.len() as u8 | if value < 0 { 0x80 } else { 0 }];
    out.extend(body);
    out
}

/// dlib's float writer for values that are exact in 2^-20 steps (enough for tests).
#[cfg(test)]
pub(crate) fn pack_float(value: f32) -> Vec<u8> {
    let mut out = pack((value as f64 * 1048576.0).round() as i64);
    out.extend(pack(-20));
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integers_round_trip() {
        for v in [0i64, 1, -1, 255, 256, -70000, i64::MAX, -i64::MAX] {
            let bytes = pack(v);
            let mut r = Reader::new(&bytes);
            assert_eq!(r.signed("v").unwrap(), v);
            assert_eq!(r.remaining(), 0);
        }
        assert_eq!(pack(0), vec![1, 0], "dlib writes zero as one byte");
    }

    #[test]
    fn floats_are_mantissa_times_two_to_the_exponent() {
        let mut bytes = pack(3);
        bytes.extend(pack(-2));
        bytes.extend(pack(1));
        bytes.extend(pack(32002));
        let mut r = Reader::new(&bytes);
        assert_eq!(r.float("x").unwrap(), 0.75);
        assert!(r.float("y").unwrap().is_nan());
    }

    #[test]
    fn truncated_and_corrupt_input_is_an_error_with_its_offset() {
        let bytes = [0x02, 0x10];
        let e = Reader::new(&bytes).signed("the count").unwrap_err();
        assert!(e.message.contains("ends inside the count"), "{e}");
        let e = Reader::new(&[0x31]).signed("x").unwrap_err();
        assert!(e.message.contains("not a dlib integer header"), "{e}");
        let mut long = pack(1_000_000);
        long.push(0);
        let e = Reader::new(&long)
            .length("a vector's length", u64::MAX)
            .unwrap_err();
        assert!(e.message.contains("more than this file can hold"), "{e}");
        let e = Reader::new(&pack(-4)).unsigned("an index").unwrap_err();
        assert!(e.message.contains("negative"), "{e}");
        // A column of 136 values cut after two of them: truncated, not "not a column".
        let mut cut = pack(-136);
        cut.extend(pack(-1));
        cut.extend([pack(3), pack(0)].concat().repeat(2));
        let e = Reader::new(&cut)
            .float_column("the mean shape")
            .unwrap_err();
        assert!(
            e.message.contains("136 values") && e.message.contains("truncated"),
            "{e}"
        );
        let mut wide = pack(-2);
        wide.extend(pack(-3));
        let e = Reader::new(&wide).float_column("a column").unwrap_err();
        assert!(e.message.contains("found a 2x3 matrix"), "{e}");
    }
}
