//! VTK XML unstructured grids (`.vtu`): data arrays inline (ASCII or
//! base64) or appended (raw binary, ParaView's default, or base64), raw or
//! zlib-compressed — what meshio, VTK and ParaView write — through
//! `quick-xml` for the XML and `flate2` for zlib. Other compressors (LZ4,
//! LZMA) are refused by name. As for legacy `.vtk` files,
//! tetrahedra become the mesh, cells of lower dimension are skipped, and
//! other volume cells are an error naming how many.

use super::vtk::{LOWER_DIMENSIONAL, TETRA};
use base64::Engine;
use cvd::error::{Error, Result};
use cvd::geom::mesh::TetMesh;
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
    /// Where an appended array starts in the `AppendedData`.
    offset: Option<usize>,
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

/// The data of a binary array from its raw bytes: a header with the byte
/// count, or with the zlib blocks' sizes `[blocks, block size, last block
/// size, compressed sizes...]`, then the data.
fn unpack(raw: &[u8], enc: &Encoding, name: &str) -> Result<Vec<u8>> {
    let h = enc.header;
    let short = || bad(name, "a binary array is shorter than its header says");
    if !enc.zlib {
        let n = header_values(raw.get(..h).unwrap_or(&[]), enc, name)?.first().copied().unwrap_or(0);
        return raw.get(h..h.saturating_add(n)).map(<[u8]>::to_vec).ok_or_else(short);
    }
    let blocks = header_values(raw.get(..h).unwrap_or(&[]), enc, name)?.first().copied().unwrap_or(0);
    if blocks > raw.len() {
        return Err(bad(name, format!("a compressed array claims {blocks} blocks")));
    }
    let header_len = (3 + blocks) * h;
    let header = header_values(raw.get(..header_len).ok_or_else(short)?, enc, name)?;
    let data = &raw[header_len..];
    let (block, last) = (header.get(1).copied().unwrap_or(0), header.get(2).copied().unwrap_or(0));
    let mut out = Vec::new();
    let mut at = 0usize;
    for b in 0..blocks {
        let size = header.get(3 + b).copied().unwrap_or(0);
        let chunk =
            data.get(at..at.saturating_add(size)).ok_or_else(|| bad(name, "a compressed block runs past its array"))?;
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

/// The data of a base64 binary array: header and data encoded together,
/// or (compressed) the header encoded apart from the data.
fn decode(text: &[u8], enc: &Encoding, name: &str) -> Result<Vec<u8>> {
    let s: String = text.iter().filter(|c| !c.is_ascii_whitespace()).map(|&c| c as char).collect();
    if !enc.zlib {
        return unpack(&base64(&s, name)?, enc, name);
    }
    let h = enc.header;
    let first = base64(s.get(..4 * h).unwrap_or(""), name)?;
    let blocks = header_values(&first, enc, name)?.first().copied().unwrap_or(0);
    if blocks > s.len() {
        return Err(bad(name, format!("a compressed array claims {blocks} blocks")));
    }
    let header_chars = 4 * ((3 + blocks) * h).div_ceil(3);
    let mut raw = base64(s.get(..header_chars).unwrap_or(""), name)?;
    raw.truncate((3 + blocks) * h);
    raw.extend(base64(s.get(header_chars..).unwrap_or(""), name)?);
    unpack(&raw, enc, name)
}

/// The file's `AppendedData`: its bytes after the `_` mark, whether they
/// are base64 (else raw binary), and every array's offset into them.
struct Appended<'a> {
    bytes: &'a [u8],
    base64: bool,
    offsets: Vec<usize>,
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

fn rfind(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).rposition(|w| w == needle)
}

/// Splits off the `AppendedData` section (raw binary is not XML): the XML
/// around it, and the section.
fn split_appended<'a>(bytes: &'a [u8], name: &str) -> Result<(std::borrow::Cow<'a, [u8]>, Option<Appended<'a>>)> {
    let Some(start) = find(bytes, b"<AppendedData") else { return Ok((bytes.into(), None)) };
    let tag_end = start + find(&bytes[start..], b">").ok_or_else(|| bad(name, "an unterminated AppendedData tag"))?;
    let tag = String::from_utf8_lossy(&bytes[start..tag_end]);
    let base64 = match tag.split("encoding=").nth(1).and_then(|v| v.split(['"', '\'']).nth(1)) {
        Some("raw") => false,
        Some("base64") => true,
        other => return Err(bad(name, format!("AppendedData encoding {other:?}: raw or base64 expected"))),
    };
    let mark = tag_end + find(&bytes[tag_end..], b"_").ok_or_else(|| bad(name, "AppendedData without its '_' mark"))?;
    let close = rfind(bytes, b"</AppendedData>")
        .filter(|&i| i > mark)
        .ok_or_else(|| bad(name, "AppendedData without its end tag"))?;
    let mut xml = bytes[..start].to_vec();
    xml.extend_from_slice(&bytes[close + b"</AppendedData>".len()..]);
    let text = String::from_utf8_lossy(&xml);
    let mut offsets: Vec<usize> = text
        .split(" offset=\"")
        .skip(1)
        .filter_map(|v| v.split('"').next().and_then(|n| n.trim().parse().ok()))
        .collect();
    offsets.sort_unstable();
    Ok((xml.into(), Some(Appended { bytes: &bytes[mark + 1..close], base64, offsets })))
}

fn numbers(a: &Array, enc: &Encoding, appended: Option<&Appended>, name: &str) -> Result<Vec<f64>> {
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
        "binary" => values(&decode(a.text.as_bytes(), enc, name)?, &a.kind, enc.little, name),
        "appended" => {
            let block = appended.ok_or_else(|| {
                bad(name, format!("DataArray {} is appended, but the file has no AppendedData", a.name))
            })?;
            let at = a.offset.filter(|&o| o <= block.bytes.len()).ok_or_else(|| {
                bad(name, format!("DataArray {} has no offset within the AppendedData ({:?})", a.name, a.offset))
            })?;
            let rest = &block.bytes[at..];
            let data = if block.base64 {
                // Up to the next array's offset, or the end.
                let next = block.offsets.iter().find(|&&o| o > at);
                let end = next.map_or(rest.len(), |&n| (n - at).min(rest.len()));
                decode(&rest[..end], enc, name)?
            } else {
                unpack(rest, enc, name)?
            };
            values(&data, &a.kind, enc.little, name)
        }
        other => Err(bad(name, format!("unknown DataArray format '{other}'"))),
    }
}

/// A `.vtu` file.
pub fn parse_vtu(bytes: &[u8], name: &str) -> Result<TetMesh> {
    let (xml, appended) = split_appended(bytes, name)?;
    let appended = appended.as_ref();
    let mut reader = quick_xml::Reader::from_reader(xml.as_ref());
    // `<DataArray .../>` (appended) as a start and an end.
    reader.config_mut().expand_empty_elements = true;
    let mut buf = Vec::new();
    let mut enc = Encoding { header: 4, little: true, zlib: false };
    let mut section = String::new();
    let mut array: Option<Array> = None;
    let (mut points, mut connectivity, mut offsets, mut types) = (None, None, None, None);
    let mut vertices: Vec<[f64; 3]> = Vec::new();
    let mut tets: Vec<[u32; 4]> = Vec::new();
    let mut others = 0usize;
    let mut grid = false;
    let mut nested = 0usize;
    loop {
        let event = reader.read_event_into(&mut buf).map_err(|e| bad(name, format!("not valid XML: {e}")))?;
        match event {
            // Elements inside a DataArray (VTK's InformationKey) hold no data.
            Event::Start(_) if array.is_some() => nested += 1,
            Event::End(_) if nested > 0 => nested -= 1,
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
                        offset: attr(&e, "offset").and_then(|o| o.trim().parse().ok()),
                        text: String::new(),
                    });
                }
                _ => {}
            },
            Event::Text(t) if nested == 0 => {
                if let Some(a) = array.as_mut() {
                    a.text.push_str(&String::from_utf8_lossy(&t));
                }
            }
            Event::End(e) => match e.name().as_ref() {
                b"DataArray" => {
                    if let Some(a) = array.take() {
                        match (section.as_str(), a.name.as_str()) {
                            ("Points", _) if points.is_none() => points = Some(numbers(&a, &enc, appended, name)?),
                            ("Cells", "connectivity") => connectivity = Some(numbers(&a, &enc, appended, name)?),
                            ("Cells", "offsets") => offsets = Some(numbers(&a, &enc, appended, name)?),
                            ("Cells", "types") => types = Some(numbers(&a, &enc, appended, name)?),
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
pub(super) mod tests {
    use super::super::tests::no_panic_on_mutations;
    use super::*;

    pub(in crate::read) const TWO_TETS: &str = r#"<?xml version="1.0"?>
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
        assert!(e.unwrap_err().to_string().contains("no AppendedData"));
    }

    /// Two tets with every array appended as raw binary (32-bit headers,
    /// uncompressed), as VTK writes them.
    fn appended_raw() -> Vec<u8> {
        let mut data = Vec::new();
        let mut arrays = String::new();
        let mut add = |tag: &str, bytes: Vec<u8>| {
            arrays += &format!("<DataArray {tag} format=\"appended\" offset=\"{}\"/>\n", data.len());
            data.extend((bytes.len() as u32).to_le_bytes());
            data.extend(bytes);
        };
        let points: Vec<f64> = vec![0., 0., 0., 1., 0., 0., 0., 1., 0., 0., 0., 1., 1., 1., 1.];
        add("type=\"Float64\" NumberOfComponents=\"3\"", points.iter().flat_map(|x| x.to_le_bytes()).collect());
        let ids = |v: &[i64]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
        add("type=\"Int64\" Name=\"connectivity\"", ids(&[0, 1, 2, 3, 1, 2, 3, 4]));
        add("type=\"Int64\" Name=\"offsets\"", ids(&[4, 8]));
        add("type=\"UInt8\" Name=\"types\"", vec![10, 10]);
        let (points, cells) = arrays.split_at(arrays.find("<DataArray type=\"Int64\"").unwrap());
        let mut file = format!(
            "<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" byte_order=\"LittleEndian\">\n\
             <UnstructuredGrid><Piece NumberOfPoints=\"5\" NumberOfCells=\"2\">\n\
             <Points>{points}</Points><Cells>{cells}</Cells></Piece></UnstructuredGrid>\n\
             <AppendedData encoding=\"raw\">\n_"
        )
        .into_bytes();
        file.extend(data);
        file.extend(b"\n</AppendedData>\n</VTKFile>\n");
        file
    }

    #[test]
    fn appended_raw_data_is_read_and_no_mutation_panics() {
        let file = appended_raw();
        assert_eq!(parse_vtu(&file, "a.vtu").unwrap().tets, vec![[0, 1, 2, 3], [1, 2, 3, 4]]);
        for cut in 0..file.len() {
            let _ = parse_vtu(&file[..cut], "cut.vtu");
        }
        for i in 0..file.len() {
            for x in [0u8, 1, 0x7f, 0xff, b'<', b'_'] {
                let mut m = file.clone();
                m[i] = x;
                let _ = parse_vtu(&m, "flip.vtu");
            }
        }
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
