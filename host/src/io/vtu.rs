//! VTK XML unstructured grids (`.vtu`): inline data arrays in ASCII or
//! base64 binary, raw or zlib-compressed (what meshio and ParaView write),
//! through `quick-xml` for the XML and `flate2` for zlib. Appended data
//! and other compressors are refused by name. As for legacy `.vtk` files,
//! tetrahedra become the mesh, cells of lower dimension are skipped, and
//! other volume cells are an error naming how many.

use super::vtk::{LOWER_DIMENSIONAL, TETRA};
use crate::error::{Error, Result};
use crate::mesh::TetMesh;
use base64::Engine;
use quick_xml::events::{BytesStart, Event};
use std::io::Read;

/// How the file stores binary arrays.
struct Encoding {
    header: usize,
    little: bool,
    zlib: bool,
}

/// One `DataArray` being read.
#[derive(Default)]
struct Array {
    name: String,
    kind: String,
    format: String,
    text: String,
}

fn attr(e: &BytesStart, key: &str) -> Option<String> {
    e.attributes()
        .flatten()
        .find(|a| a.key.as_ref() == key.as_bytes())
        .map(|a| String::from_utf8_lossy(&a.value).into_owned())
}

fn bad(name: &str, message: impl std::fmt::Display) -> Error {
    Error::InvalidInput(format!("{name}: {message}"))
}

/// The values of an array of VTK type `kind`, as f64, from raw bytes.
fn values(raw: &[u8], kind: &str, little: bool, name: &str) -> Result<Vec<f64>> {
    macro_rules! read {
        ($t:ty) => {{
            const N: usize = std::mem::size_of::<$t>();
            raw.chunks_exact(N)
                .map(|c| {
                    let b: [u8; N] = c.try_into().unwrap_or([0; N]);
                    (if little { <$t>::from_le_bytes(b) } else { <$t>::from_be_bytes(b) }) as f64
                })
                .collect()
        }};
    }
    Ok(match kind {
        "Float32" => read!(f32),
        "Float64" => read!(f64),
        "Int8" => read!(i8),
        "UInt8" => read!(u8),
        "Int16" => read!(i16),
        "UInt16" => read!(u16),
        "Int32" => read!(i32),
        "UInt32" => read!(u32),
        "Int64" => read!(i64),
        "UInt64" => read!(u64),
        _ => return Err(bad(name, format!("unsupported DataArray type '{kind}'"))),
    })
}

fn header_values(raw: &[u8], enc: &Encoding, name: &str) -> Result<Vec<usize>> {
    let kind = if enc.header == 8 { "UInt64" } else { "UInt32" };
    Ok(values(raw, kind, enc.little, name)?.into_iter().map(|x| x as usize).collect())
}

fn base64(text: &str, name: &str) -> Result<Vec<u8>> {
    base64::engine::general_purpose::STANDARD.decode(text).map_err(|e| bad(name, format!("bad base64 data: {e}")))
}

/// The bytes of a binary array: a header with the byte count, or with the
/// zlib blocks' sizes, then the data.
fn decode(text: &str, enc: &Encoding, name: &str) -> Result<Vec<u8>> {
    let s: String = text.chars().filter(|c| !c.is_ascii_whitespace()).collect();
    let h = enc.header;
    if !enc.zlib {
        let all = base64(&s, name)?;
        let n = header_values(all.get(..h).unwrap_or(&[]), enc, name)?.first().copied().unwrap_or(0);
        return all
            .get(h..h + n)
            .map(<[u8]>::to_vec)
            .ok_or_else(|| bad(name, "a binary array is shorter than its header says"));
    }
    // The header is encoded apart: [blocks, block size, last block size,
    // compressed sizes...].
    let first = base64(s.get(..4 * h).unwrap_or(""), name)?;
    let blocks = header_values(&first, enc, name)?.first().copied().unwrap_or(0);
    if blocks > s.len() {
        return Err(bad(name, format!("a compressed array claims {blocks} blocks")));
    }
    let header_chars = 4 * ((3 + blocks) * h).div_ceil(3);
    let header = header_values(&base64(s.get(..header_chars).unwrap_or(""), name)?, enc, name)?;
    let data = base64(s.get(header_chars..).unwrap_or(""), name)?;
    let (block, last) = (header.get(1).copied().unwrap_or(0), header.get(2).copied().unwrap_or(0));
    let mut out = Vec::new();
    let mut at = 0usize;
    for b in 0..blocks {
        let size = header.get(3 + b).copied().unwrap_or(0);
        let chunk = data.get(at..at + size).ok_or_else(|| bad(name, "a compressed block runs past its array"))?;
        at += size;
        // Never more than the block's own size: no zlib bomb.
        let limit = if b + 1 == blocks && last > 0 { last } else { block };
        flate2::read::ZlibDecoder::new(chunk)
            .take(limit as u64)
            .read_to_end(&mut out)
            .map_err(|e| bad(name, format!("bad zlib data: {e}")))?;
    }
    Ok(out)
}

fn numbers(a: &Array, enc: &Encoding, name: &str) -> Result<Vec<f64>> {
    match a.format.as_str() {
        "ascii" => a
            .text
            .split_ascii_whitespace()
            .map(|t| {
                t.parse::<f64>().map_err(|_| {
                    bad(name, format!("'{}' in DataArray {} is not a number", super::lex::shown(t), a.name))
                })
            })
            .collect(),
        "binary" => values(&decode(&a.text, enc, name)?, &a.kind, enc.little, name),
        "appended" => Err(bad(name, "appended data arrays are not supported (write the file with inline data)")),
        other => Err(bad(name, format!("unknown DataArray format '{other}'"))),
    }
}

/// A `.vtu` file.
pub fn parse_vtu(bytes: &[u8], name: &str) -> Result<TetMesh> {
    let mut reader = quick_xml::Reader::from_reader(bytes);
    let mut buf = Vec::new();
    let mut enc = Encoding { header: 4, little: true, zlib: false };
    let mut section = String::new();
    let mut array: Option<Array> = None;
    let (mut points, mut connectivity, mut offsets, mut types) = (None, None, None, None);
    let mut vertices: Vec<[f64; 3]> = Vec::new();
    let mut tets: Vec<[u32; 4]> = Vec::new();
    let mut others = 0usize;
    let mut grid = false;
    loop {
        let event = reader.read_event_into(&mut buf).map_err(|e| bad(name, format!("not valid XML: {e}")))?;
        match event {
            Event::Start(e) | Event::Empty(e) => match e.name().as_ref() {
                b"VTKFile" => {
                    grid = attr(&e, "type").as_deref() == Some("UnstructuredGrid");
                    enc.header = if attr(&e, "header_type").as_deref() == Some("UInt64") { 8 } else { 4 };
                    enc.little = attr(&e, "byte_order").as_deref() != Some("BigEndian");
                    enc.zlib = match attr(&e, "compressor").as_deref() {
                        None | Some("") => false,
                        Some("vtkZLibDataCompressor") => true,
                        Some(other) => return Err(bad(name, format!("compressor {other} is not supported (zlib is)"))),
                    };
                }
                b"Points" | b"Cells" | b"PointData" | b"CellData" | b"FieldData" => {
                    section = String::from_utf8_lossy(e.name().as_ref()).into_owned();
                }
                b"DataArray" => {
                    array = Some(Array {
                        name: attr(&e, "Name").unwrap_or_default(),
                        kind: attr(&e, "type").unwrap_or_default(),
                        format: attr(&e, "format").unwrap_or_else(|| "ascii".into()),
                        text: String::new(),
                    });
                }
                _ => {}
            },
            Event::Text(t) => {
                if let Some(a) = array.as_mut() {
                    a.text.push_str(&String::from_utf8_lossy(&t));
                }
            }
            Event::End(e) => match e.name().as_ref() {
                b"DataArray" => {
                    if let Some(a) = array.take() {
                        match (section.as_str(), a.name.as_str()) {
                            ("Points", _) if points.is_none() => points = Some(numbers(&a, &enc, name)?),
                            ("Cells", "connectivity") => connectivity = Some(numbers(&a, &enc, name)?),
                            ("Cells", "offsets") => offsets = Some(numbers(&a, &enc, name)?),
                            ("Cells", "types") => types = Some(numbers(&a, &enc, name)?),
                            _ => {}
                        }
                    }
                }
                b"Points" | b"Cells" | b"PointData" | b"CellData" | b"FieldData" => section.clear(),
                b"Piece" => {
                    let (Some(p), Some(c), Some(o), Some(t)) =
                        (points.take(), connectivity.take(), offsets.take(), types.take())
                    else {
                        return Err(bad(
                            name,
                            "a Piece lacks its Points or its Cells' connectivity, offsets and types",
                        ));
                    };
                    let base = vertices.len();
                    vertices.extend(p.as_chunks::<3>().0.iter().copied());
                    let n = vertices.len() - base;
                    if o.len() != t.len() {
                        return Err(bad(name, format!("{} offsets for {} cell types", o.len(), t.len())));
                    }
                    let mut start = 0usize;
                    for (i, (&end, &kind)) in o.iter().zip(&t).enumerate() {
                        let end = end as usize;
                        let Some(cell) = c.get(start..end) else {
                            return Err(bad(name, format!("cell {i} runs past the connectivity")));
                        };
                        start = end;
                        let kind = kind as i64;
                        if kind == TETRA {
                            if cell.len() != 4 || cell.iter().any(|&v| !(v >= 0.0 && (v as usize) < n)) {
                                return Err(bad(name, format!("tetra {i} has points {cell:?}, of {n}")));
                            }
                            tets.push([0, 1, 2, 3].map(|k| (cell[k] as usize + base) as u32));
                        } else if !LOWER_DIMENSIONAL.contains(&kind) {
                            others += 1;
                        }
                    }
                }
                _ => {}
            },
            Event::Eof => break,
            _ => {}
        }
        buf.clear();
    }
    if !grid {
        return Err(bad(name, "not a VTK XML UnstructuredGrid file"));
    }
    if others > 0 {
        return Err(bad(
            name,
            format!("only tetrahedra are supported as volume cells; the file also has {others} others"),
        ));
    }
    if vertices.len() > u32::MAX as usize {
        return Err(bad(name, "more than 2^32 points"));
    }
    TetMesh::new(vertices, tets).map_err(|e| bad(name, e))
}

#[cfg(test)]
mod tests {
    use super::super::tests::no_panic_on_mutations;
    use super::*;

    const TWO_TETS: &str = r#"<?xml version="1.0"?>
<VTKFile type="UnstructuredGrid" version="0.1" byte_order="LittleEndian">
<UnstructuredGrid>
<Piece NumberOfPoints="5" NumberOfCells="3">
<Points>
<DataArray type="Float64" NumberOfComponents="3" format="ascii">
0 0 0 1 0 0 0 1 0 0 0 1 1 1 1
</DataArray>
</Points>
<Cells>
<DataArray type="Int64" Name="connectivity" format="ascii">0 1 2 3 1 2 3 4 1 2 3</DataArray>
<DataArray type="Int64" Name="offsets" format="ascii">4 8 11</DataArray>
<DataArray type="UInt8" Name="types" format="ascii">10 10 5</DataArray>
</Cells>
</Piece>
</UnstructuredGrid>
</VTKFile>
"#;

    #[test]
    fn tets_are_read_and_other_cells_refused() {
        let mesh = parse_vtu(TWO_TETS.as_bytes(), "two.vtu").unwrap();
        assert_eq!(mesh.tets, vec![[0, 1, 2, 3], [1, 2, 3, 4]]);
        let e = parse_vtu(TWO_TETS.replace(">10 10 5<", ">10 12 5<").as_bytes(), "hex.vtu").unwrap_err();
        assert!(e.to_string().contains("hex.vtu") && e.to_string().contains("1 others"), "{e}");
        let e = parse_vtu(TWO_TETS.replace("format=\"ascii\">4 8", "format=\"appended\">4 8").as_bytes(), "a.vtu");
        assert!(e.unwrap_err().to_string().contains("appended"));
    }

    #[test]
    fn no_vtu_file_makes_the_reader_panic() {
        no_panic_on_mutations(TWO_TETS, |t| parse_vtu(t.as_bytes(), "m.vtu"));
        let zlib = TWO_TETS
            .replace("byte_order=\"LittleEndian\"", "byte_order=\"LittleEndian\" compressor=\"vtkZLibDataCompressor\"")
            .replace("format=\"ascii\">4 8 11", "format=\"binary\">AQAAAAAAAAAAAAAA////eJzz//8/");
        let _ = parse_vtu(zlib.as_bytes(), "z.vtu");
    }
}
