//! What the particle readers share: the frame they give
//! ([`ParticleFrame`]), their trait ([`FrameReader`]), the opening of a
//! file by its extension ([`open_particles`]), and the streaming of lines,
//! the atom lines' columns and the sorting by id used by both formats
//! (`lammps_dump.rs`, `extxyz.rs`).
//!
//! The readers stream: a file is read line by line through a buffer, one
//! frame at a time, so a trajectory of any length takes the memory of one
//! frame. Frames are numbered from 0 (as [`ParticleFrame::index`] and as
//! OVITO numbers them), and every error names the file, the line and the
//! frame: `dump.lj:1234: frame 3: expected 5 values (id type x y z) for
//! atom 17, found 4`.

use super::formats::{self, PARTICLES};
use super::lex::{parse_error, plural, shown};
use cvd::backends::distributed::Reduce;
use cvd::error::{Error, Result};
use cvd::PeriodicBox;
use std::fmt::Display;
use std::io::{BufRead, Read, Seek, SeekFrom};
use std::path::Path;

/// One frame of a trajectory: the particles at one time and their box.
#[derive(Clone, Debug, PartialEq)]
pub struct ParticleFrame {
    /// The frame's number in the file, from 0.
    pub index: usize,
    /// The simulation's step: LAMMPS's `ITEM: TIMESTEP`; in extended XYZ
    /// the `step`, `Step` or `timestep` key (any case), if given.
    pub timestep: Option<u64>,
    /// The cell, with its periodic axes.
    pub domain: PeriodicBox,
    /// Cartesian positions as given (not wrapped into the cell; scaled
    /// coordinates are turned into Cartesian ones).
    pub positions: Vec<[f64; 3]>,
    /// The particles' ids (LAMMPS's `id` column, extended XYZ's `id`
    /// property) when given: the rows are then sorted by id, so the same
    /// particle has the same place in every frame.
    pub ids: Option<Vec<u64>>,
    /// The particles' radii (a `radius` column or property, or extended
    /// XYZ's `radii`) when given.
    pub radii: Option<Vec<f64>>,
    /// Read in parts ([`FrameReader::next_in_parts`]): which of the
    /// frame's atoms these rows are. `None`: all of them, sorted by id.
    pub part: Option<FramePart>,
}

/// The rows of a frame one part of a run read ([`FrameReader::next_in_parts`]):
/// atoms `first..first + len` of the file's order, not sorted by id.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FramePart {
    /// The frame's atoms in all.
    pub total: usize,
    /// The first row's place among the frame's atom lines, from 0.
    pub first: usize,
    /// The line the first row was read from (row `i` is on line
    /// `first_line + i`), for errors.
    pub first_line: usize,
}

impl ParticleFrame {
    /// The number of particles.
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    /// Whether the frame holds no particle.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }
}

/// A reader of a trajectory's frames, one at a time, in the file's order.
///
/// After an error the reader ends: the next call gives `None` (and
/// [`skip_frame`](Self::skip_frame) `Ok(false)`). `nth(n)` skips `n`
/// frames with `skip_frame` before reading one.
pub trait FrameReader: Iterator<Item = Result<ParticleFrame>> + Send {
    /// Passes over the next frame without parsing its atoms (its lines
    /// are still counted, for the line numbers of later errors): `Ok(true)`
    /// when a frame was skipped, `Ok(false)` at the end of the file, an
    /// error if the frame's header is wrong or the file ends inside it.
    fn skip_frame(&mut self) -> Result<bool>;

    /// The index the next frame read or skipped will have.
    fn next_index(&self) -> usize;

    /// The next frame read in parts over the ranks of `comm`, every rank
    /// calling it in step: rank `p` of `P` gets the atom lines
    /// `n p / P..n (p + 1) / P` of the frame's `n`, in the file's order
    /// (not sorted by id: the ranks sort them together), with
    /// [`ParticleFrame::part`] saying which. No rank reads the whole frame:
    /// every rank reads the frame's few header lines, the ranks find where
    /// the parts' lines start by each counting the line ends of a share of
    /// the frame's bytes, and each then parses only its own lines' bytes
    /// (see [`atoms_in_parts`]). An atom line's error is the error of the
    /// rank that reads it; a frame cut short is every rank's.
    fn next_in_parts(&mut self, comm: &dyn Reduce) -> Option<Result<ParticleFrame>>;

    /// [`skip_frame`](Self::skip_frame) in parts over the ranks of `comm`,
    /// every rank calling it in step: each counts the line ends of a share
    /// of the frame's bytes.
    fn skip_in_parts(&mut self, comm: &dyn Reduce) -> Result<bool>;
}

/// Opens a particle file, choosing the reader by the extension (any case)
/// from [`formats::PARTICLES`] (also files named `dump.*`, whatever their
/// extension, as LAMMPS dumps); any other file is an
/// [`Error::InvalidInput`] listing the formats. Only the file's opening
/// is done here: frames are read as the reader is iterated.
pub fn open_particles(path: &Path) -> Result<Box<dyn FrameReader>> {
    match formats::find_particles(path) {
        Some(format) => format.read(path),
        None => Err(formats::unknown(PARTICLES, "particle", path)),
    }
}

/// A file opened for reading through a buffer; errors name it.
pub(super) fn open_buffered(path: &Path) -> Result<std::io::BufReader<std::fs::File>> {
    let file = std::fs::File::open(path).map_err(|source| Error::Io { path: path.display().to_string(), source })?;
    Ok(std::io::BufReader::with_capacity(1 << 16, file))
}

/// The longest line read: longer is not a text file.
const MAX_LINE: u64 = 4 << 20;

/// How many rows to reserve for a frame announcing `count`: a count
/// written in a file reserves no more than a frame of some size, the rest
/// grows as lines come.
pub(super) fn reserve(count: usize) -> usize {
    count.min(1 << 16)
}

/// The lines of a file, read one at a time through its buffer, counted
/// from 1; errors name the file, the line and the frame being read.
pub(super) struct Lines<R> {
    reader: R,
    path: String,
    /// The frame being read, for errors.
    pub frame: usize,
    /// The current line, without its line end.
    text: String,
    /// The current line's number: 0 before the first, else the lines read.
    no: usize,
    /// The bytes of the file read as lines or passed over: where the next
    /// line starts (when `reader` was at the file's start).
    offset: u64,
}

impl<R: BufRead> Lines<R> {
    pub fn new(reader: R, path: String) -> Self {
        Self::at(reader, path, 0, 0)
    }

    /// The lines of `reader`, whose first is the file's line `after + 1`,
    /// read in frame `frame`.
    fn at(reader: R, path: String, frame: usize, after: usize) -> Self {
        Self { reader, path, frame, text: String::new(), no: after, offset: 0 }
    }

    /// The current line (valid after [`Self::next`] gave `true`).
    pub fn text(&self) -> &str {
        &self.text
    }

    /// The current line's number (the last line read).
    pub fn no(&self) -> usize {
        self.no
    }

    /// An error at `line`, in the current frame.
    pub fn error_at(&self, line: usize, message: impl Display) -> Error {
        parse_error(&self.path, line, format!("frame {}: {message}", self.frame))
    }

    /// An error at the current line, in the current frame.
    pub fn error(&self, message: impl Display) -> Error {
        self.error_at(self.no, message)
    }

    /// "expected `what`, found `token`" at the current line.
    pub fn unexpected(&self, token: &str, what: impl Display) -> Error {
        self.error(format_args!("expected {what}, found {}", shown(token)))
    }

    /// "expected `what`, found end of file" at the last line.
    pub fn missing(&self, what: impl Display) -> Error {
        self.error(format_args!("expected {what}, found end of file"))
    }

    fn io(&self, source: std::io::Error) -> Error {
        Error::Io { path: self.path.clone(), source }
    }

    /// Reads the next line: `false` at the end of the file. Bytes that are
    /// not UTF-8 read as U+FFFD.
    pub fn next(&mut self) -> Result<bool> {
        // The last line's allocation, reused.
        let mut bytes = std::mem::take(&mut self.text).into_bytes();
        bytes.clear();
        let read = (&mut self.reader).take(MAX_LINE).read_until(b'\n', &mut bytes);
        let n = read.map_err(|e| self.io(e))?;
        if n == 0 {
            return Ok(false);
        }
        self.no += 1;
        self.offset += n as u64;
        if bytes.last() == Some(&b'\n') {
            bytes.pop();
            if bytes.last() == Some(&b'\r') {
                bytes.pop();
            }
        } else if n as u64 == MAX_LINE {
            return Err(self.error(format_args!("a line longer than {} MiB (not a text file?)", MAX_LINE >> 20)));
        }
        self.text = String::from_utf8(bytes).unwrap_or_else(|e| String::from_utf8_lossy(e.as_bytes()).into_owned());
        Ok(true)
    }

    /// Reads the next line holding more than whitespace: `false` at the
    /// end of the file.
    pub fn next_nonblank(&mut self) -> Result<bool> {
        while self.next()? {
            if !is_blank(&self.text) {
                return Ok(true);
            }
        }
        Ok(false)
    }

    /// The next line, which must exist: `what` names it for the error.
    pub fn expect(&mut self, what: impl Display) -> Result<()> {
        match self.next()? {
            true => Ok(()),
            false => Err(self.missing(what)),
        }
    }

    /// Passes over `n` lines without looking at them but for their ends;
    /// returns how many there were (fewer at the end of the file). The
    /// current line's text is then undefined.
    pub fn skip(&mut self, n: usize) -> Result<usize> {
        let mut skipped = 0;
        // Whether bytes of a line were passed since the last line end.
        let mut partial = false;
        while skipped < n {
            let chunk = match self.reader.fill_buf() {
                Ok(chunk) => chunk,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(self.io(e)),
            };
            if chunk.is_empty() {
                if partial {
                    skipped += 1;
                    self.no += 1;
                }
                break;
            }
            let mut used = chunk.len();
            for (i, _) in chunk.iter().enumerate().filter(|(_, &b)| b == b'\n') {
                skipped += 1;
                self.no += 1;
                if skipped == n {
                    used = i + 1;
                    break;
                }
            }
            partial = chunk[..used].last() != Some(&b'\n');
            self.reader.consume(used);
            self.offset += used as u64;
        }
        self.text.clear();
        Ok(skipped)
    }
}

/// Whether a line holds only whitespace.
pub(super) fn is_blank(text: &str) -> bool {
    text.bytes().all(|b| b.is_ascii_whitespace())
}

/// `token` as a finite f64, or the error "expected `what` (a finite
/// number), found ..." on the current line.
pub(super) fn finite<R: BufRead>(lines: &Lines<R>, token: &str, what: impl Display) -> Result<f64> {
    match token.parse::<f64>() {
        Ok(x) if x.is_finite() => Ok(x),
        _ => Err(lines.unexpected(token, format_args!("{what} (a finite number)"))),
    }
}

/// `token` as a non-negative integer, or the error.
pub(super) fn unsigned<R: BufRead>(lines: &Lines<R>, token: &str, what: impl Display) -> Result<u64> {
    token.parse::<u64>().map_err(|_| lines.unexpected(token, format_args!("{what} (a non-negative integer)")))
}

/// `token` as a count, or the error.
pub(super) fn count<R: BufRead>(lines: &Lines<R>, token: &str, what: impl Display) -> Result<usize> {
    token.parse::<usize>().map_err(|_| lines.unexpected(token, format_args!("{what} (a non-negative integer)")))
}

/// The current line's tokens, which must be `n`: else "expected `n`
/// values (`what`), found ...".
pub(super) fn tokens<R: BufRead>(lines: &Lines<R>, n: usize, what: impl Display) -> Result<Vec<&str>> {
    let toks: Vec<&str> = lines.text().split_ascii_whitespace().collect();
    if toks.len() != n {
        let (found, values) = (toks.len(), plural(n, "value", "values"));
        return Err(lines.error(format_args!("expected {n} {values} ({what}), found {found}")));
    }
    Ok(toks)
}

/// The message of a box's error, without the error's kind.
pub(super) fn box_message(e: Error) -> String {
    match e {
        Error::InvalidInput(m) => m,
        other => other.to_string(),
    }
}

/// What a column of the atom lines gives.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Field {
    /// A position's coordinate along x, y or z (or a, b, c if scaled).
    Position(usize),
    Id,
    Radius,
}

/// The columns of a frame's atom lines: how many, and which of them are
/// read.
#[derive(Clone, Debug)]
pub(super) struct Columns {
    /// Values on each atom line.
    pub count: usize,
    /// The columns read, by their place on the line.
    pub fields: Vec<(usize, Field)>,
    /// Whether positions are fractional coordinates of the cell.
    pub scaled: bool,
    /// The columns' description in errors, e.g. "id type x y z".
    pub names: String,
}

impl Columns {
    /// The columns, `fields` in any order.
    pub fn new(count: usize, mut fields: Vec<(usize, Field)>, scaled: bool, names: String) -> Self {
        fields.sort_by_key(|&(at, _)| at);
        Self { count, fields, scaled, names }
    }

    fn has(&self, field: Field) -> bool {
        self.fields.iter().any(|&(_, f)| f == field)
    }
}

/// The atoms of a frame as read, in the file's order.
pub(super) struct Rows {
    pub positions: Vec<[f64; 3]>,
    pub ids: Option<Vec<u64>>,
    pub radii: Option<Vec<f64>>,
}

/// Where a frame's atom lines start and what announced their count, for
/// errors: the count's line and a description such as "ITEM: NUMBER OF
/// ATOMS".
pub(super) struct Atoms<'a> {
    pub count: usize,
    pub count_line: usize,
    pub count_name: &'a str,
    /// A line starting so (LAMMPS's `ITEM:`) is a frame's start, not an
    /// atom: the frame has too few atom lines.
    pub stop: Option<&'a str>,
}

impl Atoms<'_> {
    /// "expected `count` atom lines (... on line ...), found `found`".
    fn too_few(&self, found: usize) -> String {
        let n = self.count;
        let lines = plural(n, "atom line", "atom lines");
        format!("expected {n} {lines} ({} on line {}), found {found}", self.count_name, self.count_line)
    }

    /// The error for a file that ends after `found` atom lines.
    pub fn cut_short<R: BufRead>(&self, lines: &Lines<R>, found: usize) -> Error {
        lines.error(format_args!("{}: the file ends (cut short?)", self.too_few(found)))
    }
}

/// Reads a frame's atom lines, one per line with no line between them:
/// positions (Cartesian, or fractional in `domain` if the columns are
/// scaled), ids and radii when the columns have them, then sorted by id.
pub(super) fn read_atoms<R: BufRead>(
    lines: &mut Lines<R>,
    columns: &Columns,
    atoms: &Atoms,
    domain: &PeriodicBox,
) -> Result<Rows> {
    let first = lines.no() + 1;
    let mut rows = parse_atoms(lines, columns, atoms, domain, 0..atoms.count)?;
    sort_by_id(&mut rows, first, lines)?;
    Ok(rows)
}

/// Parses the atom lines `range` of a frame's, the next lines of `lines`.
fn parse_atoms<R: BufRead>(
    lines: &mut Lines<R>,
    columns: &Columns,
    atoms: &Atoms,
    domain: &PeriodicBox,
    range: std::ops::Range<usize>,
) -> Result<Rows> {
    let (lo, hi) = (range.start, range.end);
    let mut rows = Rows {
        positions: Vec::with_capacity(reserve(hi - lo)),
        ids: columns.has(Field::Id).then(|| Vec::with_capacity(reserve(hi - lo))),
        radii: columns.has(Field::Radius).then(|| Vec::with_capacity(reserve(hi - lo))),
    };
    for i in lo..hi {
        if !lines.next()? {
            return Err(atoms.cut_short(lines, i));
        }
        let text = lines.text();
        if atoms.stop.is_some_and(|s| text.trim_start().starts_with(s)) {
            return Err(lines.error(format_args!("{} before this line", atoms.too_few(i))));
        }
        let atom = i + 1;
        // The line split once: the values read kept, all counted.
        let mut values = [""; 5];
        let mut found = 0;
        let mut fields = columns.fields.iter().peekable();
        for (k, tok) in text.split_ascii_whitespace().enumerate() {
            if let Some(&&(at, field)) = fields.peek() {
                if at == k {
                    values[slot(field)] = tok;
                    fields.next();
                }
            }
            found += 1;
        }
        if found != columns.count {
            let count = columns.count;
            return Err(lines.error(format_args!(
                "expected {count} {} ({}) for atom {atom}, found {found}",
                plural(count, "value", "values"),
                columns.names
            )));
        }
        let mut p = [0.0; 3];
        for (axis, c) in p.iter_mut().enumerate() {
            let name = if columns.scaled { ["xs", "ys", "zs"][axis] } else { ["x", "y", "z"][axis] };
            *c = finite(lines, values[axis], format_args!("{name} of atom {atom}"))?;
        }
        rows.positions.push(if columns.scaled { domain.cartesian(p) } else { p });
        if let Some(ids) = &mut rows.ids {
            ids.push(unsigned(lines, values[3], format_args!("the id of atom {atom}"))?);
        }
        if let Some(radii) = &mut rows.radii {
            let tok = values[4];
            match tok.parse::<f64>() {
                Ok(r) if r.is_finite() && r >= 0.0 => radii.push(r),
                _ => {
                    return Err(lines.unexpected(tok, format_args!("the radius of atom {atom} (a finite number >= 0)")))
                }
            }
        }
    }
    Ok(rows)
}

/// The bytes each rank counts line ends in, per round, when a frame's
/// size is not yet known well: at least this, at most [`MAX_CHUNK`].
const MIN_CHUNK: u64 = 64 << 10;
/// The most bytes a rank holds while counting line ends.
const MAX_CHUNK: u64 = 64 << 20;

/// What a reader in parts keeps from frame to frame.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct PartsScan {
    /// The bytes of an atom line in the last frame read, on average.
    line_bytes: Option<f64>,
    /// The bytes each rank counts per round, if fixed (tests).
    #[cfg(test)]
    pub chunk: Option<u64>,
}

/// A frame's atom lines read in parts over the ranks of `comm` (all
/// calling it in step), `lines` standing after the frame's header: rank
/// `p` of `P` parses the atom lines `n p / P..n (p + 1) / P` when `parse`
/// gives the columns and the cell (else only passes over the frame), and
/// `lines` is left after the frame's last atom line.
///
/// No rank reads the whole frame. The ranks count line ends in rounds:
/// in each, rank `p` reads the `p`-th of `P` consecutive chunks of bytes
/// (sized from the last frame's bytes per line, or this frame's first
/// line's, so that one round mostly covers the frame) and the counts are
/// all-gathered; the rank whose chunk holds the line end before a part's
/// first line tells its byte offset. Each rank then reads its own lines'
/// bytes: about `2 / P` of the frame's bytes a rank. Every rank learns
/// the same counts, so a frame cut short is the same error on all.
pub(super) fn atoms_in_parts<R: BufRead + Seek>(
    lines: &mut Lines<R>,
    atoms: &Atoms,
    comm: &dyn Reduce,
    parse: Option<(&Columns, &PeriodicBox)>,
    scan: &mut PartsScan,
) -> Result<(Rows, FramePart)> {
    let (n, parts, p) = (atoms.count, comm.size(), comm.rank());
    // The line before the first atom line, and the byte it starts at.
    let (before, start) = (lines.no(), lines.offset);
    let chunk = chunk_bytes(lines, n, parts, scan);
    // Line `t` of the frame starts after `t` line ends.
    let targets: Vec<u64> = (0..=parts).map(|q| share(n, q, parts) as u64).collect();
    let path = lines.path.clone();
    let io = move |source| Error::Io { path: path.clone(), source };
    // The bytes this rank read first (from where), kept to parse from.
    let mut held = (start, Vec::new());
    let starts = match line_starts(&mut lines.reader, start, &targets, chunk, comm, &io, &mut held)? {
        Ok(starts) => starts,
        Err(found) => {
            lines.no = before + found as usize;
            return Err(atoms.cut_short(lines, found as usize));
        }
    };
    let end = starts[parts];
    if n > 0 {
        scan.line_bytes = Some((end - start) as f64 / n as f64);
    }
    let (lo, hi) = (share(n, p, parts), share(n, p + 1, parts));
    let rows = match parse {
        Some((columns, domain)) => {
            // This rank's lines' bytes: what it holds of them, the bytes
            // before read (the chunks are sized so that they are few), the
            // rest streamed from the file: no more of the frame's text is
            // held than the chunk counted.
            let (a, b) = (starts[p], starts[p + 1]);
            let (from, bytes) = (held.0, &held.1);
            let (inner_a, inner_b) = (a.max(from), b.min(from + bytes.len() as u64));
            let (before_held, middle, rest) = match inner_a < inner_b {
                true => {
                    let mut out = vec![0; (inner_a - a) as usize];
                    lines.reader.seek(SeekFrom::Start(a)).map_err(&io)?;
                    lines.reader.read_exact(&mut out).map_err(&io)?;
                    (out, &bytes[(inner_a - from) as usize..(inner_b - from) as usize], inner_b..b)
                }
                false => (Vec::new(), &[][..], a..b),
            };
            lines.reader.seek(SeekFrom::Start(rest.start)).map_err(&io)?;
            let (path, frame) = (lines.path.clone(), lines.frame);
            let streamed = (&mut lines.reader).take(rest.end - rest.start);
            let own = std::io::Cursor::new(before_held).chain(middle).chain(streamed);
            let mut own = Lines::at(own, path, frame, before + lo);
            parse_atoms(&mut own, columns, atoms, domain, lo..hi)?
        }
        None => Rows { positions: Vec::new(), ids: None, radii: None },
    };
    lines.reader.seek(SeekFrom::Start(end)).map_err(|e| lines.io(e))?;
    (lines.no, lines.offset) = (before + n, end);
    lines.text.clear();
    Ok((rows, FramePart { total: n, first: lo, first_line: before + lo + 1 }))
}

/// The bytes each rank counts line ends in per round for a frame of `n`
/// atom lines over `parts` ranks: a share of the frame's expected bytes
/// (the last frame's bytes per line, else the first atom lines' length),
/// a little over, so that one round mostly covers the frame.
fn chunk_bytes<R: BufRead>(lines: &mut Lines<R>, n: usize, parts: usize, scan: &PartsScan) -> u64 {
    #[cfg(test)]
    if let Some(chunk) = scan.chunk {
        return chunk;
    }
    let line = scan.line_bytes.unwrap_or_else(|| {
        // The first atom lines the buffer holds, on average.
        let held = lines.reader.fill_buf().unwrap_or(&[]);
        let held = &held[..held.len().min(1 << 16)];
        let ends = held.iter().enumerate().filter(|(_, &b)| b == b'\n').map(|(i, _)| i + 1).take(n.max(1));
        let (count, last) = ends.fold((0, 0), |(count, _), end| (count + 1, end));
        if count == 0 {
            64.0
        } else {
            last as f64 / count as f64
        }
    });
    let frame = line * n as f64 * 1.02 / parts.max(1) as f64;
    (frame as u64 + 4096).clamp(MIN_CHUNK, MAX_CHUNK)
}

/// The byte offsets where the lines `targets` (ascending) start, counted
/// from 0 at `start`: line `t` starts after the `t`-th line end (the
/// file's end ends a last line without one). Found by the ranks of `comm`
/// together, each reading only its chunks (see [`atoms_in_parts`]); every
/// rank gets all of them, or `Err(lines)` if the file holds only `lines`
/// lines after `start`, fewer than the last target. `held`: the bytes
/// this rank read in the first round and where they start.
fn line_starts<R: Read + Seek>(
    reader: &mut R,
    start: u64,
    targets: &[u64],
    chunk: u64,
    comm: &dyn Reduce,
    io: &dyn Fn(std::io::Error) -> Error,
    held: &mut (u64, Vec<u8>),
) -> Result<std::result::Result<Vec<u64>, u64>> {
    let (parts, p) = (comm.size() as u64, comm.rank() as u64);
    let want = targets.last().copied().unwrap_or(0);
    // The offsets this rank found, by target; the line ends counted before
    // this round's chunks.
    let mut found: Vec<(u64, u64)> =
        targets.iter().enumerate().filter(|(_, &t)| t == 0).map(|(q, _)| (q as u64, start)).collect();
    let mut counted = 0u64;
    let mut buffer = Vec::new();
    let mut round = 0u64;
    while counted < want {
        let from = start + (round * parts + p) * chunk;
        reader.seek(SeekFrom::Start(from)).map_err(io)?;
        // One byte past the chunk read: whether the file ends in it.
        buffer.clear();
        let got = (&mut *reader).take(chunk + 1).read_to_end(&mut buffer).map_err(io)?;
        let (bytes, at_end) = (&buffer[..got.min(chunk as usize)], got <= chunk as usize);
        let mut ends = bytes.iter().filter(|&&b| b == b'\n').count() as u64;
        let unended = at_end && bytes.last().is_some_and(|&b| b != b'\n');
        ends += unended as u64;
        let mine: Vec<u8> = [ends, at_end as u64].iter().flat_map(|w| w.to_le_bytes()).collect();
        let all = gathered_words(comm, &mine)?;
        let mut ended = false;
        let mut mine_before = counted;
        for (r, words) in all.iter().enumerate() {
            let [ends, at_end] = [words[0], words[1]];
            if (r as u64) < p {
                mine_before += ends;
            }
            counted += ends;
            ended |= at_end != 0;
        }
        // The targets whose line end is in this rank's chunk.
        let mut k = mine_before;
        let mut positions = bytes.iter().enumerate().filter(|(_, &b)| b == b'\n').map(|(i, _)| i as u64 + 1);
        // (Parts of no line share their start with the next.)
        let mut last = None;
        for (q, &t) in targets.iter().enumerate().filter(|(_, &t)| t > mine_before && t <= mine_before + ends) {
            let at = match last {
                Some((lt, at)) if lt == t => at,
                _ => loop {
                    match positions.next() {
                        Some(i) => {
                            k += 1;
                            if k == t {
                                break i;
                            }
                        }
                        // The file's end ending its last line.
                        None => break bytes.len() as u64,
                    }
                },
            };
            last = Some((t, at));
            found.push((q as u64, from + at));
        }
        if round == 0 {
            let len = bytes.len();
            buffer.truncate(len);
            *held = (from, std::mem::take(&mut buffer));
        }
        round += 1;
        if counted < want && ended {
            return Ok(Err(counted));
        }
    }
    // Every rank's finds, to every rank.
    let mine: Vec<u8> = found.iter().flat_map(|&(q, at)| [q, at]).flat_map(u64::to_le_bytes).collect();
    let mut starts = vec![u64::MAX; targets.len()];
    for words in gathered_words(comm, &mine)? {
        for pair in words.as_chunks::<2>().0 {
            let q = pair[0] as usize;
            starts[q] = starts[q].min(pair[1]);
        }
    }
    if starts.contains(&u64::MAX) {
        return Err(Error::Internal("a part's first line was found by no rank".into()));
    }
    Ok(Ok(starts))
}

/// `mine` (little-endian u64s) all-gathered: every rank's words, by rank.
fn gathered_words(comm: &dyn Reduce, mine: &[u8]) -> Result<Vec<Vec<u64>>> {
    let all = comm.all_gather(mine)?;
    Ok(all.iter().map(|bytes| bytes.as_chunks::<8>().0.iter().map(|&w| u64::from_le_bytes(w)).collect()).collect())
}

/// Where part `p` of `parts` of `n` rows starts: `n p / parts`.
fn share(n: usize, p: usize, parts: usize) -> usize {
    (n as u128 * p as u128 / parts.max(1) as u128) as usize
}

/// Where a field's value is kept while its line is read.
fn slot(field: Field) -> usize {
    match field {
        Field::Position(axis) => axis,
        Field::Id => 3,
        Field::Radius => 4,
    }
}

/// Sorts the rows by id (if any), row `i` having been read on line
/// `first + i`; two rows of one id are an error naming both lines.
fn sort_by_id<R: BufRead>(rows: &mut Rows, first: usize, lines: &Lines<R>) -> Result<()> {
    let Some(ids) = &rows.ids else { return Ok(()) };
    if ids.windows(2).all(|w| w[0] < w[1]) {
        return Ok(());
    }
    let mut order: Vec<usize> = (0..ids.len()).collect();
    order.sort_unstable_by_key(|&i| (ids[i], i));
    if let Some(w) = order.windows(2).find(|w| ids[w[0]] == ids[w[1]]) {
        let (a, b) = (first + w[0], first + w[1]);
        return Err(lines.error_at(b, format_args!("atom id {} again (it is on line {a} too)", ids[w[0]])));
    }
    rows.positions = order.iter().map(|&i| rows.positions[i]).collect();
    rows.ids = Some(order.iter().map(|&i| ids[i]).collect());
    if let Some(radii) = &rows.radii {
        rows.radii = Some(order.iter().map(|&i| radii[i]).collect());
    }
    Ok(())
}

/// What `Iterator::next` of a reader gives for `read`, the reading of
/// the next frame: `None` at the end of the file; at the end or after an
/// error, `done` is set (and nothing more is read).
pub(super) fn frame_or_end(done: &mut bool, read: Result<Option<ParticleFrame>>) -> Option<Result<ParticleFrame>> {
    let r = read.transpose();
    *done = !matches!(r, Some(Ok(_)));
    r
}

/// What [`FrameReader::skip_frame`] of a reader gives for `skip`, as
/// [`frame_or_end`] does.
pub(super) fn skipped(done: &mut bool, skip: Result<bool>) -> Result<bool> {
    *done = !matches!(skip, Ok(true));
    skip
}

/// A reader's `Iterator` and [`FrameReader`], from its own `read(&mut
/// self) -> Result<Option<ParticleFrame>>` (the next frame, `None` at the
/// end), `skip(&mut self) -> Result<bool>` (past the next frame) and its
/// fields `done` (after an error or the end) and `index` (the next
/// frame's).
macro_rules! frame_reader {
    ($reader:ident) => {
        impl<R: BufRead + Seek> $reader<R> {
            /// [`FrameReader::skip_frame`] (in parts over `comm`'s ranks):
            /// nothing after an error or the end.
            fn skip_checked(&mut self, comm: Option<&dyn Reduce>) -> Result<bool> {
                if self.done {
                    return Ok(false);
                }
                let skip = self.skip(comm);
                super::particles::skipped(&mut self.done, skip)
            }

            /// The next frame (in parts over `comm`'s ranks): nothing
            /// after an error or the end.
            fn read_checked(&mut self, comm: Option<&dyn Reduce>) -> Option<Result<ParticleFrame>> {
                if self.done {
                    return None;
                }
                let read = self.read(comm);
                super::particles::frame_or_end(&mut self.done, read)
            }
        }

        impl<R: BufRead + Seek> Iterator for $reader<R> {
            type Item = Result<ParticleFrame>;

            fn next(&mut self) -> Option<Self::Item> {
                self.read_checked(None)
            }

            /// Skips `n` frames without parsing their atoms, then reads one.
            fn nth(&mut self, n: usize) -> Option<Self::Item> {
                super::particles::nth_frame(self, n, |r| r.skip_checked(None))
            }
        }

        impl<R: BufRead + Seek + Send> FrameReader for $reader<R> {
            fn skip_frame(&mut self) -> Result<bool> {
                self.skip_checked(None)
            }

            fn next_index(&self) -> usize {
                self.index
            }

            fn next_in_parts(&mut self, comm: &dyn Reduce) -> Option<Result<ParticleFrame>> {
                self.read_checked(Some(comm))
            }

            fn skip_in_parts(&mut self, comm: &dyn Reduce) -> Result<bool> {
                self.skip_checked(Some(comm))
            }
        }
    };
}
pub(super) use frame_reader;

/// `Iterator::nth` of a reader: `n` frames skipped with `skip` (the
/// reader's `skip_frame`), then one read.
pub(super) fn nth_frame<I: Iterator<Item = Result<ParticleFrame>>>(
    reader: &mut I,
    n: usize,
    skip: fn(&mut I) -> Result<bool>,
) -> Option<Result<ParticleFrame>> {
    for _ in 0..n {
        match skip(reader) {
            Ok(true) => {}
            Ok(false) => return None,
            Err(e) => return Some(Err(e)),
        }
    }
    reader.next()
}

#[cfg(test)]
pub(super) mod tests {
    use super::super::tests::temp_path;
    use super::*;

    /// Every frame of `text` read by `open`'s reader, then again skipping
    /// every other frame: a fuzz-like check that nothing panics and that
    /// the readers always end.
    pub fn read_all_frames<'a, F: FrameReader>(text: &'a str, open: impl Fn(std::io::Cursor<&'a [u8]>) -> F) {
        let mut frames = 0;
        for frame in open(std::io::Cursor::new(text.as_bytes())) {
            frames += 1;
            assert!(frames <= text.len() + 1, "a reader that does not end");
            let _ = frame;
        }
        let mut reader = open(std::io::Cursor::new(text.as_bytes()));
        for k in 0..=text.len() + 1 {
            let more = if k % 2 == 0 { matches!(reader.skip_frame(), Ok(true)) } else { reader.next().is_some() };
            if !more {
                return;
            }
        }
        panic!("a reader that does not end");
    }

    /// The frames a reader named `name` read, `frames`, ended in an error
    /// at `line` of frame `frame`, the message holding `part`.
    #[track_caller]
    pub fn fails_at(frames: Result<Vec<ParticleFrame>>, name: &str, line: usize, frame: usize, part: &str) {
        let e = frames.unwrap_err();
        let m = e.to_string();
        assert!(matches!(e, Error::Parse { .. }), "{m}");
        assert!(m.starts_with(&format!("{name}:{line}: frame {frame}: ")), "{m}");
        assert!(m.contains(part), "{m}");
    }

    /// `text` with its line `line` (1-based) replaced by `new`.
    pub fn replace_line(text: &str, line: usize, new: &str) -> String {
        let mut lines: Vec<&str> = text.lines().collect();
        lines[line - 1] = new;
        lines.join("\n") + "\n"
    }

    #[test]
    fn lines_count_and_skip() {
        let text = "a\r\n\n  \nb\nc\nd\ne";
        let mut lines = Lines::new(text.as_bytes(), "l".into());
        assert!(lines.next().unwrap());
        assert_eq!((lines.no(), lines.text()), (1, "a"));
        assert!(lines.next_nonblank().unwrap());
        assert_eq!((lines.no(), lines.text()), (4, "b"));
        assert_eq!(lines.skip(2).unwrap(), 2);
        assert_eq!(lines.no(), 6);
        assert!(lines.next().unwrap());
        assert_eq!((lines.no(), lines.text()), (7, "e"));
        assert!(!lines.next().unwrap());
        assert_eq!(lines.no(), 7);
        // The last line without its end counts; skipping past the end
        // says how far it got.
        let mut lines = Lines::new(text.as_bytes(), "l".into());
        assert_eq!(lines.skip(100).unwrap(), 7);
        assert_eq!(lines.no(), 7);
        let mut lines = Lines::new("x\ny\n".as_bytes(), "l".into());
        assert_eq!(lines.skip(5).unwrap(), 2);
        assert!(!lines.next().unwrap());
        // Through a small buffer: lines end across its refills.
        let long = (0..1000).map(|i| format!("line {i}\n")).collect::<String>();
        let mut lines = Lines::new(std::io::BufReader::with_capacity(7, long.as_bytes()), "l".into());
        assert_eq!(lines.skip(500).unwrap(), 500);
        assert!(lines.next().unwrap());
        assert_eq!((lines.no(), lines.text()), (501, "line 500"));
    }

    #[test]
    fn lines_that_are_not_utf8_or_too_long() {
        let mut lines = Lines::new(&b"caf\xe9 1\nok\n"[..], "l".into());
        assert!(lines.next().unwrap());
        assert_eq!(lines.text(), "caf\u{fffd} 1");
        assert!(lines.next().unwrap());
        assert_eq!(lines.text(), "ok");
        let long = vec![b'1'; MAX_LINE as usize + 10];
        let mut lines = Lines::new(&long[..], "l".into());
        let e = lines.next().unwrap_err().to_string();
        assert!(e.starts_with("l:1: frame 0: a line longer than 4 MiB"), "{e}");
    }

    #[test]
    fn unknown_particle_files_are_errors_listing_the_formats() {
        let e = open_particles(Path::new("dir/run.xyz")).err().unwrap();
        let m = e.to_string();
        assert!(matches!(e, Error::InvalidInput(_)), "{m}");
        assert!(m.contains("dir/run.xyz: unknown particle format; supported extensions: .dump/.lammpstrj"), "{m}");
        assert!(m.contains(".extxyz"), "{m}");
        // A missing file of a known format: an I/O error naming it.
        let missing = temp_path("missing.lammpstrj");
        assert!(matches!(open_particles(&missing), Err(Error::Io { path, .. }) if path.contains("missing.lammpstrj")));
    }
}
