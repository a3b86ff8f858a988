//! `cells.vtu`: each cell as one VTK polyhedron (cell type 42, in the
//! `faces`/`faceoffsets` layout VTK, ParaView and meshio read), binary:
//! raw appended data, each array zlib-compressed in blocks (VTK's
//! `vtkZLibDataCompressor` layout, `UInt64` headers). Cell data: `site`,
//! `volume`, `centroid`, `energy`, `neighbors` (faces shared with other
//! cells, counted by neighbour). Each cell has its own points, so that
//! cells can be moved apart (ParaView's Shrink filter).
//!
//! Cells are written by increasing point count, then by site: meshio
//! (5.3) sorts polyhedra into blocks by point count in file order but
//! their cell data by increasing count, which agree only then.

use super::Progress;
use cvd::diagram::voronoi::Cells;
use cvd::error::{Error, Result};
use cvd::passes::polyhedra::CellPolyhedron;
use flate2::write::ZlibEncoder;
use flate2::Compression;
use rayon::prelude::*;
use std::io::Write;
use std::path::Path;

/// VTK's cell type for polyhedra.
const VTK_POLYHEDRON: u8 = 42;

/// Uncompressed bytes per zlib block.
const BLOCK: usize = 1 << 20;

/// A cell's numbers in `cells.vtu`: its volume, centroid and energy.
pub type CellNumbers = (f64, [f64; 3], f64);

/// Writes `polyhedra` (with their cells' numbers from `cells`) to `path`,
/// reporting progress in arrays written.
pub fn write_cells_vtu(path: &Path, cells: &Cells, polyhedra: &[CellPolyhedron], progress: Progress<'_>) -> Result<()> {
    let numbers = |k: usize| {
        let i = polyhedra[k].site as usize;
        (cells.volume[i], cells.centroid[i], cells.energy[i])
    };
    write_cells_vtu_with(path, polyhedra, &numbers, progress)
}

/// [`write_cells_vtu`] with the numbers of the cell of `polyhedra[k]`
/// given by `numbers(k)`: a piece of a run in parts (the cells one rank
/// built, their sites by input index).
pub fn write_cells_vtu_with(
    path: &Path,
    polyhedra: &[CellPolyhedron],
    numbers: &(dyn Fn(usize) -> CellNumbers + Sync),
    progress: Progress<'_>,
) -> Result<()> {
    let mut keyed: Vec<usize> = (0..polyhedra.len()).collect();
    keyed.sort_by_key(|&k| (polyhedra[k].vertices.len(), polyhedra[k].site));
    let order: Vec<&CellPolyhedron> = keyed.iter().map(|&k| &polyhedra[k]).collect();
    let n_points: usize = order.iter().map(|p| p.vertices.len()).sum();

    // Each array compressed as soon as it is made: (type, name,
    // components, zlib blocks).
    let mut arrays: Vec<(&str, &str, usize, Vec<u8>)> = Vec::new();
    // Points, the 5 cells' arrays and the 5 cell data (progress).
    let total = 11;
    let mut push = |kind, name, components, raw: Vec<u8>| {
        arrays.push((kind, name, components, compress(&raw)));
        progress(arrays.len() as u64, total);
    };
    let mut bytes = Vec::with_capacity(n_points * 24);
    for p in &order {
        for v in &p.vertices {
            for c in v {
                bytes.extend_from_slice(&c.to_le_bytes());
            }
        }
    }
    push("Float64", "Points", 3, bytes);
    // Indices in 32 bits (VTK widens them on reading) where they fit.
    let wide = n_points > i32::MAX as usize / 2;
    let ids = |values: &mut dyn Iterator<Item = i64>| -> Vec<u8> {
        if wide {
            values.flat_map(|v| v.to_le_bytes()).collect()
        } else {
            values.flat_map(|v| (v as i32).to_le_bytes()).collect()
        }
    };
    let id_type = if wide { "Int64" } else { "Int32" };
    push(id_type, "connectivity", 1, ids(&mut (0..n_points as i64)));
    let mut end = 0i64;
    let offsets = ids(&mut order.iter().map(|p| {
        end += p.vertices.len() as i64;
        end
    }));
    push(id_type, "offsets", 1, offsets);
    push("UInt8", "types", 1, vec![VTK_POLYHEDRON; order.len()]);
    // Per polyhedron: its face count, then each face as its point count
    // and points (numbered over the whole file).
    let mut faces = Vec::new();
    let mut faceoffsets = Vec::with_capacity(order.len());
    let mut first = 0i64;
    for p in &order {
        faces.push(p.face_ends.len() as i64);
        for face in p.faces() {
            faces.push(face.len() as i64);
            faces.extend(face.iter().map(|&v| first + v as i64));
        }
        first += p.vertices.len() as i64;
        faceoffsets.push(faces.len() as i64);
    }
    push(id_type, "faces", 1, ids(&mut faces.into_iter()));
    push(id_type, "faceoffsets", 1, ids(&mut faceoffsets.into_iter()));

    push("Int32", "site", 1, order.iter().flat_map(|p| (p.site as i32).to_le_bytes()).collect());
    let f64s = |values: &mut dyn Iterator<Item = f64>| values.flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>();
    let numbers: Vec<CellNumbers> = keyed.iter().map(|&k| numbers(k)).collect();
    push("Float64", "volume", 1, f64s(&mut numbers.iter().map(|n| n.0)));
    push("Float64", "centroid", 3, f64s(&mut numbers.iter().flat_map(|n| n.1)));
    push("Float64", "energy", 1, f64s(&mut numbers.iter().map(|n| n.2)));
    let neighbors = |p: &&CellPolyhedron| {
        let mut n: Vec<i64> = p.face_neighbors.iter().copied().filter(|&j| j >= 0).collect();
        n.sort_unstable();
        n.dedup();
        n.len() as i32
    };
    push("Int32", "neighbors", 1, order.iter().flat_map(|p| neighbors(p).to_le_bytes()).collect());
    // The first 6 arrays describe the cells; the rest are cell data.
    let n_cell_arrays = 6;

    let io = |source| Error::Write { path: path.display().to_string(), source };
    let file = std::fs::File::create(path).map_err(io)?;
    let mut w = std::io::BufWriter::with_capacity(1 << 20, file);
    let mut body = || -> std::io::Result<()> {
        writeln!(w, r#"<?xml version="1.0"?>"#)?;
        writeln!(
            w,
            r#"<VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian" header_type="UInt64" compressor="vtkZLibDataCompressor">"#
        )?;
        writeln!(w, "<UnstructuredGrid>")?;
        writeln!(w, r#"<Piece NumberOfPoints="{n_points}" NumberOfCells="{}">"#, order.len())?;
        let mut offset = 0usize;
        for (k, (kind, name, components, _)) in arrays.iter().enumerate() {
            match k {
                0 => writeln!(w, "<Points>")?,
                1 => writeln!(w, "</Points>\n<Cells>")?,
                k if k == n_cell_arrays => writeln!(w, "</Cells>\n<CellData Scalars=\"site\">")?,
                _ => {}
            }
            writeln!(
                w,
                r#"<DataArray type="{kind}" Name="{name}" NumberOfComponents="{components}" format="appended" offset="{offset}"/>"#
            )?;
            offset += arrays[k].3.len();
        }
        writeln!(w, "</CellData>\n</Piece>\n</UnstructuredGrid>")?;
        write!(w, "<AppendedData encoding=\"raw\">\n_")?;
        for (_, _, _, c) in &arrays {
            w.write_all(c)?;
        }
        writeln!(w, "\n</AppendedData>\n</VTKFile>")?;
        w.flush()
    };
    body().map_err(io)
}

/// Writes `cells.pvtu`: the pieces (`cells.vtu` files, named relative to
/// it) as one grid, as VTK and ParaView read a grid written in parts.
pub fn write_cells_pvtu(path: &Path, pieces: &[String]) -> Result<()> {
    let arrays = [
        ("Int32", "site", 1),
        ("Float64", "volume", 1),
        ("Float64", "centroid", 3),
        ("Float64", "energy", 1),
        ("Int32", "neighbors", 1),
    ];
    write_pvtu(path, &arrays, pieces)
}

/// `pieces.pvtu`: a parallel VTK file listing `pieces` (file names
/// relative to it), each a `pieces.vtu` of some of the pieces.
pub fn write_pieces_pvtu(path: &Path, pieces: &[String]) -> Result<()> {
    write_pvtu(path, &[("Int32", "site", 1), ("Int32", "tet", 1), ("Float64", "volume", 1)], pieces)
}

/// A parallel VTK file over `pieces` whose cells carry `arrays` (type,
/// name, components).
fn write_pvtu(path: &Path, arrays: &[(&str, &str, u32)], pieces: &[String]) -> Result<()> {
    let mut text = String::from(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"PUnstructuredGrid\" version=\"1.0\" \
         byte_order=\"LittleEndian\" header_type=\"UInt64\">\n<PUnstructuredGrid GhostLevel=\"0\">\n\
         <PCellData Scalars=\"site\">\n",
    );
    for (kind, name, components) in arrays {
        text += &format!("<PDataArray type=\"{kind}\" Name=\"{name}\" NumberOfComponents=\"{components}\"/>\n");
    }
    text += "</PCellData>\n<PPoints>\n<PDataArray type=\"Float64\" NumberOfComponents=\"3\"/>\n</PPoints>\n";
    for piece in pieces {
        text += &format!("<Piece Source=\"{piece}\"/>\n");
    }
    text += "</PUnstructuredGrid>\n</VTKFile>\n";
    std::fs::write(path, text).map_err(|source| Error::Write { path: path.display().to_string(), source })
}

/// `raw` as VTK's zlib blocks: the header `[blocks, block size, last
/// block's size, each block's compressed size]` (UInt64), then the blocks,
/// compressed in parallel.
fn compress(raw: &[u8]) -> Vec<u8> {
    let blocks: Vec<Vec<u8>> = raw
        .par_chunks(BLOCK)
        .map(|chunk| {
            let mut z = ZlibEncoder::new(Vec::with_capacity(chunk.len() / 2), Compression::fast());
            z.write_all(chunk).expect("writing to memory");
            z.finish().expect("writing to memory")
        })
        .collect();
    let last = if raw.is_empty() { 0 } else { raw.len() - (blocks.len() - 1) * BLOCK };
    let mut out = Vec::new();
    for h in [blocks.len(), BLOCK, last].into_iter().chain(blocks.iter().map(|b| b.len())) {
        out.extend_from_slice(&(h as u64).to_le_bytes());
    }
    for b in blocks {
        out.extend_from_slice(&b);
    }
    out
}
