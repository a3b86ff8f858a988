//! `pieces.vtu`: the pieces as a VTK XML UnstructuredGrid (ASCII), one
//! `VTK_POLYHEDRON` (cell type 42) per piece in the classic
//! `faces`/`faceoffsets` layout that ParaView and meshio read, with cell
//! data `site` and `tet` (input indices; -1 for a whole cell, in no tet)
//! and `volume`. Each piece has its
//! own points, so that cells can be moved apart (ParaView's Shrink filter).
//!
//! Pieces are written by increasing vertex count, then in the order given:
//! meshio (5.3) sorts polyhedra into blocks by vertex count in file order
//! but their cell data by increasing count, which agree only then.

use super::Progress;
use cvd::error::{Error, Result};
use cvd::passes::pieces::{Piece, Pieces};
use std::io::Write;
use std::path::Path;

/// VTK's cell type for polyhedra.
const VTK_POLYHEDRON: u8 = 42;

/// Writes `pieces` to `path`, reporting progress in pieces written, four
/// passes over them in all.
pub fn write_pieces_vtu(path: &Path, pieces: &Pieces, progress: Progress<'_>) -> Result<()> {
    let pieces = pieces.to_vec();
    let mut order: Vec<&Piece> = pieces.iter().collect();
    order.sort_by_key(|p| p.vertices.len());
    let io = |source| Error::Write { path: path.display().to_string(), source };
    let file = std::fs::File::create(path).map_err(io)?;
    let mut w = std::io::BufWriter::with_capacity(1 << 20, file);
    write_body(&mut w, &order, progress).map_err(io)?;
    w.flush().map_err(io)
}

/// Calls `each` on every piece, reporting progress every few thousand.
fn pass(
    w: &mut dyn Write,
    pieces: &[&Piece],
    step: u64,
    progress: &mut dyn FnMut(u64, u64),
    mut each: impl FnMut(&mut dyn Write, &Piece) -> std::io::Result<()>,
) -> std::io::Result<()> {
    let total = 4 * pieces.len() as u64;
    for (i, &p) in pieces.iter().enumerate() {
        each(w, p)?;
        if i % 4096 == 4095 {
            progress(step * pieces.len() as u64 + i as u64 + 1, total);
        }
    }
    progress((step + 1) * pieces.len() as u64, total);
    Ok(())
}

fn write_body(w: &mut dyn Write, pieces: &[&Piece], progress: Progress<'_>) -> std::io::Result<()> {
    let n_points: usize = pieces.iter().map(|p| p.vertices.len()).sum();
    writeln!(w, r#"<?xml version="1.0"?>"#)?;
    writeln!(w, r#"<VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian" header_type="UInt64">"#)?;
    writeln!(w, "<UnstructuredGrid>")?;
    writeln!(w, r#"<Piece NumberOfPoints="{n_points}" NumberOfCells="{}">"#, pieces.len())?;

    writeln!(w, "<Points>")?;
    writeln!(w, r#"<DataArray type="Float64" Name="Points" NumberOfComponents="3" format="ascii">"#)?;
    pass(w, pieces, 0, progress, |w, p| {
        for [x, y, z] in &p.vertices {
            writeln!(w, "{x} {y} {z}")?;
        }
        Ok(())
    })?;
    writeln!(w, "</DataArray>\n</Points>")?;

    writeln!(w, "<Cells>")?;
    // A polyhedron's points: its own, numbered after the previous pieces'.
    writeln!(w, r#"<DataArray type="Int64" Name="connectivity" format="ascii">"#)?;
    let mut first = 0usize;
    pass(w, pieces, 1, progress, |w, p| {
        for i in first..first + p.vertices.len() {
            write!(w, "{i} ")?;
        }
        first += p.vertices.len();
        writeln!(w)
    })?;
    writeln!(w, "</DataArray>")?;
    writeln!(w, r#"<DataArray type="Int64" Name="offsets" format="ascii">"#)?;
    let mut end = 0usize;
    for p in pieces {
        end += p.vertices.len();
        writeln!(w, "{end}")?;
    }
    writeln!(w, "</DataArray>")?;
    writeln!(w, r#"<DataArray type="UInt8" Name="types" format="ascii">"#)?;
    for _ in pieces {
        writeln!(w, "{VTK_POLYHEDRON}")?;
    }
    writeln!(w, "</DataArray>")?;
    // Per polyhedron: the face count, then each face as its point count
    // and points; `faceoffsets` gives where each polyhedron's part ends.
    writeln!(w, r#"<DataArray type="Int64" Name="faces" format="ascii">"#)?;
    let mut first = 0usize;
    pass(w, pieces, 2, progress, |w, p| {
        write!(w, "{}", p.face_ends.len())?;
        for face in p.faces() {
            write!(w, " {}", face.len())?;
            for &v in face {
                write!(w, " {}", first + v as usize)?;
            }
        }
        first += p.vertices.len();
        writeln!(w)
    })?;
    writeln!(w, "</DataArray>")?;
    writeln!(w, r#"<DataArray type="Int64" Name="faceoffsets" format="ascii">"#)?;
    let mut end = 0usize;
    for p in pieces {
        end += 1 + p.face_ends.len() + p.face_vertices.len();
        writeln!(w, "{end}")?;
    }
    writeln!(w, "</DataArray>")?;
    writeln!(w, "</Cells>")?;

    writeln!(w, r#"<CellData Scalars="site">"#)?;
    writeln!(w, r#"<DataArray type="Int32" Name="site" format="ascii">"#)?;
    for p in pieces {
        writeln!(w, "{}", p.site)?;
    }
    writeln!(w, "</DataArray>")?;
    // A whole cell (in no tet) as -1: Int32, as VTK reads it.
    writeln!(w, r#"<DataArray type="Int32" Name="tet" format="ascii">"#)?;
    for p in pieces {
        match p.tet {
            Piece::WHOLE => writeln!(w, "-1")?,
            tet => writeln!(w, "{tet}")?,
        }
    }
    writeln!(w, "</DataArray>")?;
    writeln!(w, r#"<DataArray type="Float64" Name="volume" format="ascii">"#)?;
    pass(w, pieces, 3, progress, |w, p| writeln!(w, "{:e}", p.volume()))?;
    writeln!(w, "</DataArray>")?;
    writeln!(w, "</CellData>")?;
    writeln!(w, "</Piece>\n</UnstructuredGrid>\n</VTKFile>")
}
