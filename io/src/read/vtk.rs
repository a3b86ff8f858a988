//! Legacy VTK unstructured grids (`.vtk`): ASCII and binary, the cells as
//! `CELLS n size` lists (versions up to 4.2: the format the paper's own
//! code reads) or as `OFFSETS` and `CONNECTIVITY` arrays (version 5.1, what
//! VTK 9 and meshio write by default).
//!
//! Read here rather than through a crate: the Rust crate for VTK files
//! (`vtkio` 0.6) fails on version 5.1 and on meshio's `.vtu` files, and
//! aborts (a stack overflow, which no caller can catch) on some malformed
//! ones. Tetrahedra
//! (cell type 10) become the mesh; cells of lower dimension (boundary
//! triangles, edges, points) are skipped; any other volume cell is an error
//! naming how many there are, so no part of a domain is lost silently.
//! Data sections after the cells (`POINT_DATA`, `CELL_DATA`) are ignored.

use cvd::error::{Error, Result};
use cvd::geom::mesh::TetMesh;

/// VTK cell types of dimension below 3 (skipped).
pub(super) const LOWER_DIMENSIONAL: [i64; 12] = [1, 2, 3, 4, 5, 6, 7, 8, 9, 21, 22, 23];
/// The tetrahedron.
pub(super) const TETRA: i64 = 10;

/// The file as lines of text with binary blocks between them.
struct Cursor<'a> {
    bytes: &'a [u8],
    pos: usize,
    line: usize,
    name: &'a str,
    binary: bool,
}

impl<'a> Cursor<'a> {
    fn error(&self, message: impl Into<String>) -> Error {
        Error::Parse { path: self.name.to_string(), line: self.line, message: message.into() }
    }

    /// The next line that holds something, trimmed.
    fn line(&mut self) -> Option<&'a str> {
        while self.pos < self.bytes.len() {
            let rest = &self.bytes[self.pos..];
            let end = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
            self.pos += (end + 1).min(rest.len());
            self.line += 1;
            if rest[..end].iter().any(|b| !b.is_ascii_whitespace()) {
                // Keyword lines are ASCII; anything else reads as U+FFFD
                // and is reported where a keyword was expected.
                return Some(std::str::from_utf8(&rest[..end]).unwrap_or("\u{fffd}").trim());
            }
        }
        None
    }

    fn expect_line(&mut self, what: &str) -> Result<&'a str> {
        self.line().ok_or_else(|| self.error(format!("expected {what}, found the end of the file")))
    }

    /// `n` numbers of `kind` (a VTK data type name), as f64 (exact for the
    /// integers a mesh holds).
    fn numbers(&mut self, n: usize, kind: &str, what: &str) -> Result<Vec<f64>> {
        if self.binary {
            let size = match kind {
                "float" | "int" | "unsigned_int" | "vtktypeint32" | "vtktypeuint32" => 4,
                "double" | "long" | "unsigned_long" | "vtktypeint64" | "vtktypeuint64" => 8,
                _ => return Err(self.error(format!("unsupported data type '{kind}' for {what}"))),
            };
            let bytes = n.checked_mul(size).filter(|&b| b <= self.bytes.len() - self.pos).ok_or_else(|| {
                self.error(format!("expected {n} binary values for {what}, but the file ends before"))
            })?;
            let data = &self.bytes[self.pos..self.pos + bytes];
            self.pos += bytes;
            // Big-endian, as legacy VTK writes.
            Ok(data
                .chunks_exact(size)
                .map(|c| match kind {
                    "float" => f32::from_be_bytes([c[0], c[1], c[2], c[3]]) as f64,
                    "double" => f64::from_be_bytes(c.try_into().unwrap_or([0; 8])),
                    "int" | "vtktypeint32" => i32::from_be_bytes([c[0], c[1], c[2], c[3]]) as f64,
                    "unsigned_int" | "vtktypeuint32" => u32::from_be_bytes([c[0], c[1], c[2], c[3]]) as f64,
                    "vtktypeuint64" | "unsigned_long" => u64::from_be_bytes(c.try_into().unwrap_or([0; 8])) as f64,
                    _ => i64::from_be_bytes(c.try_into().unwrap_or([0; 8])) as f64,
                })
                .collect())
        } else {
            let mut out = Vec::with_capacity(n.min((self.bytes.len() - self.pos) / 2 + 1));
            while out.len() < n {
                let line = self.expect_line(&format!("{n} values for {what}"))?;
                for tok in line.split_ascii_whitespace() {
                    let x: f64 = tok.parse().map_err(|_| {
                        self.error(format!("expected a number for {what}, found \"{}\"", super::lex::shown(tok)))
                    })?;
                    if !x.is_finite() {
                        return Err(self.error(format!("expected a finite number for {what}, found \"{tok}\"")));
                    }
                    out.push(x);
                }
            }
            if out.len() > n {
                return Err(self.error(format!("expected {n} values for {what}, found {}", out.len())));
            }
            Ok(out)
        }
    }
}

/// An integer from a value read as f64, which must be a whole number in
/// `0..=max`.
fn whole(x: f64, max: u64) -> Option<u64> {
    (x >= 0.0 && x.fract() == 0.0 && x <= max as f64).then_some(x as u64)
}

/// A legacy `.vtk` file holding an unstructured grid.
pub fn parse_vtk(bytes: &[u8], name: &str) -> Result<TetMesh> {
    let mut c = Cursor { bytes, pos: 0, line: 0, name, binary: false };
    let head = c.expect_line("'# vtk DataFile Version x.y'")?;
    let Some(version) = head.strip_prefix("# vtk DataFile Version") else {
        return Err(c.error(format!("expected '# vtk DataFile Version x.y', found \"{}\"", super::lex::shown(head))));
    };
    let new_cells = version.trim().starts_with('5');
    c.expect_line("a title line")?;
    let encoding = c.expect_line("ASCII or BINARY")?;
    c.binary = match encoding.to_ascii_uppercase().as_str() {
        "ASCII" => false,
        "BINARY" => true,
        _ => return Err(c.error(format!("expected ASCII or BINARY, found \"{}\"", super::lex::shown(encoding)))),
    };
    let dataset = c.expect_line("'DATASET UNSTRUCTURED_GRID'")?;
    if !dataset.split_ascii_whitespace().eq(["DATASET", "UNSTRUCTURED_GRID"]) {
        return Err(c.error(format!(
            "expected 'DATASET UNSTRUCTURED_GRID' (the only VTK data set with tets), found \"{}\"",
            super::lex::shown(dataset)
        )));
    }
    let mut vertices: Option<Vec<[f64; 3]>> = None;
    let mut cells: Option<Vec<Vec<u64>>> = None;
    let mut types: Option<Vec<i64>> = None;
    while let Some(line) = c.line() {
        let words: Vec<&str> = line.split_ascii_whitespace().collect();
        let count = |k: usize| words.get(k).and_then(|w| w.parse::<usize>().ok());
        match words[0] {
            "POINTS" => {
                let (Some(n), Some(&kind)) = (count(1), words.get(2)) else {
                    return Err(c.error("expected 'POINTS n type'"));
                };
                let xyz = c.numbers(n.saturating_mul(3), kind, "the points")?;
                vertices = Some(xyz.as_chunks::<3>().0.to_vec());
            }
            "CELLS" if !new_cells => {
                let (Some(n), Some(size)) = (count(1), count(2)) else {
                    return Err(c.error("expected 'CELLS n size'"));
                };
                let list = c.numbers(size, "int", "the cells")?;
                let mut out = Vec::with_capacity(n.min(list.len()));
                let mut pos = 0;
                while out.len() < n {
                    let k = list.get(pos).and_then(|&k| whole(k, 64)).ok_or_else(|| {
                        c.error(format!("cell {} has no valid point count in the CELLS list", out.len()))
                    })? as usize;
                    let Some(ids) = list.get(pos + 1..pos + 1 + k) else {
                        return Err(c.error(format!("cell {} runs past the CELLS list", out.len())));
                    };
                    out.push(ids.iter().map(|&v| whole(v, u32::MAX as u64).unwrap_or(u64::MAX)).collect());
                    pos += k + 1;
                }
                cells = Some(out);
            }
            "CELLS" => {
                // Version 5: OFFSETS and CONNECTIVITY arrays follow.
                let (Some(n_offsets), Some(n_conn)) = (count(1), count(2)) else {
                    return Err(c.error("expected 'CELLS n_offsets n_connectivity'"));
                };
                let mut arrays = [Vec::new(), Vec::new()];
                for (k, (word, n)) in [("OFFSETS", n_offsets), ("CONNECTIVITY", n_conn)].into_iter().enumerate() {
                    let head = c.expect_line(&format!("'{word} type'"))?;
                    let parts: Vec<&str> = head.split_ascii_whitespace().collect();
                    if parts.first() != Some(&word) || parts.len() != 2 {
                        return Err(c.error(format!("expected '{word} type', found \"{}\"", super::lex::shown(head))));
                    }
                    arrays[k] = c.numbers(n, parts[1], &word.to_ascii_lowercase())?;
                }
                let [offsets, connectivity] = arrays;
                let mut out = Vec::with_capacity(offsets.len().saturating_sub(1));
                for w in offsets.windows(2) {
                    let (Some(a), Some(b)) = (whole(w[0], u64::MAX), whole(w[1], u64::MAX)) else {
                        return Err(c.error("an offset is not a whole number"));
                    };
                    let Some(ids) = connectivity.get(a as usize..b as usize) else {
                        return Err(c.error(format!("cell {} runs past the connectivity", out.len())));
                    };
                    out.push(ids.iter().map(|&v| whole(v, u32::MAX as u64).unwrap_or(u64::MAX)).collect());
                }
                cells = Some(out);
            }
            "CELL_TYPES" => {
                let Some(n) = count(1) else { return Err(c.error("expected 'CELL_TYPES n'")) };
                let t = c.numbers(n, "int", "the cell types")?;
                types = Some(t.iter().map(|&x| x as i64).collect());
            }
            // Data and metadata after the grid: the mesh is complete.
            "POINT_DATA" | "CELL_DATA" => break,
            // METADATA and anything else between the sections.
            _ => {}
        }
    }
    let (Some(vertices), Some(cells), Some(types)) = (vertices, cells, types) else {
        return Err(c.error("expected POINTS, CELLS and CELL_TYPES sections"));
    };
    if types.len() != cells.len() {
        return Err(c.error(format!("{} cell types for {} cells", types.len(), cells.len())));
    }
    let mut tets = Vec::new();
    let mut others: Vec<(i64, usize)> = Vec::new();
    for (i, (cell, &kind)) in cells.iter().zip(&types).enumerate() {
        if kind == TETRA {
            if cell.len() != 4 {
                return Err(c.error(format!("tetra {i} has {} points", cell.len())));
            }
            if let Some(&bad) = cell.iter().find(|&&v| v as usize >= vertices.len()) {
                return Err(
                    c.error(format!("cell {i} refers to point {bad}, but the file has {} points", vertices.len()))
                );
            }
            tets.push([cell[0] as u32, cell[1] as u32, cell[2] as u32, cell[3] as u32]);
        } else if !LOWER_DIMENSIONAL.contains(&kind) {
            match others.iter_mut().find(|(t, _)| *t == kind) {
                Some((_, n)) => *n += 1,
                None => others.push((kind, 1)),
            }
        }
    }
    if !others.is_empty() {
        let listed: Vec<String> = others.iter().map(|(t, n)| format!("{n} of VTK cell type {t}")).collect();
        return Err(Error::InvalidInput(format!(
            "{name}: only tetrahedra (cell type 10) are supported as volume cells; the file also has {}",
            listed.join(", ")
        )));
    }
    TetMesh::new(vertices, tets).map_err(|e| Error::InvalidInput(format!("{name}: {e}")))
}

#[cfg(test)]
pub(super) mod tests {
    use super::super::tests::no_panic_on_mutations;
    use super::*;

    pub(in crate::read) const TWO_TETS: &str =
        "# vtk DataFile Version 4.2\ntwo tets\nASCII\nDATASET UNSTRUCTURED_GRID\n\
        POINTS 5 double\n0 0 0 1 0 0 0 1 0 0 0 1 1 1 1\nCELLS 3 14\n4 0 1 2 3\n4 1 2 3 4\n3 1 2 3\n\
        CELL_TYPES 3\n10\n10\n5\n";

    #[test]
    fn tets_are_read_and_triangles_skipped() {
        let mesh = parse_vtk(TWO_TETS.as_bytes(), "two.vtk").unwrap();
        assert_eq!(mesh.tets, vec![[0, 1, 2, 3], [1, 2, 3, 4]]);
        assert!((mesh.volume() - 0.5).abs() < 1e-12);
        let e = parse_vtk(TWO_TETS.replace("4 1 2 3 4", "4 1 2 3 9").as_bytes(), "bad.vtk").unwrap_err();
        assert!(e.to_string().contains("bad.vtk") && e.to_string().contains("point 9"), "{e}");
        let e = parse_vtk(TWO_TETS.replace("10\n10\n5", "10\n12\n5").as_bytes(), "hex.vtk").unwrap_err();
        assert!(e.to_string().contains("1 of VTK cell type 12"), "{e}");
    }

    #[test]
    fn no_vtk_file_makes_the_reader_panic() {
        no_panic_on_mutations(TWO_TETS, |t| parse_vtk(t.as_bytes(), "m.vtk"));
        let binary = TWO_TETS.replace("ASCII", "BINARY");
        for cut in 0..binary.len() {
            let _ = parse_vtk(&binary.as_bytes()[..cut], "cut.vtk");
        }
    }
}
