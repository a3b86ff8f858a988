//! A cursor over a binary file's bytes in the file's byte order, for the
//! binary mesh readers (`.meshb`, binary `.msh`): every read names what it
//! expected when the file ends first.

use cvd::error::{Error, Result};

pub(super) struct ByteReader<'a> {
    pub bytes: &'a [u8],
    pub pos: usize,
    /// Little-endian (else big-endian).
    pub little: bool,
    pub name: &'a str,
}

impl<'a> ByteReader<'a> {
    pub fn new(bytes: &'a [u8], name: &'a str) -> Self {
        Self { bytes, pos: 0, little: true, name }
    }

    /// An error at the current byte.
    pub fn error(&self, message: impl Into<String>) -> Error {
        Error::InvalidInput(format!("{}: at byte {}: {}", self.name, self.pos, message.into()))
    }

    /// The next `n` bytes.
    pub fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8]> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.bytes.len());
        let Some(end) = end else {
            return Err(self.error(format!("expected {what}, found the end of the file")));
        };
        let s = &self.bytes[self.pos..end];
        self.pos = end;
        Ok(s)
    }

    /// Sets the byte order from a 32-bit integer that must read as 1.
    pub fn byte_order(&mut self, what: &str) -> Result<()> {
        let b = self.take(4, what)?;
        let b = [b[0], b[1], b[2], b[3]];
        self.little = match (i32::from_le_bytes(b), i32::from_be_bytes(b)) {
            (1, _) => true,
            (_, 1) => false,
            _ => return Err(self.error(format!("{what} is not 1 in either byte order"))),
        };
        Ok(())
    }

    /// A signed integer of `size` bytes (4 or 8).
    pub fn int(&mut self, size: usize, what: &str) -> Result<i64> {
        let b = self.take(size, what)?;
        Ok(match (b.len(), self.little) {
            (4, true) => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as i64,
            (4, false) => i32::from_be_bytes([b[0], b[1], b[2], b[3]]) as i64,
            (_, true) => i64::from_le_bytes(b.try_into().unwrap_or([0; 8])),
            (_, false) => i64::from_be_bytes(b.try_into().unwrap_or([0; 8])),
        })
    }

    /// A real of `size` bytes (4: f32, 8: f64).
    pub fn real(&mut self, size: usize, what: &str) -> Result<f64> {
        let b = self.take(size, what)?;
        Ok(match (b.len(), self.little) {
            (4, true) => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
            (4, false) => f32::from_be_bytes([b[0], b[1], b[2], b[3]]) as f64,
            (_, true) => f64::from_le_bytes(b.try_into().unwrap_or([0; 8])),
            (_, false) => f64::from_be_bytes(b.try_into().unwrap_or([0; 8])),
        })
    }

    /// The next text line, trimmed (the text parts of a binary `.msh`).
    pub fn line(&mut self) -> Option<&'a str> {
        if self.pos >= self.bytes.len() {
            return None;
        }
        let rest = &self.bytes[self.pos..];
        let end = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
        self.pos += (end + 1).min(rest.len());
        Some(std::str::from_utf8(&rest[..end]).unwrap_or("").trim())
    }
}
