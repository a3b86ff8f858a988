//! Sites as NumPy `.npy` files (format versions 1.0, 2.0 and 3.0): the
//! magic string `\x93NUMPY`, the version, the header's length (2 bytes in
//! version 1.0, 4 after), a header that is a Python dict literal
//! (`{'descr': '<f8', 'fortran_order': False, 'shape': (N, 3), }`, padded
//! with spaces and a line end), then the array's data.
//!
//! Read: arrays of shape (N, 3), little-endian float64 (`<f8`) or float32
//! (`<f4`, widened to f64 exactly), in C or Fortran order. Anything else is
//! an error naming the file and what was expected; NaN and infinities are
//! refused, as in `.xyz` files. A file is read straight into the sites'
//! memory (no copy of the file is held).

use super::lex::shown;
use cvd::error::{Error, Result};
use rayon::prelude::*;
use std::fmt::Display;
use std::io::Read;
use std::path::Path;

const MAGIC: &[u8] = b"\x93NUMPY";

/// The element types read.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Dtype {
    F64,
    F32,
}

impl Dtype {
    fn size(self) -> usize {
        match self {
            Dtype::F64 => 8,
            Dtype::F32 => 4,
        }
    }

    fn name(self) -> &'static str {
        match self {
            Dtype::F64 => "float64",
            Dtype::F32 => "float32",
        }
    }
}

/// What a header says.
#[derive(Debug, PartialEq)]
struct Header {
    dtype: Dtype,
    fortran: bool,
    /// Rows (sites).
    n: usize,
    /// Bytes from the magic string to the header's end: where data starts.
    len: usize,
}

/// An error naming the file.
fn error(name: &str, message: impl Display) -> Error {
    Error::InvalidInput(format!("{name}: {message}"))
}

/// Parses an `.npy` file's bytes: an (N, 3) array of `<f8` or `<f4`.
pub fn parse_npy(bytes: &[u8], name: &str) -> Result<Vec<[f64; 3]>> {
    let h = header(bytes, bytes.len() as u64, name)?;
    let data = &bytes[h.len..];
    let points = decode(&h, |buf| {
        buf.copy_from_slice(data);
        Ok(())
    })
    .map_err(|source| Error::Io { path: name.to_string(), source })?;
    finite(points, name, 0)
}

/// Reads an `.npy` file, its data straight into the sites' memory.
pub(super) fn read_npy(path: &Path) -> Result<Vec<[f64; 3]>> {
    let name = path.display().to_string();
    let io = |source| Error::Io { path: name.clone(), source };
    let mut file = std::fs::File::open(path).map_err(io)?;
    let meta = file.metadata().map_err(io)?;
    if !meta.is_file() {
        // A pipe or device: its size is known only once read.
        let mut bytes = Vec::new();
        file.read_to_end(&mut bytes).map_err(io)?;
        return parse_npy(&bytes, &name);
    }
    let h = read_header(&file, meta.len(), &name)?;
    cvd::job::memory::check(&format!("the {} sites of {name}", h.n), (h.n as u64).saturating_mul(24), None)?;
    let points = decode(&h, |buf| super::read_exact_at(&file, h.len as u64, buf)).map_err(io)?;
    finite(points, &name, 0)
}

/// The header of a regular file of `size` bytes, read from its start
/// (and checked against the size, as [`header`] does).
fn read_header(file: &std::fs::File, size: u64, name: &str) -> Result<Header> {
    let io = |source| Error::Io { path: name.to_string(), source };
    let mut prefix = vec![0; size.min(12) as usize];
    super::read_exact_at(file, 0, &mut prefix).map_err(io)?;
    let want = (header_len(&prefix, name)? as u64).min(size) as usize;
    if want > prefix.len() {
        let old = prefix.len();
        prefix.resize(want, 0);
        super::read_exact_at(file, old as u64, &mut prefix[old..]).map_err(io)?;
    }
    header(&prefix, size, name)
}

/// Part `part` of `parts` of an `.npy` regular file of `size` bytes: the
/// rows `n * part / parts .. n * (part + 1) / parts`, read at their
/// offsets (in Fortran order, the three columns' ranges). Returns the
/// part's first row, its sites and the file's rows.
pub(super) fn read_npy_part(
    file: &std::fs::File,
    size: u64,
    name: &str,
    part: usize,
    parts: usize,
) -> Result<(u64, Vec<[f64; 3]>, u64)> {
    let io = |source| Error::Io { path: name.to_string(), source };
    let h = read_header(file, size, name)?;
    let n = h.n as u64;
    let rows = super::parts::share(n, part, parts);
    // Fits: at most the file's rows, which the header found in the file.
    let m = (rows.end - rows.start) as usize;
    let what = format!("the {m} sites of part {part} of {parts} of {name}");
    cvd::job::memory::check(&what, (m as u64).saturating_mul(24), None)?;
    let item = h.dtype.size() as u64;
    let data = h.len as u64;
    let part_header = Header { n: m, ..h };
    let points = decode(&part_header, |buf| {
        if !h.fortran {
            return super::read_exact_at(file, data + rows.start * 3 * item, buf);
        }
        // All x, then all y, then all z: the part's range of each.
        let column = m * item as usize;
        for (axis, range) in buf.chunks_exact_mut(column.max(1)).enumerate() {
            super::read_exact_at(file, data + (axis as u64 * n + rows.start) * item, range)?;
        }
        Ok(())
    })
    .map_err(io)?;
    Ok((rows.start, finite(points, name, rows.start)?, n))
}

/// Writes sites as an `.npy` file (version 1.0, `<f8`, C order, shape
/// (N, 3)), which [`parse_npy`] and `numpy.load` read back exactly.
pub fn write_sites_npy(path: &Path, sites: &[[f64; 3]]) -> Result<()> {
    super::write_file(path, |w| {
        w.write_all(&npy_header(sites.len()))?;
        for p in sites {
            for c in p {
                w.write_all(&c.to_le_bytes())?;
            }
        }
        Ok(())
    })
}

/// The header of an (n, 3) `<f8` array in C order, its length a multiple
/// of 64 as numpy writes it.
fn npy_header(n: usize) -> Vec<u8> {
    let dict = format!("{{'descr': '<f8', 'fortran_order': False, 'shape': ({n}, 3), }}");
    let total = (10 + dict.len() + 1).div_ceil(64) * 64;
    let mut h = MAGIC.to_vec();
    h.extend([1, 0]);
    // Below 100 bytes: always fits version 1.0's 2-byte length.
    h.extend(((total - 10) as u16).to_le_bytes());
    h.extend(dict.as_bytes());
    h.resize(total - 1, b' ');
    h.push(b'\n');
    h
}

/// The header's length (from the magic string to its end) as the file's
/// first bytes give it (12 are enough).
fn header_len(bytes: &[u8], name: &str) -> Result<usize> {
    if !bytes.starts_with(MAGIC) {
        let start: String = bytes.iter().take(6).flat_map(|&b| std::ascii::escape_default(b)).map(char::from).collect();
        return Err(error(
            name,
            format!("expected a NumPy .npy file, starting with \"\\x93NUMPY\", found \"{start}\""),
        ));
    }
    let truncated = |what: &str| error(name, format!("expected {what}, found the end of the file"));
    let (major, minor) = match bytes.get(6..8) {
        Some(&[major, minor]) => (major, minor),
        _ => return Err(truncated("the .npy format version")),
    };
    let size = match (major, minor) {
        (1, 0) => 2,
        (2, 0) | (3, 0) => 4,
        _ => {
            return Err(error(
                name,
                format!("unsupported .npy format version {major}.{minor} (versions 1.0, 2.0 and 3.0 are read)"),
            ))
        }
    };
    let Some(field) = bytes.get(8..8 + size) else {
        return Err(truncated("the .npy header's length"));
    };
    let len = field.iter().rev().fold(0usize, |acc, &b| acc << 8 | b as usize);
    Ok((8 + size).saturating_add(len))
}

/// The header, from the file's first bytes (at least the whole header, or
/// the whole file if shorter), `size` being the file's size, which must be
/// the header and exactly the data it announces.
fn header(bytes: &[u8], size: u64, name: &str) -> Result<Header> {
    let len = header_len(bytes, name)?;
    let start = if bytes[6] == 1 { 10 } else { 12 };
    let Some(dict) = bytes.get(start..len) else {
        return Err(error(
            name,
            format!(
                "expected a header of {} bytes, found the end of the file after {}",
                len - start,
                size - start as u64
            ),
        ));
    };
    let text = String::from_utf8_lossy(dict);
    let expected = "expected the .npy header to be a Python dict {'descr': ..., 'fortran_order': ..., 'shape': ...}";
    let syntax = || error(name, format!("{expected}, found {}", shown(text.trim_end())));
    let entries = Dict { b: dict, pos: 0 }.parse().ok_or_else(syntax)?;
    let (mut descr, mut fortran, mut shape) = (None, None, None);
    for (key, value) in entries {
        let slot = match key {
            b"descr" => &mut descr,
            b"fortran_order" => &mut fortran,
            b"shape" => &mut shape,
            _ => {
                let key = String::from_utf8_lossy(key);
                return Err(error(name, format!("{expected}, found the key '{key}'")));
            }
        };
        if slot.replace(value).is_some() {
            let key = String::from_utf8_lossy(key);
            return Err(error(name, format!("{expected}, found the key '{key}' twice")));
        }
    }
    let lacks = |key: &str| error(name, format!("{expected}, found no '{key}'"));
    let dtype = match descr.ok_or_else(|| lacks("descr"))? {
        Value::Str(b"<f8") => Dtype::F64,
        Value::Str(b"<f4") => Dtype::F32,
        Value::Str(d) => {
            let d = String::from_utf8_lossy(d);
            let why = match d.as_bytes() {
                [b'>', ..] => " (big-endian)",
                _ => "",
            };
            return Err(error(
                name,
                format!(
                    "dtype '{d}'{why}: expected little-endian float64 '<f8' or float32 '<f4' \
                     (numpy: a.astype('<f8'))"
                ),
            ));
        }
        _ => {
            return Err(error(name, "a structured dtype: expected little-endian float64 '<f8' or float32 '<f4'"));
        }
    };
    let fortran = match fortran.ok_or_else(|| lacks("fortran_order"))? {
        Value::Bool(b) => b,
        _ => return Err(error(name, format!("{expected}, with 'fortran_order' True or False"))),
    };
    let n = match shape.ok_or_else(|| lacks("shape"))? {
        Value::Tuple(dims) => match dims[..] {
            [Value::Int(n), Value::Int(3)] => n,
            _ => {
                let dims: Vec<String> = dims.iter().map(|d| d.to_string()).collect();
                let shape = if dims.len() == 1 { format!("({},)", dims[0]) } else { format!("({})", dims.join(", ")) };
                return Err(error(name, format!("shape {shape}: expected (N, 3), N sites of x y z")));
            }
        },
        _ => return Err(error(name, format!("{expected}, with 'shape' a tuple (N, 3)"))),
    };
    // The data: exactly n * 3 values.
    let item = dtype.size();
    let needed = n as u128 * 3 * item as u128;
    let found = size - len as u64;
    if needed != found as u128 {
        let what = if needed > found as u128 { "the file is truncated" } else { "bytes follow the data" };
        return Err(error(
            name,
            format!(
                "expected {n} × 3 {} values ({needed} bytes) after the {len}-byte header, found {found} bytes: {what}",
                dtype.name()
            ),
        ));
    }
    // Fits: the data is in the file.
    Ok(Header { dtype, fortran, n: n as usize, len })
}

/// The sites from the data, which `fill` writes into the bytes given (of
/// the header's data length).
fn decode(h: &Header, fill: impl FnOnce(&mut [u8]) -> std::io::Result<()>) -> std::io::Result<Vec<[f64; 3]>> {
    let n = h.n;
    let le64 = |c: f64| f64::from_le_bytes(c.to_ne_bytes());
    let le32 = |c: f32| f32::from_le_bytes(c.to_ne_bytes()) as f64;
    Ok(match (h.dtype, h.fortran) {
        (Dtype::F64, false) => {
            let mut points = vec![[0.0f64; 3]; n];
            fill(bytemuck::cast_slice_mut(&mut points))?;
            if cfg!(target_endian = "big") {
                points.par_iter_mut().for_each(|p| *p = p.map(le64));
            }
            points
        }
        (Dtype::F32, false) => {
            let mut data = vec![[0.0f32; 3]; n];
            fill(bytemuck::cast_slice_mut(&mut data))?;
            data.par_iter().map(|p| p.map(le32)).collect()
        }
        // Fortran order: all x, then all y, then all z.
        (Dtype::F64, true) => {
            let mut data = vec![0.0f64; 3 * n];
            fill(bytemuck::cast_slice_mut(&mut data))?;
            (0..n).into_par_iter().map(|i| [0, 1, 2].map(|a| le64(data[a * n + i]))).collect()
        }
        (Dtype::F32, true) => {
            let mut data = vec![0.0f32; 3 * n];
            fill(bytemuck::cast_slice_mut(&mut data))?;
            (0..n).into_par_iter().map(|i| [0, 1, 2].map(|a| le32(data[a * n + i]))).collect()
        }
    })
}

/// The sites, if all coordinates are finite (`first`: the file's row of
/// the first, for errors).
fn finite(points: Vec<[f64; 3]>, name: &str, first: u64) -> Result<Vec<[f64; 3]>> {
    let Some(i) = points.par_iter().position_first(|p| p.iter().any(|c| !c.is_finite())) else {
        return Ok(points);
    };
    let (axis, c) = ["x", "y", "z"].into_iter().zip(points[i]).find(|(_, c)| !c.is_finite()).unwrap_or(("x", 0.0));
    Err(error(
        name,
        format!("expected the {axis} coordinate of point {} (a finite number), found {c}", first + i as u64 + 1),
    ))
}

/// A value of the header's dict.
#[derive(Debug, PartialEq)]
enum Value<'a> {
    Str(&'a [u8]),
    Bool(bool),
    None,
    Int(u64),
    Tuple(Vec<Value<'a>>),
    List(Vec<Value<'a>>),
}

impl Display for Value<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        match self {
            Value::Str(s) => write!(f, "'{}'", String::from_utf8_lossy(s)),
            Value::Bool(b) => f.write_str(if *b { "True" } else { "False" }),
            Value::None => f.write_str("None"),
            Value::Int(i) => write!(f, "{i}"),
            Value::Tuple(_) => f.write_str("(...)"),
            Value::List(_) => f.write_str("[...]"),
        }
    }
}

/// The Python literals of a header: a dict of strings to strings, True,
/// False, None, integers, tuples and lists (structured dtypes), nested at
/// most `DEPTH` deep.
struct Dict<'a> {
    b: &'a [u8],
    pos: usize,
}

const DEPTH: usize = 8;

impl<'a> Dict<'a> {
    /// The entries, in order; `None` if the text is not such a dict
    /// followed by whitespace only.
    fn parse(mut self) -> Option<Vec<(&'a [u8], Value<'a>)>> {
        let mut entries = Vec::new();
        self.eat(b'{')?;
        while !self.peek_is(b'}') {
            let Value::Str(key) = self.value(0)? else { return None };
            self.eat(b':')?;
            entries.push((key, self.value(0)?));
            if !self.peek_is(b'}') {
                self.eat(b',')?;
            }
        }
        self.eat(b'}')?;
        self.skip();
        (self.pos == self.b.len()).then_some(entries)
    }

    fn skip(&mut self) {
        while self.b.get(self.pos).is_some_and(|b| b.is_ascii_whitespace()) {
            self.pos += 1;
        }
    }

    /// Whether the next byte after whitespace is `c`.
    fn peek_is(&mut self, c: u8) -> bool {
        self.skip();
        self.b.get(self.pos) == Some(&c)
    }

    fn eat(&mut self, c: u8) -> Option<()> {
        self.peek_is(c).then(|| self.pos += 1)
    }

    /// Whether `word` comes next (then read).
    fn word(&mut self, word: &[u8]) -> bool {
        let found = self.b[self.pos..].starts_with(word);
        if found {
            self.pos += word.len();
        }
        found
    }

    fn value(&mut self, depth: usize) -> Option<Value<'a>> {
        self.skip();
        let &c = self.b.get(self.pos)?;
        match c {
            b'\'' | b'"' => {
                let start = self.pos + 1;
                let len = self.b[start..].iter().position(|&b| b == c)?;
                self.pos = start + len + 1;
                Some(Value::Str(&self.b[start..start + len]))
            }
            b'(' | b'[' if depth < DEPTH => {
                let close = if c == b'(' { b')' } else { b']' };
                self.pos += 1;
                let mut items = Vec::new();
                while !self.peek_is(close) {
                    items.push(self.value(depth + 1)?);
                    if !self.peek_is(close) {
                        self.eat(b',')?;
                    }
                }
                self.pos += 1;
                Some(if c == b'(' { Value::Tuple(items) } else { Value::List(items) })
            }
            b'0'..=b'9' => {
                let start = self.pos;
                while self.b.get(self.pos).is_some_and(u8::is_ascii_digit) {
                    self.pos += 1;
                }
                let digits = std::str::from_utf8(&self.b[start..self.pos]).ok()?;
                // Python 2's long integers (old numpy files): 10L.
                self.word(b"L");
                digits.parse().ok().map(Value::Int)
            }
            _ if self.word(b"True") => Some(Value::Bool(true)),
            _ if self.word(b"False") => Some(Value::Bool(false)),
            _ if self.word(b"None") => Some(Value::None),
            _ => None,
        }
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::super::tests::{no_panic_on_mutations, temp_path};
    use super::*;
    use proptest::prelude::*;

    /// An `.npy` file of format `version` with header dict `dict` (padded
    /// as numpy pads it) and `data`.
    pub fn npy(version: u8, dict: &str, data: &[u8]) -> Vec<u8> {
        let pre = if version == 1 { 10 } else { 12 };
        let len = (pre + dict.len() + 1).div_ceil(64) * 64 - pre;
        let mut b = MAGIC.to_vec();
        b.extend([version, 0]);
        if version == 1 {
            b.extend((len as u16).to_le_bytes());
        } else {
            b.extend((len as u32).to_le_bytes());
        }
        b.extend(dict.as_bytes());
        b.resize(pre + len - 1, b' ');
        b.push(b'\n');
        b.extend(data);
        b
    }

    fn dict(descr: &str, fortran: bool, shape: &str) -> String {
        let fortran = if fortran { "True" } else { "False" };
        format!("{{'descr': '{descr}', 'fortran_order': {fortran}, 'shape': {shape}, }}")
    }

    const SITES: [[f64; 3]; 4] =
        [[0.1, -2.5e-7, 3.0e300], [f64::MIN_POSITIVE, 1.0 / 3.0, -0.0], [123456.79, 5e-324, 7.0], [1e6, -1.5, 0.25]];

    fn f64_data(sites: &[[f64; 3]], fortran: bool) -> Vec<u8> {
        let values: Vec<f64> = if fortran {
            (0..3).flat_map(|a| sites.iter().map(move |p| p[a])).collect()
        } else {
            sites.iter().flatten().copied().collect()
        };
        values.iter().flat_map(|v| v.to_le_bytes()).collect()
    }

    fn f32_data(sites: &[[f32; 3]], fortran: bool) -> Vec<u8> {
        let values: Vec<f32> = if fortran {
            (0..3).flat_map(|a| sites.iter().map(move |p| p[a])).collect()
        } else {
            sites.iter().flatten().copied().collect()
        };
        values.iter().flat_map(|v| v.to_le_bytes()).collect()
    }

    fn bits(points: &[[f64; 3]]) -> Vec<[u64; 3]> {
        points.iter().map(|p| p.map(f64::to_bits)).collect()
    }

    /// The message of an invalid-input error.
    fn message<T: std::fmt::Debug>(r: Result<T>) -> String {
        match r {
            Err(e @ Error::InvalidInput(_)) => e.to_string(),
            other => panic!("expected an invalid-input error, got {other:?}"),
        }
    }

    #[test]
    fn every_version_dtype_and_order_reads() {
        let f32_sites: [[f32; 3]; 3] =
            [[0.1, -2.5e-7, 3.0e38], [f32::MIN_POSITIVE, 1.0 / 3.0, -0.0], [1e-45, 7.0, 16777217.0]];
        let widened: Vec<[f64; 3]> = f32_sites.iter().map(|p| p.map(f64::from)).collect();
        for version in 1..=3 {
            for fortran in [false, true] {
                let file = npy(version, &dict("<f8", fortran, "(4, 3)"), &f64_data(&SITES, fortran));
                let got = parse_npy(&file, "s.npy").unwrap_or_else(|e| panic!("v{version} {fortran}: {e}"));
                assert_eq!(bits(&got), bits(&SITES), "v{version} fortran {fortran}");
                let file = npy(version, &dict("<f4", fortran, "(3, 3)"), &f32_data(&f32_sites, fortran));
                let got = parse_npy(&file, "s.npy").unwrap_or_else(|e| panic!("v{version} {fortran}: {e}"));
                assert_eq!(bits(&got), bits(&widened), "v{version} fortran {fortran}");
            }
        }
        // No sites; the keys in any order, Python 2's long integers, double quotes.
        assert!(parse_npy(&npy(1, &dict("<f8", false, "(0, 3)"), &[]), "e.npy").unwrap().is_empty());
        let file =
            npy(1, "{\"shape\": (1L, 3L), 'fortran_order': False, 'descr': '<f8'}", &f64_data(&SITES[..1], false));
        assert_eq!(parse_npy(&file, "old.npy").unwrap(), SITES[..1]);
    }

    #[test]
    fn written_files_read_back_exactly() {
        let path = temp_path("round_trip.npy");
        write_sites_npy(&path, &SITES).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(bytes.len() % 8, 0);
        assert_eq!(&bytes[..10], b"\x93NUMPY\x01\x00\x76\x00", "a 128-byte header as numpy writes it");
        assert_eq!(bits(&parse_npy(&bytes, "r.npy").unwrap()), bits(&SITES));
        let back = super::super::read_sites(&path);
        std::fs::remove_file(&path).unwrap();
        assert_eq!(bits(&back.unwrap()), bits(&SITES));
        // The file reader and the bytes reader agree, errors included.
        let path = temp_path("cut.npy");
        for cut in [0, 3, 7, 9, 11, 60, 128, 129, bytes.len() - 1] {
            std::fs::write(&path, &bytes[..cut]).unwrap();
            let (file, slice) = (read_npy(&path), parse_npy(&bytes[..cut], &path.display().to_string()));
            assert_eq!(message(file), message(slice), "cut at {cut}");
        }
        std::fs::remove_file(&path).unwrap();
    }

    #[test]
    fn bad_files_are_named_with_what_was_expected() {
        let data = f64_data(&SITES, false);
        let good = npy(1, &dict("<f8", false, "(4, 3)"), &data);
        let cases: Vec<(Vec<u8>, &str)> = vec![
            (b"0 0 0\n1 1 1\n".to_vec(), "expected a NumPy .npy file, starting with \"\\x93NUMPY\", found \"0 0 0\\n\""),
            (b"\x93NUMPY".to_vec(), "expected the .npy format version, found the end of the file"),
            (b"\x93NUMPY\x01\x00\x76".to_vec(), "expected the .npy header's length, found the end of the file"),
            (b"\x93NUMPY\x04\x00\x00\x00\x00\x00".to_vec(), "unsupported .npy format version 4.0"),
            (good[..100].to_vec(), "expected a header of 118 bytes, found the end of the file after 90"),
            (npy(1, &dict(">f8", false, "(4, 3)"), &data), "dtype '>f8' (big-endian): expected little-endian float64 '<f8'"),
            (npy(2, &dict("<i8", false, "(4, 3)"), &data), "dtype '<i8': expected little-endian float64 '<f8' or float32 '<f4'"),
            (npy(1, &dict("<f2", false, "(4, 3)"), &data), "dtype '<f2'"),
            (npy(1, "{'descr': [('x', '<f8')], 'fortran_order': False, 'shape': (4,), }", &data), "a structured dtype"),
            (npy(1, &dict("<f8", false, "(12,)"), &data), "shape (12,): expected (N, 3), N sites of x y z"),
            (npy(1, &dict("<f8", false, "(3, 4)"), &data), "shape (3, 4): expected (N, 3)"),
            (npy(1, &dict("<f8", false, "(4, 3, 1)"), &data), "shape (4, 3, 1): expected (N, 3)"),
            (npy(1, &dict("<f8", false, "()"), &data), "shape (): expected (N, 3)"),
            (npy(1, &dict("<f8", false, "(5, 3)"), &data), "expected 5 × 3 float64 values (120 bytes) after the 128-byte header, found 96 bytes: the file is truncated"),
            (npy(1, &dict("<f4", false, "(4, 3)"), &data), "expected 4 × 3 float32 values (48 bytes) after the 128-byte header, found 96 bytes: bytes follow the data"),
            (npy(1, &dict("<f8", false, "(18446744073709551615, 3)"), &data), "(442721857769029238760 bytes)"),
            (npy(1, "{'descr': '<f8', 'fortran_order': False}", &data), "found no 'shape'"),
            (npy(1, "{'descr': '<f8', 'shape': (4, 3)}", &data), "found no 'fortran_order'"),
            (npy(1, &dict("<f8", false, "(4, 3)").replace("False", "0"), &data), "with 'fortran_order' True or False"),
            (npy(1, &dict("<f8", false, "[4, 3]"), &data), "with 'shape' a tuple (N, 3)"),
            (npy(1, "{'descr': '<f8', 'descr': '<f8', 'fortran_order': False, 'shape': (4, 3)}", &data), "found the key 'descr' twice"),
            (npy(1, "{'descr': '<f8', 'fortran_order': False, 'shape': (4, 3), 'x': 1}", &data), "found the key 'x'"),
            (npy(1, "{'descr': '<f8', 'fortran_order': False, 'shape': (4, 3)} x", &data), "found \"{'descr'"),
            (npy(1, "not a dict", &data), "expected the .npy header to be a Python dict"),
        ];
        for (bytes, expected) in cases {
            let m = message(parse_npy(&bytes, "bad.npy"));
            assert!(m.starts_with("invalid input: bad.npy: ") && m.contains(expected), "{m}\n  lacks {expected}");
        }
        // Non-finite coordinates, as in .xyz files, with the point and axis.
        for (v, shown) in [(f64::NAN, "NaN"), (f64::INFINITY, "inf"), (f64::NEG_INFINITY, "-inf")] {
            let mut sites = SITES;
            sites[2][1] = v;
            let m = message(parse_npy(&npy(1, &dict("<f8", false, "(4, 3)"), &f64_data(&sites, false)), "n.npy"));
            assert!(
                m.ends_with(&format!("expected the y coordinate of point 3 (a finite number), found {shown}")),
                "{m}"
            );
            let mut f32_sites = [[1.0f32, 2.0, 3.0]; 4];
            f32_sites[2][1] = v as f32;
            let m = message(parse_npy(&npy(3, &dict("<f4", true, "(4, 3)"), &f32_data(&f32_sites, true)), "n.npy"));
            assert!(m.contains("y coordinate of point 3"), "{m}");
        }
    }

    #[test]
    fn no_npy_file_makes_the_reader_panic() {
        for version in 1..=3 {
            for (descr, fortran) in [("<f8", false), ("<f4", true)] {
                let data =
                    if descr == "<f8" { f64_data(&SITES, fortran) } else { f32_data(&[[1.0, 2.0, 3.0]; 4], fortran) };
                let d = dict(descr, fortran, "(4, 3)");
                let b = npy(version, &d, &data);
                for cut in 0..b.len() {
                    let _ = parse_npy(&b[..cut], "cut.npy");
                }
                for i in 0..b.len() {
                    for x in [0u8, 1, 3, b'(', b'\'', b',', b' ', 0x7f, 0xff] {
                        let mut m = b.clone();
                        m[i] = x;
                        let _ = parse_npy(&m, "flip.npy");
                    }
                }
                no_panic_on_mutations(&d, |t| parse_npy(&npy(version, t, &data), "m.npy"));
            }
        }
        // Deep nesting stops, not the stack.
        let deep = format!(
            "{{'descr': {}1{}, 'fortran_order': False, 'shape': (0, 3)}}",
            "(".repeat(100_000),
            ")".repeat(100_000)
        );
        assert!(parse_npy(&npy(2, &deep, &[]), "deep.npy").is_err());
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

        #[test]
        fn random_headers_never_panic(tokens in prop::collection::vec(prop::sample::select(vec![
            "{", "}", "(", ")", "[", "]", ",", ":", " ", "'descr'", "'shape'", "'fortran_order'", "'<f8'", "'<f4'",
            "'>f8'", "True", "False", "None", "0", "3", "4", "18446744073709551616", "L", "'", "\"",
        ]), 0..40), version in 1u8..=3, data in prop::collection::vec(any::<u8>(), 0..100)) {
            let _ = parse_npy(&npy(version, &tokens.concat(), &data), "r.npy");
        }

        #[test]
        fn random_bytes_after_the_magic_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..300)) {
            let _ = parse_npy(&[MAGIC, &bytes].concat(), "r.npy");
        }
    }
}
