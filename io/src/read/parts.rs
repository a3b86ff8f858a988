//! Sites read by parts, for runs of several processes none of which may
//! read the whole file: [`read_sites_part`] reads one part of `parts`,
//! only its bytes, and the parts together give what [`read_sites`] gives.
//!
//! An `.npy` part knows where its rows lie in the file (its first row and
//! the file's rows come from the header). A text part does not: its first
//! row, the file's rows and the check of a count line need what the other
//! parts read. Each process gathers every part's [`SitesPartSummary`] (a
//! few numbers, e.g. by an all-gather of [`SitesPartSummary::to_bytes`])
//! and calls [`SitesPart::join`], which gives the same answer, or the same
//! error, on all of them.
//!
//! [`read_sites`]: super::read_sites

use super::formats::{self, SITES};
use super::{npy, xyz};
use cvd::error::{Error, Result};
use std::ops::Range;
use std::path::Path;

/// One part of a sites file, as [`read_sites_part`] reads it.
#[derive(Clone, Debug, PartialEq)]
pub struct SitesPart {
    /// The file's row (0-based) of the part's first site: known for
    /// `.npy`; for text, `None` until [`SitesPart::join`] (the sites of
    /// the parts before, an exclusive prefix sum of their counts).
    pub first: Option<u64>,
    /// The part's sites, in the file's order.
    pub sites: Vec<[f64; 3]>,
    /// The file's rows (sites): known for `.npy`; for text, `None` until
    /// [`SitesPart::join`].
    pub total: Option<u64>,
    /// Text: the part's first line holding a token, when it holds a single
    /// count. It is the file's count line if no earlier part holds a token
    /// (then the file must hold that many sites), else an error: only
    /// [`SitesPart::join`] can tell. Never one of [`Self::sites`].
    pub count_line: Option<CountLine>,
}

/// A line of a text sites file holding a single count.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CountLine {
    /// The byte offset in the file of the line's start.
    pub offset: u64,
    /// The count it holds.
    pub count: u64,
}

/// What a part tells the others (see [`SitesPart::join`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SitesPartSummary {
    /// The part's sites.
    pub sites: u64,
    /// Its [`SitesPart::count_line`].
    pub count_line: Option<CountLine>,
}

impl SitesPartSummary {
    /// Its bytes, to send to the other processes: little-endian u64s.
    pub fn to_bytes(&self) -> [u8; 32] {
        let (has, line) = match self.count_line {
            Some(line) => (1, line),
            None => (0, CountLine { offset: 0, count: 0 }),
        };
        let mut bytes = [0; 32];
        for (chunk, word) in bytes.as_chunks_mut::<8>().0.iter_mut().zip([self.sites, has, line.offset, line.count]) {
            *chunk = word.to_le_bytes();
        }
        bytes
    }

    /// The summary that [`Self::to_bytes`] gave these bytes, if it did.
    pub fn from_bytes(bytes: &[u8]) -> Option<Self> {
        let bytes: &[u8; 32] = bytes.try_into().ok()?;
        let words = bytes.as_chunks::<8>().0;
        let [sites, has, offset, count] = [0, 1, 2, 3].map(|i| u64::from_le_bytes(words[i]));
        match has {
            0 if offset == 0 && count == 0 => Some(Self { sites, count_line: None }),
            1 => Some(Self { sites, count_line: Some(CountLine { offset, count }) }),
            _ => None,
        }
    }
}

impl SitesPart {
    /// What the other parts need from this one.
    pub fn summary(&self) -> SitesPartSummary {
        SitesPartSummary { sites: self.sites.len() as u64, count_line: self.count_line }
    }

    /// Sets [`Self::first`] and [`Self::total`] from the summaries of all
    /// parts of `path`, in part order, this one being `part`, and makes the
    /// checks [`read_sites`](super::read_sites) makes across lines: a count
    /// line only as the file's first line holding a token, and then the
    /// file's sites as many as it says. Every part, given the same
    /// summaries, gets the same result. Call it once every part has been
    /// read without error. (For `.npy`, checks that the summaries agree
    /// with what the header gave.)
    pub fn join(&mut self, path: &Path, summaries: &[SitesPartSummary], part: usize) -> Result<()> {
        let name = path.display().to_string();
        if summaries.get(part) != Some(&self.summary()) {
            return Err(Error::InvalidInput(format!(
                "{name}: part {part} of {} parts: its summary is not {:?}",
                summaries.len(),
                self.summary()
            )));
        }
        let (mut before, mut first, mut held, mut count) = (0u64, 0, false, None);
        for (k, s) in summaries.iter().enumerate() {
            if let Some(line) = s.count_line {
                if held {
                    return Err(Error::InvalidInput(format!(
                        "{name}: the line at byte {}: expected 3 coordinates x y z for point {}, found 1 value",
                        line.offset,
                        before + 1
                    )));
                }
                count = Some(line);
            }
            held |= s.count_line.is_some() || s.sites > 0;
            if k == part {
                first = before;
            }
            before = before.saturating_add(s.sites);
        }
        let total = before;
        if let Some(line) = count.filter(|line| line.count != total) {
            return Err(Error::InvalidInput(format!(
                "{name}: expected {} points (the count on the line at byte {}), found {total}",
                line.count, line.offset
            )));
        }
        let known = |k: Option<u64>, v| k.is_none_or(|k| k == v);
        if !known(self.first, first) || !known(self.total, total) {
            return Err(Error::InvalidInput(format!(
                "{name}: part {part}: the summaries give row {first} of {total}, the file row {:?} of {:?}",
                self.first, self.total
            )));
        }
        (self.first, self.total) = (Some(first), Some(total));
        Ok(())
    }
}

/// Reads part `part` of `parts` (0-based) of a sites file, reading only
/// that part's bytes; the format is chosen as [`read_sites`] chooses it.
/// Concatenated in order, the parts' sites are exactly (bit for bit) those
/// [`read_sites`] reads, for any `parts >= 1` (parts may be empty).
///
/// * `.npy`: the rows `n * part / parts .. n * (part + 1) / parts`, read at
///   their offsets (in Fortran order, the part's range of each of the three
///   columns) after the header is read and checked against the file's
///   size. [`SitesPart::first`] and [`SitesPart::total`] are known.
/// * Text (`.xyz` or any other extension): the lines that start in the
///   bytes `len * part / parts .. len * (part + 1) / parts` (a line belongs
///   to the part where its first byte lies), read from the byte before
///   the range (to tell whether a line starts at its first byte) to the end
///   of the last line starting in it. Comments, blank lines and a count
///   line are read as [`read_sites`] reads them; errors name the file and
///   the line's byte offset, its line number being unknown to a part:
///   `"s.xyz: the line at byte 12345: expected 3 coordinates x y z, found
///   2 values"`. [`SitesPart::first`] and [`SitesPart::total`] are `None`:
///   [`SitesPart::join`] gives them, and checks the count line.
///
/// The part's bytes (not the file's) are checked against the memory
/// available before they are read. The file must be a regular file (its
/// size known before it is read).
///
/// [`read_sites`]: super::read_sites
pub fn read_sites_part(path: &Path, part: usize, parts: usize) -> Result<SitesPart> {
    let name = path.display().to_string();
    check_part(&name, part, parts)?;
    let Some(format) = formats::find(SITES, path) else {
        return Err(formats::unknown(SITES, "sites", path));
    };
    let npy = format.matches("npy");
    if !npy && !format.fallback {
        return Err(Error::InvalidInput(format!("{name}: {} sites files cannot be read by parts", format.name)));
    }
    let (file, size) = open_regular(path)?;
    if npy {
        let (first, sites, total) = npy::read_npy_part(&file, size, &name, part, parts)?;
        return Ok(SitesPart { first: Some(first), sites, total: Some(total), count_line: None });
    }
    let (sites, count_line) = match text_part(&file, size, &name, part, parts)? {
        Some((offset, bytes, skip)) => xyz::parse_xyz_part(&bytes[skip..], offset, &name)?,
        None => (Vec::new(), None),
    };
    Ok(SitesPart { first: None, sites, total: None, count_line })
}

/// Reads part `part` of `parts` (0-based) of a file of one number per line
/// (weights, radii: what [`read_values`](super::read_values) reads), only
/// that part's bytes: the values of the lines that start in the bytes
/// `len * part / parts .. len * (part + 1) / parts`. Concatenated in order,
/// the parts' values are exactly those `read_values` reads; a part's first
/// row is the number of values of the parts before it (an all-gather of
/// their counts). Errors name the file and the line's byte offset.
pub fn read_values_part(path: &Path, part: usize, parts: usize) -> Result<Vec<f64>> {
    let name = path.display().to_string();
    check_part(&name, part, parts)?;
    let (file, size) = open_regular(path)?;
    match text_part(&file, size, &name, part, parts)? {
        Some((offset, bytes, skip)) => xyz::parse_values_part(&bytes[skip..], offset, &name),
        None => Ok(Vec::new()),
    }
}

/// Refuses a part that is not one of `parts`.
fn check_part(name: &str, part: usize, parts: usize) -> Result<()> {
    if part < parts {
        return Ok(());
    }
    let expected = match parts {
        0 => "at least 1 part".to_string(),
        _ => format!("a part from 0 to {}", parts - 1),
    };
    Err(Error::InvalidInput(format!("{name}: part {part} of {parts}: expected {expected}")))
}

/// The file at `path` and its size; refused unless a regular file.
fn open_regular(path: &Path) -> Result<(std::fs::File, u64)> {
    let name = path.display().to_string();
    let io = |source| Error::Io { path: name.clone(), source };
    let file = std::fs::File::open(path).map_err(io)?;
    let meta = file.metadata().map_err(io)?;
    if !meta.is_file() {
        return Err(Error::InvalidInput(format!(
            "{name}: not a regular file: reading by parts needs the file's size before it is read"
        )));
    }
    Ok((file, meta.len()))
}

/// Part `part` of `parts` of `0..n`: `n * part / parts .. n * (part + 1) / parts`.
pub(super) fn share(n: u64, part: usize, parts: usize) -> Range<u64> {
    let at = |k: usize| (n as u128 * k as u128 / parts.max(1) as u128) as u64;
    at(part)..at(part + 1)
}

/// The lines of a text file of `size` bytes that start in part `part` of
/// `parts` of its bytes (`None` if no line starts there): the first line's
/// byte offset, and bytes read from before it whose first `skip` are not
/// the part's, as `(offset, bytes, skip)`.
fn text_part(
    file: &std::fs::File,
    size: u64,
    name: &str,
    part: usize,
    parts: usize,
) -> Result<Option<(u64, Vec<u8>, usize)>> {
    let io = |source| Error::Io { path: name.to_string(), source };
    let range = share(size, part, parts);
    if range.is_empty() {
        return Ok(None);
    }
    // From the byte before: whether a line starts at the range's start.
    let from = range.start.saturating_sub(1);
    let what = |bytes: u64| format!("part {part} of {parts} of {name} ({bytes} bytes)");
    cvd::job::memory::check(&what(range.end - from), range.end - from, None)?;
    let mut bytes = vec![0; (range.end - from) as usize];
    super::read_exact_at(file, from, &mut bytes).map_err(io)?;
    let skip = match range.start {
        0 => 0,
        _ => match bytes.iter().position(|&b| b == b'\n') {
            Some(end) if end + 1 < bytes.len() => end + 1,
            _ => return Ok(None),
        },
    };
    // To the end of the last line that starts in the range.
    let (mut at, mut block) = (range.end, 1u64 << 16);
    while bytes.last() != Some(&b'\n') && at < size {
        let len = block.min(size - at);
        let total = bytes.len() as u64 + len;
        cvd::job::memory::check(&what(total), total, None)?;
        let old = bytes.len();
        bytes.resize(old + len as usize, 0);
        super::read_exact_at(file, at, &mut bytes[old..]).map_err(io)?;
        if let Some(end) = bytes[old..].iter().position(|&b| b == b'\n') {
            bytes.truncate(old + end + 1);
        }
        at += len;
        block = (block * 2).min(1 << 26);
    }
    Ok(Some((from + skip as u64, bytes, skip)))
}

#[cfg(test)]
mod tests {
    use super::super::npy::tests::npy;
    use super::super::tests::temp_path;
    use super::super::{read_sites, write_sites_npy, write_sites_xyz};
    use super::*;
    use proptest::prelude::*;
    use std::path::PathBuf;
    use std::time::Instant;

    /// Removes the file when dropped (also when a test fails).
    struct Temp(PathBuf);

    impl Temp {
        fn new(name: &str, bytes: &[u8]) -> Self {
            let path = temp_path(name);
            std::fs::write(&path, bytes).unwrap();
            Temp(path)
        }
    }

    impl Drop for Temp {
        fn drop(&mut self) {
            let _ = std::fs::remove_file(&self.0);
        }
    }

    fn bits(points: &[[f64; 3]]) -> Vec<[u64; 3]> {
        points.iter().map(|p| p.map(f64::to_bits)).collect()
    }

    /// All parts of `path` read, summaries gathered and joined as the
    /// processes of a run would: the sites concatenated, or the first
    /// error (of the reads, else of the joins, which must all agree).
    fn read_by_parts(path: &Path, parts: usize) -> Result<Vec<[f64; 3]>> {
        let mut read = (0..parts).map(|k| read_sites_part(path, k, parts)).collect::<Result<Vec<_>>>()?;
        // Through the bytes a run would send.
        let summaries: Vec<SitesPartSummary> =
            read.iter().map(|p| SitesPartSummary::from_bytes(&p.summary().to_bytes()).unwrap()).collect();
        let joined: Vec<Result<()>> = read.iter_mut().enumerate().map(|(k, p)| p.join(path, &summaries, k)).collect();
        let errors: Vec<String> = joined.iter().filter_map(|r| r.as_ref().err().map(|e| e.to_string())).collect();
        assert!(errors.is_empty() || errors.len() == parts, "some joins failed: {errors:?}");
        if errors.iter().any(|e| e != &errors[0]) {
            panic!("the joins disagree: {errors:?}");
        }
        joined.into_iter().collect::<Result<()>>()?;
        let mut sites = Vec::new();
        let total = read[0].total.unwrap();
        for p in read {
            assert_eq!((p.first, p.total), (Some(sites.len() as u64), Some(total)));
            sites.extend(p.sites);
        }
        assert_eq!(sites.len() as u64, total);
        Ok(sites)
    }

    /// Reads `path` in 1 to 7 parts and in `more` parts (more than it has
    /// rows): the same sites as [`read_sites`], bit for bit, or errors
    /// for the same files.
    fn check_parts(path: &Path, more: &[usize]) {
        let whole = read_sites(path);
        for parts in (1..=7).chain(more.iter().copied()) {
            match (&whole, read_by_parts(path, parts)) {
                (Ok(whole), Ok(by_parts)) => assert_eq!(bits(&by_parts), bits(whole), "{parts} parts"),
                (Err(_), Err(_)) => {}
                (whole, by_parts) => panic!("{parts} parts: read whole {whole:?}, by parts {by_parts:?}"),
            }
        }
    }

    /// Random sites, of all magnitudes.
    fn random_sites(n: usize, seed: u64) -> Vec<[f64; 3]> {
        let mut state = seed;
        let mut next = move || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            let x = f64::from_bits(state);
            if x.is_finite() {
                x
            } else {
                (state >> 11) as f64 / 7.0
            }
        };
        (0..n).map(|_| [next(), next(), next()]).collect()
    }

    #[test]
    fn written_files_read_by_parts_as_whole() {
        for n in [0, 1, 2, 5, 10, 100, 1000] {
            let sites = random_sites(n, n as u64 + 1);
            let xyz = temp_path(&format!("parts_{n}.xyz"));
            let npy = temp_path(&format!("parts_{n}.npy"));
            write_sites_xyz(&xyz, &sites).unwrap();
            write_sites_npy(&npy, &sites).unwrap();
            let (xyz, npy) = (Temp(xyz), Temp(npy));
            assert_eq!(bits(&read_sites(&xyz.0).unwrap()), bits(&sites));
            let len = std::fs::metadata(&xyz.0).unwrap().len() as usize;
            let mut more = vec![n + 1, 2 * n + 3];
            if len < 5000 {
                more.extend([len, len + 1, 3 * len + 5]);
            }
            check_parts(&xyz.0, &more);
            check_parts(&npy.0, &[n + 1, 2 * n + 3, 1000]);
        }
    }

    #[test]
    fn npy_of_every_dtype_and_order_reads_by_parts() {
        let sites = random_sites(23, 9);
        let narrow: Vec<[f32; 3]> = sites
            .iter()
            .map(|p| {
                p.map(|c| Some(f32::from_bits((c.to_bits() >> 32) as u32)).filter(|c| c.is_finite()).unwrap_or(0.5))
            })
            .collect();
        for fortran in [false, true] {
            let f64_values: Vec<f64> = if fortran {
                (0..3).flat_map(|a| sites.iter().map(move |p| p[a])).collect()
            } else {
                sites.iter().flatten().copied().collect()
            };
            let f32_values: Vec<f32> = if fortran {
                (0..3).flat_map(|a| narrow.iter().map(move |p| p[a])).collect()
            } else {
                narrow.iter().flatten().copied().collect()
            };
            let order = if fortran { "True" } else { "False" };
            for (version, descr, data) in [
                (1, "<f8", f64_values.iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>()),
                (3, "<f4", f32_values.iter().flat_map(|v| v.to_le_bytes()).collect()),
            ] {
                let dict = format!("{{'descr': '{descr}', 'fortran_order': {order}, 'shape': (23, 3), }}");
                let file = Temp::new(&format!("parts_{}_{fortran}.npy", &descr[1..]), &npy(version, &dict, &data));
                check_parts(&file.0, &[22, 23, 24, 50]);
                assert_eq!(read_by_parts(&file.0, 4).unwrap().len(), 23);
            }
        }
    }

    /// Hand-written texts: comments, blank lines, CRLF line ends, no last
    /// line end, count lines after long comments, lines of all lengths.
    const TEXTS: &[&str] = &[
        "",
        "\n\n",
        "# only a comment",
        "0 0 0",
        "1 2 3\n4 5 6",
        "# sites\r\n\r\n0.5 -1 2\r\n1e-3 0 3.25 # here\r\n   \r\n7 8 9\r\n",
        "3\n1 1 1\n\n# c\n2 2 2\n3 3 3",
        "# a long header, longer than a part\n# a long header, longer than a part\n\n  \t 2 # count\n1 2 3\n4 5 6\n",
        "0\n",
        "0\n# nothing\n\n",
        "   1.5    2.5\t3.5   \n\n\n\n\n\n\n\n\n\n\n\n\n\n\n\n1e300 -1e-300 5e-324\n",
        "0.10000000000000001 0.2 0.30000000000000004\n123456789012345678901234567890 1 1\n",
    ];

    /// Bad texts, each refused whole and by parts.
    const BAD_TEXTS: &[&str] = &[
        "1 2\n",
        "0 0 0\n1 nan 1\n",
        "0 0 0\n5\n1 1 1\n",
        "2\n0 0 0\n",
        "1\n0 0 0\n1 1 1\n",
        "0.5\n1 1 1\n",
        "# c\n\n3\n0 0 0\n1 1 1\n",
        "0 0 0\n1 1 1\n2 2 2\n3\n",
        "0 0 0 0\n",
        "x 0 0\n",
        "1e400 0 0\n",
        "0 0 0\n\u{fffd} 1 1\n",
        "-1\n",
    ];

    #[test]
    fn hand_written_texts_read_by_parts_as_whole() {
        for (i, text) in TEXTS.iter().enumerate() {
            let file = Temp::new(&format!("parts_text_{i}.xyz"), text.as_bytes());
            assert!(read_sites(&file.0).is_ok(), "{text:?}");
            // Every number of parts up to one a byte and beyond: every byte
            // is a part boundary somewhere.
            let more: Vec<usize> = (8..text.len() + 3).collect();
            check_parts(&file.0, &more);
        }
        for (i, text) in BAD_TEXTS.iter().enumerate() {
            let file = Temp::new(&format!("parts_bad_{i}.xyz"), text.as_bytes());
            assert!(read_sites(&file.0).is_err(), "{text:?}");
            let more: Vec<usize> = (8..text.len() + 3).collect();
            check_parts(&file.0, &more);
        }
        // Not UTF-8: replaced as the whole file's reader replaces it.
        let file = Temp::new("parts_latin1.txt", b"# caf\xe9\n2\n0 0 0 # \xff\xfe\n1 1 1\n");
        check_parts(&file.0, &(8..40).collect::<Vec<_>>());
    }

    #[test]
    fn a_line_starting_at_a_part_boundary_is_that_parts() {
        // 24 bytes in 2 parts: the second line starts at byte 12, the
        // second part's first byte (the byte before it is a line end).
        let text = "1.0 2.0 3.0\n4.0 5.0 6.0\n";
        assert_eq!(text.len(), 24);
        let file = Temp::new("parts_boundary.xyz", text.as_bytes());
        let [a, b] = [0, 1].map(|k| read_sites_part(&file.0, k, 2).unwrap().sites);
        assert_eq!((a, b), (vec![[1.0, 2.0, 3.0]], vec![[4.0, 5.0, 6.0]]));
        // One byte earlier, the line is the first part's; one byte later
        // (its line end the second part's first byte), the second part's.
        let file = Temp::new("parts_boundary_early.xyz", b"1.0 2.0 3.\n4.0 5.0 6.0  \n");
        let [a, b] = [0, 1].map(|k| read_sites_part(&file.0, k, 2).unwrap().sites.len());
        assert_eq!((a, b), (2, 0));
        let file = Temp::new("parts_boundary_late.xyz", b"1.0 2.0 3.0 \n4.0 5.0 6.\n");
        let [a, b] = [0, 1].map(|k| read_sites_part(&file.0, k, 2).unwrap().sites.len());
        assert_eq!((a, b), (1, 1));
    }

    #[test]
    fn errors_name_the_file_and_the_lines_byte() {
        // 10 lines of 12 bytes; in 3 parts of 40 bytes, part 2 holds the
        // lines at 84, 96 and 108 (the one at 36 is part 0's, at 72 part 1's).
        let mut lines: Vec<String> = (0..10).map(|i| format!("{i}.0 1.0 2.0\n")).collect();
        lines[8] = "8.0 1.0 x.0\n".into();
        let file = Temp::new("parts_bad_line.xyz", lines.concat().as_bytes());
        let name = file.0.display().to_string();
        for k in 0..2 {
            read_sites_part(&file.0, k, 3).unwrap();
        }
        let e = read_sites_part(&file.0, 2, 3).unwrap_err().to_string();
        assert_eq!(
            e,
            format!("invalid input: {name}: the line at byte 96: expected the z coordinate (a finite number), found \"x.0\"")
        );
        lines[8] = "8.0 1.0\n".into();
        std::fs::write(&file.0, lines.concat()).unwrap();
        let e = read_sites_part(&file.0, 2, 3).unwrap_err().to_string();
        assert!(
            e.ends_with(&format!("{name}: the line at byte 96: expected 3 coordinates x y z, found 2 values")),
            "{e}"
        );
        // Across parts, from the joins: a count line not first, a count
        // that the sites do not match.
        let file = Temp::new("parts_bad_count.xyz", b"0 0 0\n1 1 1\n7\n2 2 2\n");
        let e = read_by_parts(&file.0, 2).unwrap_err().to_string();
        assert!(e.ends_with("the line at byte 12: expected 3 coordinates x y z for point 3, found 1 value"), "{e}");
        let file = Temp::new("parts_short_count.xyz", b"# n\n3\n0 0 0\n1 1 1\n");
        let e = read_by_parts(&file.0, 3).unwrap_err().to_string();
        assert!(e.ends_with("expected 3 points (the count on the line at byte 4), found 2"), "{e}");
        let file = Temp::new("parts_bad_count_line.xyz", b"# n\n-3\n0 0 0\n1 1 1\n");
        let e = read_sites_part(&file.0, 0, 1).unwrap_err().to_string();
        assert!(e.ends_with("the line at byte 4: expected a point count or 3 coordinates x y z (a non-negative integer), found \"-3\""), "{e}");
        // Bad arguments.
        assert!(read_sites_part(&file.0, 3, 3).is_err());
        let e = read_sites_part(&file.0, 0, 0).unwrap_err().to_string();
        assert!(e.ends_with("part 0 of 0: expected at least 1 part"), "{e}");
        let mut part = SitesPart { first: None, sites: vec![], total: None, count_line: None };
        assert!(part.join(&file.0, &[], 0).is_err());
        assert!(part.join(&file.0, &[SitesPartSummary { sites: 1, count_line: None }], 0).is_err());
    }

    #[test]
    fn values_read_by_parts_as_whole() {
        let texts = ["1\n2.5\n-3e-2\n", "# radii\n0.5\n\n  0.75  \r\n1 # big\n0.25", "", "\n\n# nothing\n", "7\n"];
        let many: String = (0..997).map(|i| format!("{}\n", (i as f64 * 0.37).sin())).collect();
        for (i, text) in texts.iter().copied().chain([many.as_str()]).enumerate() {
            let file = Temp::new(&format!("parts_values_{i}.txt"), text.as_bytes());
            let whole = crate::read::read_values(&file.0).unwrap();
            for parts in 1..=7 {
                let joined: Vec<f64> = (0..parts).flat_map(|k| read_values_part(&file.0, k, parts).unwrap()).collect();
                let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&joined), bits(&whole), "text {i} in {parts} parts");
            }
        }
        // A bad line, named by its byte in the part that reads it.
        let file = Temp::new("parts_values_bad.txt", b"1.0\n2.0\n3.0 4.0\n5.0\n");
        // 20 bytes in 2 parts: the line at byte 8 starts in part 0.
        let m = read_values_part(&file.0, 0, 2).unwrap_err().to_string();
        assert!(
            m.contains("parts_values_bad.txt") && m.contains("the line at byte 8") && m.contains("one number"),
            "{m}"
        );
        assert_eq!(read_values_part(&file.0, 1, 2).unwrap(), vec![5.0], "the second part holds no bad line");
        let m = read_values_part(&file.0, 2, 2).unwrap_err().to_string();
        assert!(m.contains("part 2 of 2"), "{m}");
    }

    #[test]
    fn npy_errors_name_the_file() {
        let sites = random_sites(10, 3);
        let file = Temp(temp_path("parts_cut.npy"));
        write_sites_npy(&file.0, &sites).unwrap();
        let bytes = std::fs::read(&file.0).unwrap();
        let name = file.0.display().to_string();
        std::fs::write(&file.0, &bytes[..bytes.len() - 8]).unwrap();
        for parts in [1, 3] {
            let e = read_sites_part(&file.0, 0, parts).unwrap_err().to_string();
            assert_eq!(
                e,
                format!(
                    "invalid input: {name}: expected 10 × 3 float64 values (240 bytes) after the 128-byte header, \
                     found 232 bytes: the file is truncated"
                )
            );
        }
        std::fs::write(&file.0, &bytes[..50]).unwrap();
        let e = read_sites_part(&file.0, 1, 2).unwrap_err().to_string();
        assert!(e.contains(&name) && e.contains("expected a header of 118 bytes"), "{e}");
        // A NaN names its row in the whole file.
        let mut bad = sites.clone();
        bad[7][2] = f64::NAN;
        write_sites_npy(&file.0, &bad).unwrap();
        read_sites_part(&file.0, 0, 2).unwrap();
        let e = read_sites_part(&file.0, 1, 2).unwrap_err().to_string();
        assert!(e.ends_with("expected the z coordinate of point 8 (a finite number), found NaN"), "{e}");
    }

    #[test]
    fn a_part_of_a_huge_file_reads_only_its_range() {
        use std::io::{Seek, SeekFrom, Write};
        // 64 GiB of rows, a hole that reads as zeros but for the part's
        // first row.
        let n: u64 = (64 << 30) / 24;
        let first = n * 1000 / 100_000;
        let file = Temp(temp_path("parts_huge.npy"));
        let header = npy(1, &format!("{{'descr': '<f8', 'fortran_order': False, 'shape': ({n}, 3), }}"), &[]);
        let mut f = std::fs::File::create(&file.0).unwrap();
        f.set_len(header.len() as u64 + n * 24).unwrap();
        f.write_all(&header).unwrap();
        f.seek(SeekFrom::Start(header.len() as u64 + first * 24)).unwrap();
        f.write_all(&[1.5f64, -2.5, 3.5].map(f64::to_le_bytes).concat()).unwrap();
        drop(f);
        let start = Instant::now();
        let part = read_sites_part(&file.0, 1000, 100_000).unwrap();
        assert!(start.elapsed().as_secs_f64() < 5.0, "{:?}", start.elapsed());
        assert_eq!((part.first, part.total), (Some(first), Some(n)));
        assert_eq!(part.sites.len() as u64, n * 1001 / 100_000 - first);
        assert_eq!(part.sites[0], [1.5, -2.5, 3.5]);
        assert!(part.sites[1..].iter().all(|p| p.iter().all(|c| c.to_bits() == 0)));
        // A text file likewise: 64 GiB of zero bytes (one line, which is
        // part 0's), then two lines. Part 1000 holds no line start; the last
        // part, the two lines.
        let size: u64 = 64 << 30;
        let text = Temp(temp_path("parts_huge.xyz"));
        let mut f = std::fs::File::create(&text.0).unwrap();
        let lines = b"\n1 2 3\n4 5 6\n";
        f.set_len(size).unwrap();
        f.seek(SeekFrom::Start(size - lines.len() as u64)).unwrap();
        f.write_all(lines).unwrap();
        drop(f);
        let start = Instant::now();
        let part = read_sites_part(&text.0, 1000, 100_000).unwrap();
        assert_eq!(part, SitesPart { first: None, sites: vec![], total: None, count_line: None });
        let last = read_sites_part(&text.0, 99_999, 100_000).unwrap();
        assert!(start.elapsed().as_secs_f64() < 5.0, "{:?}", start.elapsed());
        assert_eq!(last.sites, [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
    }

    /// One line of a random text: points, comments, blank lines, counts.
    fn line() -> impl Strategy<Value = String> {
        let coordinate = prop_oneof![
            any::<f64>().prop_filter("finite", |x| x.is_finite()).prop_map(|x| x.to_string()),
            (-1e6f64..1e6).prop_map(|x| format!("{x:e}")),
            "-?[0-9]{1,3}\\.[0-9]{1,20}",
        ];
        let point = [coordinate.clone(), coordinate.clone(), coordinate].prop_map(|[x, y, z]| format!("{x} {y} {z}"));
        prop_oneof![
            20 => point.clone().prop_map(|p| p + "\n"),
            3 => point.prop_map(|p| format!("  {p}\t# here\r\n")),
            3 => prop::sample::select(vec!["\n", "   \n", "\r\n", "# comment 1 2 3\n", "#\n"]).prop_map(String::from),
            1 => prop::sample::select(vec!["1 2\n", "1 nan 2\n", "5\n", "0\n", "x\n"]).prop_map(String::from),
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

        /// Random texts, with or without a count line and a last line end:
        /// the same sites or an error, whole and in any number of parts.
        #[test]
        fn random_texts_read_by_parts_as_whole(
            lines in prop::collection::vec(line(), 0..30),
            head in prop::sample::select(vec!["", "# sites\n", "\n\n"]),
            count in prop::option::of(-1i64..=1),
            last_end in any::<bool>(),
            parts in 1usize..40,
        ) {
            let mut text = head.to_string();
            if let Some(delta) = count {
                let points = lines.iter().filter(|l| l.split('#').next().unwrap().split_ascii_whitespace().count() > 1);
                text += &format!("{}\n", (points.count() as i64 + delta).max(0));
            }
            text.extend(lines);
            if !last_end && text.ends_with('\n') {
                text.pop();
            }
            let file = Temp::new("parts_random.xyz", text.as_bytes());
            check_parts(&file.0, &[parts, parts * 7]);
        }
    }
}
