//! LAMMPS text dumps (`dump atom` and `dump custom`), read frame by frame.
//!
//! A frame is a block of `ITEM:` lines, each followed by its values:
//!
//! ```text
//! ITEM: TIMESTEP
//! 1000
//! ITEM: NUMBER OF ATOMS
//! 32000
//! ITEM: BOX BOUNDS xy xz yz pp pp ff
//! xlo_bound xhi_bound xy
//! ylo_bound yhi_bound xz
//! zlo_bound zhi_bound yz
//! ITEM: ATOMS id type x y z
//! 1 1 0.5 0.25 3.0
//! ...
//! ```
//!
//! The box: `ITEM: BOX BOUNDS` with three boundary flags (`pp`: periodic,
//! anything else of `f`, `s`, `m`: a wall; no flags, as in old dumps: all
//! periodic), then `lo hi` per axis; after `xy xz yz`, a restricted
//! triclinic cell, the lines giving the bounds of the tilted cell's
//! bounding box and the tilts (turned back into the cell's own bounds);
//! after `abc origin`, a general triclinic cell, the lines `ax ay az
//! originx`, `bx by bz originy`, `cx cy cz originz`. `ITEM: UNITS` and
//! `ITEM: TIME` (from `dump_modify units/time yes`) are passed over.
//!
//! The atoms: positions from the columns `x y z`, else `xu yu zu`
//! (unwrapped), else the scaled `xs ys zs` or `xsu ysu zsu` (fractional
//! coordinates of the cell, turned into Cartesian ones); `id` (the rows
//! are then sorted by it) and `radius` when present; other columns are
//! not looked at (types may be names).

use super::particles::{
    atoms_in_parts, box_message, count, finite, open_buffered, read_atoms, tokens, unsigned, Atoms, Columns, Field,
    FrameReader, Lines, ParticleFrame, PartsScan,
};
use cvd::backends::distributed::Reduce;
use cvd::error::{Error, Result};
use cvd::PeriodicBox;
use std::io::{BufRead, BufReader, Seek};
use std::path::Path;

/// A reader of a LAMMPS text dump's frames (see the module's notes for
/// what is read).
pub struct LammpsDumpReader<R> {
    lines: Lines<R>,
    index: usize,
    done: bool,
    /// What reading in parts keeps from frame to frame.
    scan: PartsScan,
}

impl LammpsDumpReader<BufReader<std::fs::File>> {
    /// Opens a dump file; its frames are read as the reader is iterated.
    pub fn open(path: &Path) -> Result<Self> {
        Ok(Self::new(open_buffered(path)?, path.display().to_string()))
    }
}

/// What a frame's `ITEM:` lines gave, up to `ITEM: ATOMS`.
struct Header {
    timestep: Option<u64>,
    /// The atom count and its line.
    count: (usize, usize),
    /// The cell and the atom lines' columns (not parsed when skipping).
    domain: Option<PeriodicBox>,
    columns: Option<Columns>,
}

/// The kinds of `ITEM: BOX BOUNDS`.
#[derive(Clone, Copy, PartialEq)]
enum BoxKind {
    Orthogonal,
    /// `xy xz yz`: LAMMPS's restricted triclinic cell.
    Tilted,
    /// `abc origin`: a general triclinic cell.
    General,
}

impl<R: BufRead + Seek> LammpsDumpReader<R> {
    /// A reader of the dump `reader` holds; `path` names it in errors.
    pub fn new(reader: R, path: impl Into<String>) -> Self {
        Self { lines: Lines::new(reader, path.into()), index: 0, done: false, scan: PartsScan::default() }
    }

    /// The next frame, or `None` at the end of the file: whole, or this
    /// rank's part of it over `comm`'s ranks.
    fn read(&mut self, comm: Option<&dyn Reduce>) -> Result<Option<ParticleFrame>> {
        let Some(header) = self.header(true)? else { return Ok(None) };
        let (Some(domain), Some(columns)) = (header.domain, header.columns) else {
            return Err(Error::Internal("a dump's header was read without its box or columns".into()));
        };
        let (count, count_line) = header.count;
        let atoms = Atoms { count, count_line, count_name: "ITEM: NUMBER OF ATOMS", stop: Some("ITEM:") };
        let (rows, part) = match comm {
            None => (read_atoms(&mut self.lines, &columns, &atoms, &domain)?, None),
            Some(comm) => {
                let parse = Some((&columns, &domain));
                let (rows, part) = atoms_in_parts(&mut self.lines, &atoms, comm, parse, &mut self.scan)?;
                (rows, Some(part))
            }
        };
        let frame = ParticleFrame {
            index: self.index,
            timestep: header.timestep,
            domain,
            positions: rows.positions,
            ids: rows.ids,
            radii: rows.radii,
            part,
        };
        self.index += 1;
        Ok(Some(frame))
    }

    /// Passes over the next frame: its header is read, its atom lines only
    /// counted (in parts over `comm`'s ranks, each counting a share).
    fn skip(&mut self, comm: Option<&dyn Reduce>) -> Result<bool> {
        let Some(header) = self.header(false)? else { return Ok(false) };
        let (count, count_line) = header.count;
        let atoms = Atoms { count, count_line, count_name: "ITEM: NUMBER OF ATOMS", stop: None };
        match comm {
            None => {
                let skipped = self.lines.skip(count)?;
                if skipped < count {
                    return Err(atoms.cut_short(&self.lines, skipped));
                }
            }
            Some(comm) => {
                atoms_in_parts(&mut self.lines, &atoms, comm, None, &mut self.scan)?;
            }
        }
        self.index += 1;
        Ok(true)
    }

    /// A frame's `ITEM:` lines and their values up to `ITEM: ATOMS`
    /// (`parse`: whether to read the timestep, box and columns, or only
    /// the atom count); `None` at the end of the file.
    fn header(&mut self, parse: bool) -> Result<Option<Header>> {
        let lines = &mut self.lines;
        lines.frame = self.index;
        if !lines.next_nonblank()? {
            return Ok(None);
        }
        let mut timestep = None;
        let mut count = None;
        let mut domain = None;
        // Where each item was seen in this frame, by its place in ITEMS.
        const ITEMS: [&str; 5] = ["TIMESTEP", "NUMBER OF ATOMS", "BOX BOUNDS", "UNITS", "TIME"];
        let mut seen = [None; ITEMS.len()];
        loop {
            let no = lines.no();
            let text = lines.text().trim();
            let Some(item) = text.strip_prefix("ITEM:") else {
                let what =
                    if seen.iter().all(Option::is_none) { "ITEM: TIMESTEP (a frame's start)" } else { "an ITEM: line" };
                return Err(match text.split_ascii_whitespace().next() {
                    Some(first) => lines.unexpected(first, what),
                    None => lines.error(format_args!("expected {what}, found a blank line")),
                });
            };
            let item = item.to_string();
            let words: Vec<&str> = item.split_ascii_whitespace().collect();
            let name = match words.as_slice() {
                ["NUMBER", "OF", "ATOMS"] => "NUMBER OF ATOMS",
                ["BOX", "BOUNDS", ..] => "BOX BOUNDS",
                ["ATOMS", ..] => "ATOMS",
                [one] => *one,
                _ => "",
            };
            if let Some(k) = ITEMS.iter().position(|i| *i == name) {
                if let Some(first) = seen[k] {
                    return Err(lines.error(format_args!(
                        "expected ITEM: ATOMS before a second ITEM: {name} (the first is on line {first}; a frame \
                         cut short?)"
                    )));
                }
                seen[k] = Some(no);
            }
            match name {
                "TIMESTEP" => {
                    lines.expect("the timestep after ITEM: TIMESTEP")?;
                    if parse {
                        let t = tokens(lines, 1, "the timestep")?;
                        timestep = Some(unsigned(lines, t[0], "the timestep")?);
                    }
                }
                "NUMBER OF ATOMS" => {
                    lines.expect("the atom count after ITEM: NUMBER OF ATOMS")?;
                    let t = tokens(lines, 1, "the atom count")?;
                    count = Some((count_of(lines, t[0])?, no));
                }
                "BOX BOUNDS" => domain = parse_box(lines, &words[2..], parse)?,
                "UNITS" | "TIME" => lines.expect(format_args!("the value after ITEM: {name}"))?,
                "ATOMS" => {
                    let Some(count) = count else {
                        return Err(lines.error("expected ITEM: NUMBER OF ATOMS before ITEM: ATOMS"));
                    };
                    if seen[2].is_none() {
                        return Err(lines.error("expected ITEM: BOX BOUNDS before ITEM: ATOMS"));
                    }
                    let columns = if parse { Some(columns(lines, &words[1..])?) } else { None };
                    return Ok(Some(Header { timestep, count, domain, columns }));
                }
                _ => {
                    return Err(lines.unexpected(
                        &format!("ITEM:{item}"),
                        "ITEM: TIMESTEP, NUMBER OF ATOMS, BOX BOUNDS, ATOMS, UNITS or TIME",
                    ))
                }
            }
            lines.expect("ITEM: ATOMS (the frame's atoms)")?;
        }
    }
}

/// The atom count.
fn count_of<R: BufRead>(lines: &Lines<R>, token: &str) -> Result<usize> {
    count(lines, token, "the atom count")
}

/// Reads the three lines of `ITEM: BOX BOUNDS` (the current line), whose
/// words after `BOX BOUNDS` are `rest`: the cell with its periodic axes,
/// or `None` if `parse` is false (the lines are then passed over).
fn parse_box<R: BufRead>(lines: &mut Lines<R>, rest: &[&str], parse: bool) -> Result<Option<PeriodicBox>> {
    let item = lines.no();
    let (kind, flags) = match rest {
        ["xy", "xz", "yz", flags @ ..] => (BoxKind::Tilted, flags),
        ["abc", "origin", flags @ ..] => (BoxKind::General, flags),
        flags => (BoxKind::Orthogonal, flags),
    };
    let flag = |f: &str| f.len() == 2 && f.bytes().all(|b| b"pfsm".contains(&b));
    let periodic = match *flags {
        [] => [true; 3],
        [a, b, c] if [a, b, c].into_iter().all(flag) => [a, b, c].map(|f| f == "pp"),
        _ => {
            return Err(lines.unexpected(
                &format!("ITEM: BOX BOUNDS {}", rest.join(" ")),
                "ITEM: BOX BOUNDS and 3 boundary flags such as pp pp ff (after xy xz yz for a triclinic box, abc \
                 origin for a general triclinic one)",
            ))
        }
    };
    let (names, n): ([&str; 3], usize) = match kind {
        BoxKind::Orthogonal => (["xlo xhi", "ylo yhi", "zlo zhi"], 2),
        BoxKind::Tilted => (["xlo_bound xhi_bound xy", "ylo_bound yhi_bound xz", "zlo_bound zhi_bound yz"], 3),
        BoxKind::General => (["ax ay az originx", "bx by bz originy", "cx cy cz originz"], 4),
    };
    let mut v = [[0.0; 4]; 3];
    for (row, name) in names.iter().enumerate() {
        lines.expect(format_args!("{name} (line {} of ITEM: BOX BOUNDS on line {item})", row + 1))?;
        if parse {
            let toks = tokens(lines, n, name)?;
            for ((x, tok), what) in v[row].iter_mut().zip(toks).zip(name.split(' ')) {
                *x = finite(lines, tok, what)?;
            }
        }
    }
    if !parse {
        return Ok(None);
    }
    let cell = match kind {
        BoxKind::Orthogonal => PeriodicBox::new([v[0][0], v[1][0], v[2][0]], [v[0][1], v[1][1], v[2][1]]),
        BoxKind::Tilted => {
            let [xy, xz, yz] = [v[0][2], v[1][2], v[2][2]];
            // The bounding box's bounds, less the tilts' reach.
            let lo = [v[0][0] - 0f64.min(xy).min(xz).min(xy + xz), v[1][0] - 0f64.min(yz), v[2][0]];
            let hi = [v[0][1] - 0f64.max(xy).max(xz).max(xy + xz), v[1][1] - 0f64.max(yz), v[2][1]];
            PeriodicBox::lammps(lo, hi, [xy, xz, yz])
        }
        BoxKind::General => {
            let vector = |r: usize| [v[r][0], v[r][1], v[r][2]];
            PeriodicBox::triclinic([v[0][3], v[1][3], v[2][3]], [vector(0), vector(1), vector(2)])
        }
    };
    match cell {
        Ok(cell) => Ok(Some(cell.with_periodic(periodic))),
        Err(e) => Err(lines.error_at(item, format_args!("ITEM: BOX BOUNDS gives no cell: {}", box_message(e)))),
    }
}

/// The columns named after `ITEM: ATOMS`.
fn columns<R: BufRead>(lines: &Lines<R>, names: &[&str]) -> Result<Columns> {
    let find = |name: &str| names.iter().position(|c| *c == name);
    let sets = [
        (["x", "y", "z"], false),
        (["xu", "yu", "zu"], false),
        (["xs", "ys", "zs"], true),
        (["xsu", "ysu", "zsu"], true),
    ];
    let Some((at, scaled)) = sets.iter().find_map(|(set, scaled)| match set.map(find) {
        [Some(x), Some(y), Some(z)] => Some(([x, y, z], *scaled)),
        _ => None,
    }) else {
        let found =
            if names.is_empty() { "no column names".to_string() } else { format!("ITEM: ATOMS {}", names.join(" ")) };
        return Err(lines.error(format_args!(
            "expected position columns x y z, xu yu zu, xs ys zs or xsu ysu zsu after ITEM: ATOMS, found {found}"
        )));
    };
    let mut fields: Vec<(usize, Field)> = (0..3).map(|k| (at[k], Field::Position(k))).collect();
    fields.extend(find("id").map(|i| (i, Field::Id)));
    fields.extend(find("radius").map(|i| (i, Field::Radius)));
    Ok(Columns::new(names.len(), fields, scaled, names.join(" ")))
}

super::particles::frame_reader!(LammpsDumpReader);

#[cfg(test)]
pub(crate) mod tests {
    use super::super::particles::tests::{fails_at, read_all_frames, replace_line};
    use super::super::particles::FramePart;
    use super::super::tests::{no_panic_on_mutations, parse_err};
    use super::*;
    use cvd::backends::distributed::InProcess;
    use std::fmt::Write;

    /// Two frames: an orthogonal box with walls along z, ids out of order
    /// and radii; a triclinic box with scaled coordinates and named types.
    /// Frame 0 is lines 1 to 12, frame 1 lines 13 to 23.
    pub const VALID: &str = "\
ITEM: TIMESTEP
0
ITEM: NUMBER OF ATOMS
3
ITEM: BOX BOUNDS pp pp ff
0 10
0 10
-5 5
ITEM: ATOMS id type x y z radius
3 1 1.5 2.5 3.5 0.5
1 2 0.5 0.25 -1 0.25
2 1 9 9 4 1
ITEM: TIMESTEP
100
ITEM: NUMBER OF ATOMS
2
ITEM: BOX BOUNDS xy xz yz pp pp pp
-1 10.5 0.5
0 10 -1
0 10 0
ITEM: ATOMS id type xs ys zs
2 Ar 0.5 0.5 0.5
1 Ar 0.25 0 0.75
";

    fn read_all(text: &str) -> Result<Vec<ParticleFrame>> {
        LammpsDumpReader::new(std::io::Cursor::new(text.as_bytes()), "t.dump").collect()
    }

    /// Reading `text` fails at `line` of frame `frame`, the message holding
    /// `part`.
    #[track_caller]
    fn fails(text: &str, line: usize, frame: usize, part: &str) {
        fails_at(read_all(text), "t.dump", line, frame, part);
    }

    /// `VALID` with its line `line` (1-based) replaced.
    fn with_line(line: usize, text: &str) -> String {
        replace_line(VALID, line, text)
    }

    /// A frame: the box's lines, the columns and the atom lines.
    fn frame(step: u64, bounds: &str, columns: &str, rows: &[String]) -> String {
        let mut out = format!("ITEM: TIMESTEP\n{step}\nITEM: NUMBER OF ATOMS\n{}\n{bounds}", rows.len());
        writeln!(out, "ITEM: ATOMS {columns}").unwrap();
        rows.iter().for_each(|r| writeln!(out, "{r}").unwrap());
        out
    }

    #[test]
    fn two_frames() {
        let frames = read_all(VALID).unwrap();
        assert_eq!(frames.len(), 2);
        let f = &frames[0];
        assert_eq!((f.index, f.timestep), (0, Some(0)));
        let cell = PeriodicBox::new([0.0, 0.0, -5.0], [10.0, 10.0, 5.0]).unwrap().with_periodic([true, true, false]);
        assert_eq!(f.domain, cell);
        assert_eq!(f.positions, [[0.5, 0.25, -1.0], [9.0, 9.0, 4.0], [1.5, 2.5, 3.5]]);
        assert_eq!(f.ids.as_deref(), Some(&[1, 2, 3][..]));
        assert_eq!(f.radii.as_deref(), Some(&[0.25, 1.0, 0.5][..]));
        let f = &frames[1];
        assert_eq!((f.index, f.timestep, f.radii.as_ref()), (1, Some(100), None));
        assert_eq!(f.domain, PeriodicBox::lammps([0.0; 3], [10.0; 3], [0.5, -1.0, 0.0]).unwrap());
        assert_eq!(f.positions, [[1.75, 0.0, 7.5], [4.75, 5.0, 5.0]]);
        assert_eq!(f.ids.as_deref(), Some(&[1, 2][..]));
    }

    #[test]
    fn every_coordinate_style_gives_the_same_positions() {
        let points = [[0.5, 0.25, 3.0], [9.75, -0.5, 1.0 / 3.0], [4.0, 7.5, 9.99], [12.5, 3.0, -2.0]];
        let cells = [
            ("ITEM: BOX BOUNDS pp pp pp\n0 10\n-1 9\n0 10\n", PeriodicBox::new([0.0, -1.0, 0.0], [10.0, 9.0, 10.0])),
            (
                // xy 1.5, xz -2, yz 0.5 from 0..10 along each axis.
                "ITEM: BOX BOUNDS xy xz yz pp pp pp\n-2 11.5 1.5\n0 10.5 -2\n0 10 0.5\n",
                PeriodicBox::lammps([0.0; 3], [10.0; 3], [1.5, -2.0, 0.5]),
            ),
        ];
        for (bounds, cell) in cells {
            let cell = cell.unwrap();
            let mut text = String::new();
            let styles = ["x y z", "xu yu zu", "xs ys zs", "xsu ysu zsu", "xs ys zs x y z", "xsu ysu zsu xu yu zu"];
            for (step, columns) in styles.iter().enumerate() {
                let rows: Vec<String> = points
                    .iter()
                    .enumerate()
                    .map(|(i, &p)| {
                        let s = cell.fractional(p);
                        let values: Vec<String> = columns
                            .split(' ')
                            .map(|c| match c {
                                "x" | "xu" => p[0].to_string(),
                                "y" | "yu" => p[1].to_string(),
                                "z" | "zu" => p[2].to_string(),
                                "xs" | "xsu" => s[0].to_string(),
                                "ys" | "ysu" => s[1].to_string(),
                                _ => s[2].to_string(),
                            })
                            .collect();
                        format!("{} 1 {}", i + 1, values.join(" "))
                    })
                    .collect();
                text += &frame(step as u64, bounds, &format!("id type {columns}"), &rows);
            }
            let frames = read_all(&text).unwrap();
            assert_eq!(frames.len(), styles.len());
            for (f, style) in frames.iter().zip(styles) {
                assert_eq!(f.domain, cell, "{style}");
                for (p, q) in f.positions.iter().zip(&points) {
                    assert!((0..3).all(|k| (p[k] - q[k]).abs() < 1e-12), "{style}: {p:?}, expected {q:?}");
                }
                if !style.starts_with("xs") || style.contains(" x") {
                    // Cartesian columns are taken as written.
                    assert_eq!(f.positions, points, "{style}");
                }
            }
        }
    }

    #[test]
    fn triclinic_bounds_are_the_tilted_cells_bounding_box() {
        let (lo, hi) = ([1.0, -2.0, 0.5], [3.0, 1.0, 2.0]);
        let tilts = [[0.5, 0.25, 0.75], [-0.5, -0.25, -0.75], [0.5, -0.75, 0.25], [-0.25, 0.5, -0.5], [0.0, 0.0, 0.0]];
        for tilt in tilts {
            let [xy, xz, yz] = tilt;
            // As LAMMPS writes them.
            let xlo = lo[0] + 0f64.min(xy).min(xz).min(xy + xz);
            let xhi = hi[0] + 0f64.max(xy).max(xz).max(xy + xz);
            let (ylo, yhi) = (lo[1] + 0f64.min(yz), hi[1] + 0f64.max(yz));
            let bounds = format!(
                "ITEM: BOX BOUNDS xy xz yz pp fs pp\n{xlo} {xhi} {xy}\n{ylo} {yhi} {xz}\n{} {} {yz}\n",
                lo[2], hi[2]
            );
            let text = frame(0, &bounds, "id type x y z", &["1 1 2 0 1".into()]);
            let read = read_all(&text).unwrap().remove(0).domain;
            let cell = PeriodicBox::lammps(lo, hi, tilt).unwrap().with_periodic([true, false, true]);
            assert_eq!(read, cell, "tilts {tilt:?}");
            let [lx, ly, lz] = [0, 1, 2].map(|k| hi[k] - lo[k]);
            assert_eq!(read.vectors(), [[lx, 0.0, 0.0], [xy, ly, 0.0], [xz, yz, lz]]);
            assert_eq!(read.lo(), lo);
        }
    }

    #[test]
    fn boundary_flags() {
        let cases = [
            ("pp pp ff", [true, true, false]),
            ("fs pp mm", [false, true, false]),
            ("pp ff pp", [true, false, true]),
            ("sm ss pp", [false, false, true]),
            ("", [true; 3]),
        ];
        for (flags, periodic) in cases {
            let text = frame(0, &format!("ITEM: BOX BOUNDS {flags}\n0 1\n0 1\n0 1\n"), "x y z", &[]);
            assert_eq!(read_all(&text).unwrap()[0].domain.periodic(), periodic, "{flags}");
            let tilted = frame(0, &format!("ITEM: BOX BOUNDS xy xz yz {flags}\n0 1 0\n0 1 0\n0 1 0\n"), "x y z", &[]);
            assert_eq!(read_all(&tilted).unwrap()[0].domain.periodic(), periodic, "{flags}");
        }
        for flags in ["pp pp", "pp pp pp pp", "pq pp pp", "p pp pp", "PP pp pp", "xy pp pp pp"] {
            let text = frame(0, &format!("ITEM: BOX BOUNDS {flags}\n0 1\n0 1\n0 1\n"), "x y z", &[]);
            fails(&text, 5, 0, "expected ITEM: BOX BOUNDS and 3 boundary flags such as pp pp ff");
        }
    }

    #[test]
    fn general_triclinic_cells() {
        let bounds = "ITEM: BOX BOUNDS abc origin pp pp fs\n4 0 0 1\n1 3 0 2\n0.5 0.5 5 -1\n";
        let text = frame(7, bounds, "id type x y z", &["1 1 2 2 2".into()]);
        let f = read_all(&text).unwrap().remove(0);
        let cell = PeriodicBox::triclinic([1.0, 2.0, -1.0], [[4.0, 0.0, 0.0], [1.0, 3.0, 0.0], [0.5, 0.5, 5.0]]);
        assert_eq!(f.domain, cell.unwrap().with_periodic([true, true, false]));
        assert_eq!(f.positions, [[2.0; 3]]);
        // Rotated: a along y, b along -x; scaled coordinates along a, b, c.
        let bounds = "ITEM: BOX BOUNDS abc origin pp pp pp\n0 4 0 0\n-3 0 0 0\n0 0 5 0\n";
        let text = frame(7, bounds, "id type xs ys zs", &["1 1 0.5 0.5 0.5".into()]);
        let f = read_all(&text).unwrap().remove(0);
        assert_eq!(f.positions, [[-1.5, 2.0, 2.5]]);
        // A left-handed cell.
        let bounds = "ITEM: BOX BOUNDS abc origin pp pp pp\n-3 0 0 0\n0 4 0 0\n0 0 5 0\n";
        fails(&frame(0, bounds, "x y z", &[]), 5, 0, "ITEM: BOX BOUNDS gives no cell: the lattice vectors");
    }

    #[test]
    fn ids_sort_the_rows_and_must_differ() {
        let rows: Vec<String> = [5, 2, 9, 1].iter().map(|i| format!("{i} C {i}.5 0 0 {i}")).collect();
        let text = frame(3, "ITEM: BOX BOUNDS pp pp pp\n0 10\n0 10\n0 10\n", "id type x y z radius", &rows);
        let f = read_all(&text).unwrap().remove(0);
        assert_eq!(f.ids, Some(vec![1, 2, 5, 9]));
        assert_eq!(f.positions.iter().map(|p| p[0]).collect::<Vec<_>>(), [1.5, 2.5, 5.5, 9.5]);
        assert_eq!(f.radii, Some(vec![1.0, 2.0, 5.0, 9.0]));
        // Without ids: the file's order, no ids.
        let text = frame(3, "ITEM: BOX BOUNDS pp pp pp\n0 10\n0 10\n0 10\n", "mol type x y z r", &rows);
        let f = read_all(&text).unwrap().remove(0);
        assert_eq!((f.ids, f.radii, f.positions[0]), (None, None, [5.5, 0.0, 0.0]));
        // Two rows of id 3, on lines 10 and 12.
        fails(&with_line(12, "3 1 9 9 4 1"), 12, 0, "atom id 3 again (it is on line 10 too)");
        fails(&with_line(23, "2 Ar 0.25 0 0.75"), 23, 1, "atom id 2 again (it is on line 22 too)");
    }

    /// `text`'s frames read in parts over `parts` ranks (threads), the
    /// frames `skip` passed over in parts, each rank counting line ends
    /// in chunks of `chunk` bytes (`None`: as sized for a run): each
    /// rank's frames, or its error.
    fn read_in_parts(text: &str, parts: usize, chunk: Option<u64>, skip: &[usize]) -> Vec<Result<Vec<ParticleFrame>>> {
        InProcess::each(parts, |comm| {
            let mut reader = LammpsDumpReader::new(std::io::Cursor::new(text.as_bytes()), "t.dump");
            reader.scan.chunk = chunk;
            let mut frames = Vec::new();
            loop {
                if skip.contains(&reader.next_index()) {
                    match reader.skip_in_parts(comm)? {
                        true => continue,
                        false => return Ok(frames),
                    }
                }
                match reader.next_in_parts(comm) {
                    Some(frame) => frames.push(frame?),
                    None => return Ok(frames),
                }
            }
        })
    }

    /// The frames read in parts, the parts' rows put together and sorted
    /// by id (their ids, positions, radii), with each part's checks: its
    /// rows are the atom lines `n p / P..n (p + 1) / P`, its first line
    /// `first_lines[frame] + n p / P`.
    type Row = (u64, [f64; 3], Option<f64>);
    fn joined(by_part: &[Vec<ParticleFrame>], first_lines: &[usize]) -> Vec<Vec<Row>> {
        let parts = by_part.len();
        let mut joined: Vec<Vec<Row>> = vec![Vec::new(); by_part[0].len()];
        for (p, frames) in by_part.iter().enumerate() {
            for (k, f) in frames.iter().enumerate() {
                let n = f.part.unwrap().total;
                let (lo, hi) = (n * p / parts, n * (p + 1) / parts);
                let first_line = first_lines[f.index] + lo;
                assert_eq!(f.part, Some(FramePart { total: n, first: lo, first_line }), "part {p} of {parts}");
                assert_eq!(f.len(), hi - lo);
                for i in 0..f.len() {
                    let id = f.ids.as_ref().map_or(i as u64, |ids| ids[i]);
                    joined[k].push((id, f.positions[i], f.radii.as_ref().map(|r| r[i])));
                }
            }
        }
        joined.iter_mut().for_each(|rows| rows.sort_by_key(|r| r.0));
        joined
    }

    /// The frames `whole` as rows sorted by id.
    fn rows_of(whole: &[ParticleFrame]) -> Vec<Vec<Row>> {
        let row =
            |f: &ParticleFrame, i: usize| (f.ids.as_ref().unwrap()[i], f.positions[i], f.radii.as_ref().map(|r| r[i]));
        whole.iter().map(|f| (0..f.len()).map(|i| row(f, i)).collect()).collect()
    }

    #[test]
    fn frames_read_in_parts_are_the_frames_rows_in_the_files_order() {
        // Frame 0: 3 atoms on lines 10-12; frame 1: 2 atoms on lines 22-23.
        let whole: Vec<ParticleFrame> = read_all(VALID).unwrap();
        // A line end every few bytes: chunks of 1 and 7 bytes take many
        // rounds; a frame of 2 atoms has parts of no line.
        for parts in 1..=4 {
            for chunk in [Some(1), Some(7), Some(64), None] {
                let by_part: Vec<Vec<ParticleFrame>> =
                    read_in_parts(VALID, parts, chunk, &[]).into_iter().collect::<Result<_>>().unwrap();
                for frames in &by_part {
                    assert_eq!(frames.len(), 2);
                    for f in frames {
                        assert_eq!((f.domain, f.timestep), (whole[f.index].domain, whole[f.index].timestep));
                    }
                }
                // Laid end to end, the file's order; sorted, the frames.
                let ids: Vec<u64> = by_part.iter().flat_map(|f| f[0].ids.clone().unwrap()).collect();
                assert_eq!(ids, [3, 1, 2], "{parts} parts");
                assert_eq!(joined(&by_part, &[10, 22]), rows_of(&whole), "{parts} parts, chunks of {chunk:?}");
                // Frame 0 passed over in parts: frame 1 as read.
                let second = read_in_parts(VALID, parts, chunk, &[0]);
                for (p, frames) in second.into_iter().enumerate() {
                    assert_eq!(frames.unwrap(), [by_part[p][1].clone()]);
                }
            }
        }
        // CR LF line ends, blank lines between frames, no line end at the end.
        let spaced = VALID.replace("ITEM: TIMESTEP\n100", "\n  \nITEM: TIMESTEP\n100").replace('\n', "\r\n");
        let spaced = spaced.trim_end();
        for parts in 1..=3 {
            for chunk in [Some(3), None] {
                let by_part: Vec<Vec<ParticleFrame>> =
                    read_in_parts(spaced, parts, chunk, &[]).into_iter().collect::<Result<_>>().unwrap();
                assert_eq!(joined(&by_part, &[10, 24]), rows_of(&whole));
            }
        }
        // A bad atom line is the error of the part that reads it, at its
        // line; the other parts read on (the last frame: after it no rank
        // waits for the one that failed).
        let bad = with_line(23, "1 Ar 0.25 oops 0.75");
        for chunk in [Some(5), None] {
            let mut read = read_in_parts(&bad, 3, chunk, &[]);
            assert!(read[0].is_ok() && read[1].is_ok());
            fails_at(read.remove(2), "t.dump", 23, 1, "expected ys of atom 2");
        }
        // A frame cut short is every part's error, one process's.
        let cut = VALID.lines().take(22).collect::<Vec<_>>().join("\n");
        let one = read_all(&cut).unwrap_err().to_string();
        assert!(one.starts_with("t.dump:22: frame 1: expected 2 atom lines"), "{one}");
        for parts in 1..=3 {
            for chunk in [Some(2), None] {
                for (p, read) in read_in_parts(&cut, parts, chunk, &[]).into_iter().enumerate() {
                    assert_eq!(read.unwrap_err().to_string(), one, "part {p} of {parts}");
                }
                for read in read_in_parts(&cut, parts, chunk, &[1]) {
                    assert_eq!(read.unwrap_err().to_string(), one, "passing over it");
                }
            }
        }
    }

    /// A dump of `frames` frames of `n` atoms, lines of varied lengths,
    /// ids shuffled.
    pub fn big_dump(n: usize, frames: usize) -> String {
        let mut text = String::new();
        for k in 0..frames {
            let _ = write!(text, "ITEM: TIMESTEP\n{k}\nITEM: NUMBER OF ATOMS\n{n}\n");
            text += "ITEM: BOX BOUNDS pp pp pp\n0 100\n0 100\n0 100\nITEM: ATOMS id type x y z\n";
            for i in 0..n {
                let id = (i * 7919 + k) % n + 1;
                let x = (i as f64 * 0.618034).fract() * 100.0;
                let _ = writeln!(text, "{id} {} {x} {} {:.3}", 1 + i % 3, (i % 997) as f64 * 0.1, (i % 89) as f64);
            }
        }
        text
    }

    /// A reader that counts the bytes read through it.
    struct Counted<R> {
        inner: R,
        read: std::sync::Arc<std::sync::atomic::AtomicU64>,
    }

    impl<R: std::io::Read> std::io::Read for Counted<R> {
        fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
            let n = self.inner.read(buf)?;
            self.read.fetch_add(n as u64, std::sync::atomic::Ordering::Relaxed);
            Ok(n)
        }
    }

    impl<R: std::io::Seek> std::io::Seek for Counted<R> {
        fn seek(&mut self, pos: std::io::SeekFrom) -> std::io::Result<u64> {
            self.inner.seek(pos)
        }
    }

    #[test]
    fn no_part_reads_the_whole_file() {
        // 3 frames of 60 000 atoms: about 2 MB each.
        let text = big_dump(60_000, 3);
        let whole = read_all(&text).unwrap();
        let size = text.len() as f64;
        for parts in [2, 3, 4] {
            let read: Vec<(Vec<ParticleFrame>, u64)> = InProcess::each(parts, |comm| {
                let read = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
                let counted = Counted { inner: std::io::Cursor::new(text.as_bytes()), read: read.clone() };
                let reader = LammpsDumpReader::new(std::io::BufReader::with_capacity(1 << 16, counted), "t.dump");
                let mut reader = reader;
                let frames: Vec<ParticleFrame> =
                    std::iter::from_fn(|| reader.next_in_parts(comm)).collect::<Result<_>>().unwrap();
                (frames, read.load(std::sync::atomic::Ordering::Relaxed))
            });
            let by_part: Vec<Vec<ParticleFrame>> = read.iter().map(|r| r.0.clone()).collect();
            assert_eq!(joined(&by_part, &[10, 60_019, 120_028]), rows_of(&whole));
            // About a part's share of the bytes each (measured: 0.54-0.56
            // at 2 parts, 0.28-0.31 at 4): its share counted a little over,
            // a buffer's refill at each frame's header and its part's start.
            for (p, (_, bytes)) in read.iter().enumerate() {
                let share = *bytes as f64 / size;
                assert!(share < 1.1 / parts as f64 + 0.05, "part {p} of {parts} read {share:.3} of the file");
            }
        }
    }

    #[test]
    fn zero_atoms_and_other_items() {
        let text = frame(5, "ITEM: BOX BOUNDS pp pp pp\n0 1\n0 1\n0 1\n", "id type x y z", &[]);
        let text = format!("ITEM: UNITS\nlj\nITEM: TIME\n0.25\n{text}ITEM: TIME\n0.5\n{VALID}");
        let frames = read_all(&text).unwrap();
        assert_eq!(frames.len(), 3);
        assert!(frames[0].is_empty() && frames[0].ids == Some(vec![]));
        assert_eq!((frames[0].timestep, frames[1].timestep, frames[2].index), (Some(5), Some(0), 2));
        // Blank lines between frames and at the end; CR LF line ends.
        let spaced = VALID.replace("ITEM: TIMESTEP\n100", "\n  \nITEM: TIMESTEP\n100").replace('\n', "\r\n") + "\n\n";
        assert_eq!(read_all(&spaced).unwrap(), read_all(VALID).unwrap());
        assert!(read_all("").unwrap().is_empty());
        assert!(read_all("\n \n").unwrap().is_empty());
    }

    #[test]
    fn skipped_frames_are_counted_for_later_errors() {
        // Five frames of 3 atoms (12 lines each), the fifth with a bad line.
        let mut text = String::new();
        for k in 0..5 {
            let rows: Vec<String> = (1..=3).map(|i| format!("{i} 1 {k} {i} 0.5")).collect();
            text += &frame(10 * k, "ITEM: BOX BOUNDS pp pp pp\n0 10\n0 10\n0 10\n", "id type x y z", &rows);
        }
        let bad = text.replacen("3 1 4 3 0.5", "3 1 4 3", 1);
        let mut r = LammpsDumpReader::new(std::io::Cursor::new(bad.as_bytes()), "t.dump");
        assert!(r.skip_frame().unwrap() && r.skip_frame().unwrap());
        assert_eq!(r.next_index(), 2);
        let f = r.next().unwrap().unwrap();
        assert_eq!((f.index, f.timestep, f.positions[0]), (2, Some(20), [2.0, 1.0, 0.5]));
        assert!(r.skip_frame().unwrap());
        let e = r.next().unwrap().unwrap_err().to_string();
        assert_eq!(e, "t.dump:60: frame 4: expected 5 values (id type x y z) for atom 3, found 4");
        assert!(r.next().is_none() && !r.skip_frame().unwrap(), "the reader ends after an error");
        // nth skips; skipping does not parse the atoms.
        let mut r = LammpsDumpReader::new(std::io::Cursor::new(bad.as_bytes()), "t.dump");
        assert_eq!(r.nth(3).unwrap().unwrap().timestep, Some(30));
        assert!(r.skip_frame().unwrap(), "the bad line is not looked at");
        assert!(!r.skip_frame().unwrap() && r.next().is_none());
        let mut r = LammpsDumpReader::new(std::io::Cursor::new(text.as_bytes()), "t.dump");
        assert!(r.nth(5).is_none());
        // A frame cut short while skipping.
        let cut = &text[..text.len() - "3 1 4 3 0.5\n".len()];
        let mut r = LammpsDumpReader::new(std::io::Cursor::new(cut.as_bytes()), "t.dump");
        assert!((0..4).all(|_| r.skip_frame().unwrap()));
        let e = r.skip_frame().unwrap_err().to_string();
        assert_eq!(
            e,
            "t.dump:59: frame 4: expected 3 atom lines (ITEM: NUMBER OF ATOMS on line 51), found 2: the file ends \
             (cut short?)"
        );
        // A last line without its line end is a line.
        let mut r = LammpsDumpReader::new(std::io::Cursor::new(&text.as_bytes()[..text.len() - 1]), "t.dump");
        assert!((0..5).all(|_| r.skip_frame().unwrap()) && !r.skip_frame().unwrap());
    }

    #[test]
    fn errors_name_the_file_line_and_frame() {
        fails(&with_line(21, "ITEM: ATOMS id type xs ys"), 21, 1, "expected position columns x y z, xu yu zu");
        fails(&with_line(21, "ITEM: ATOMS"), 21, 1, "found no column names");
        fails(&with_line(11, "1 2 0.5 0.25 -1"), 11, 0, "expected 6 values (id type x y z radius) for atom 2, found 5");
        fails(&with_line(11, ""), 11, 0, "expected 6 values (id type x y z radius) for atom 2, found 0");
        fails(&with_line(11, "1 2 0.5 0.25 -1 1 1"), 11, 0, "for atom 2, found 7");
        fails(&with_line(12, "2 1 9 x 4 1"), 12, 0, "expected y of atom 3 (a finite number), found \"x\"");
        fails(&with_line(23, "1 Ar 0.25 nan 0.75"), 23, 1, "expected ys of atom 2 (a finite number), found \"nan\"");
        fails(&with_line(22, "2 Ar inf 0.5 0.5"), 22, 1, "expected xs of atom 1 (a finite number), found \"inf\"");
        fails(&with_line(22, "2 Ar 1e400 0.5 0.5"), 22, 1, "found \"1e400\"");
        fails(&with_line(10, "-3 1 1.5 2.5 3.5 0.5"), 10, 0, "expected the id of atom 1 (a non-negative integer)");
        fails(&with_line(10, "3 1 1.5 2.5 3.5 -0.5"), 10, 0, "expected the radius of atom 1 (a finite number >= 0)");
        // Too few atom lines: the next frame comes, or the file ends.
        fails(
            &with_line(4, "4"),
            13,
            0,
            "expected 4 atom lines (ITEM: NUMBER OF ATOMS on line 3), found 3 before this line",
        );
        let cut = &VALID[..VALID.len() - "1 Ar 0.25 0 0.75\n".len()];
        fails(
            cut,
            22,
            1,
            "expected 2 atom lines (ITEM: NUMBER OF ATOMS on line 15), found 1: the file ends (cut short?)",
        );
        // Too many: the next frame must start with an ITEM line.
        fails(&with_line(4, "2"), 12, 1, "expected ITEM: TIMESTEP (a frame's start), found \"2\"");
        // Bad ITEM lines and values.
        fails(&with_line(15, "ITEM: NUMBER OF ATOM"), 15, 1, "expected ITEM: TIMESTEP, NUMBER OF ATOMS, BOX BOUNDS");
        fails(&with_line(15, "NUMBER OF ATOMS"), 15, 1, "expected an ITEM: line, found \"NUMBER\"");
        fails(&with_line(15, ""), 15, 1, "expected an ITEM: line, found a blank line");
        fails(&with_line(14, "1e3"), 14, 1, "expected the timestep (a non-negative integer), found \"1e3\"");
        fails(&with_line(14, "1 2"), 14, 1, "expected 1 value (the timestep), found 2");
        fails(&with_line(16, "-2"), 16, 1, "expected the atom count (a non-negative integer), found \"-2\"");
        fails(&with_line(6, "0 10 5"), 6, 0, "expected 2 values (xlo xhi), found 3");
        fails(&with_line(19, "0 10"), 19, 1, "expected 3 values (ylo_bound yhi_bound xz), found 2");
        fails(&with_line(7, "0 nan"), 7, 0, "expected yhi (a finite number), found \"nan\"");
        fails(&with_line(7, "10 0"), 5, 0, "ITEM: BOX BOUNDS gives no cell: a periodic box needs");
        // Items out of order, twice, or missing.
        fails(&with_line(13, "ITEM: BOX BOUNDS pp pp pp"), 14, 1, "expected 2 values (xlo xhi), found 1");
        let twice = VALID.replacen("ITEM: ATOMS id type x y z radius", "ITEM: TIMESTEP", 1);
        fails(&twice, 9, 0, "expected ITEM: ATOMS before a second ITEM: TIMESTEP (the first is on line 1");
        let no_box = VALID.replacen("ITEM: BOX BOUNDS pp pp ff\n0 10\n0 10\n-5 5\n", "", 1);
        fails(&no_box, 5, 0, "expected ITEM: BOX BOUNDS before ITEM: ATOMS");
        let no_count = VALID.replacen("ITEM: NUMBER OF ATOMS\n2\n", "", 1);
        fails(&no_count, 19, 1, "expected ITEM: NUMBER OF ATOMS before ITEM: ATOMS");
        // The file ends in a header.
        let cut = VALID.split("0 10 -1").next().unwrap();
        fails(cut, 18, 1, "expected ylo_bound yhi_bound xz (line 2 of ITEM: BOX BOUNDS on line 17), found end of file");
        fails(
            &VALID[..VALID.find("ITEM: ATOMS").unwrap()],
            8,
            0,
            "expected ITEM: ATOMS (the frame's atoms), found end",
        );
        fails("ITEM: TIMESTEP\n", 1, 0, "expected the timestep after ITEM: TIMESTEP, found end of file");
        fails("hello\n", 1, 0, "expected ITEM: TIMESTEP (a frame's start), found \"hello\"");
    }

    #[test]
    fn truncated_files() {
        let lines: Vec<&str> = VALID.lines().collect();
        for k in 0..=lines.len() {
            let text: String = lines[..k].iter().map(|l| format!("{l}\n")).collect();
            let mut frames = 0;
            let mut error = None;
            for f in LammpsDumpReader::new(std::io::Cursor::new(text.as_bytes()), "t.dump") {
                match f {
                    Ok(_) => frames += 1,
                    Err(e) => error = Some(e.to_string()),
                }
            }
            assert_eq!(frames, (k >= 12) as usize + (k >= 23) as usize, "{k} lines");
            match error {
                None => assert!([0, 12, 23].contains(&k), "{k} lines read without an error"),
                Some(e) => {
                    let (line, frame) = (k.max(1), (k > 12) as usize);
                    assert!(e.starts_with(&format!("t.dump:{line}: frame {frame}: expected ")), "{k} lines: {e}");
                }
            }
        }
    }

    #[test]
    fn files_that_are_not_utf8_get_parse_errors() {
        let mut bytes = VALID.as_bytes().to_vec();
        let at = VALID.find("9 9 4").unwrap();
        bytes[at + 2] = 0xff;
        let r: Result<Vec<_>> = LammpsDumpReader::new(std::io::Cursor::new(&bytes[..]), "t.dump").collect();
        let (line, m) = parse_err(r);
        assert_eq!((line, m.as_str()), (12, "frame 0: expected y of atom 3 (a finite number), found \"\u{fffd}\""));
    }

    #[test]
    fn a_large_frame_through_a_file() {
        // 200 000 atoms, ids shuffled (a permutation by a stride prime to n).
        let n: u64 = 200_000;
        let mut text = format!("ITEM: TIMESTEP\n9\nITEM: NUMBER OF ATOMS\n{n}\n");
        text += "ITEM: BOX BOUNDS pp pp pp\n0 100\n0 100\n0 100\nITEM: ATOMS id type xs ys zs\n";
        for i in 0..n {
            let id = (i * 7919) % n + 1;
            writeln!(text, "{id} 1 {} {} {}", id as f64 / n as f64, 0.5, 0.25).unwrap();
        }
        let path = super::super::tests::temp_path("large.dump");
        std::fs::write(&path, format!("{text}{text}")).unwrap();
        let start = std::time::Instant::now();
        let mut r = LammpsDumpReader::open(&path).unwrap();
        assert!(r.skip_frame().unwrap());
        let skipped = start.elapsed();
        let f = r.next().unwrap().unwrap();
        eprintln!(
            "{n} atoms: skipped in {:.1} ms, read in {:.1} ms",
            skipped.as_secs_f64() * 1e3,
            (start.elapsed() - skipped).as_secs_f64() * 1e3
        );
        assert!(r.next().is_none());
        std::fs::remove_file(&path).unwrap();
        assert_eq!((f.index, f.len()), (1, n as usize));
        assert!(f.ids.unwrap().iter().zip(1..).all(|(&id, k)| id == k));
        assert!(f.positions.iter().zip(1..).all(|(p, k)| p[0] == 100.0 * (k as f64 / n as f64) && p[1] == 50.0));
    }

    #[test]
    fn no_input_panics() {
        no_panic_on_mutations(VALID, |t| {
            read_all_frames(t, |b| LammpsDumpReader::new(b, "f.dump"));
            read_all(t)
        });
    }

    #[test]
    fn opened_from_a_file() {
        let path = super::super::tests::temp_path("frames.lammpstrj");
        std::fs::write(&path, VALID).unwrap();
        let frames: Result<Vec<_>> = LammpsDumpReader::open(&path).unwrap().collect();
        std::fs::remove_file(&path).unwrap();
        assert_eq!(frames.unwrap(), read_all(VALID).unwrap());
    }
}
