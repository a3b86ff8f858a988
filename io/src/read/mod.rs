//! Reading tet meshes, surfaces, site files and particle trajectories,
//! and writing them back.
//!
//! [`read_mesh`], [`read_surface`] and [`read_sites`] choose the format by
//! the file's extension, from the tables in [`formats`] (the list of
//! formats, the variants each reads, and how to add one).
//! [`read_sites_part`] reads one part of a sites file, only its bytes,
//! for runs of several processes none of which reads the whole file.
//! [`open_particles`] opens a trajectory (LAMMPS dump or extended XYZ) the
//! same way, as a [`FrameReader`] giving one [`ParticleFrame`] (positions,
//! cell, ids, radii) at a time, so that a file of any length is read in
//! the memory of one frame.
//!
//! A bad file is reported as [`Error::Parse`] naming its line and what was
//! expected there; no input makes a reader panic, and counts read from a
//! file only reserve as much memory as the file could actually fill.

mod binary;
mod extxyz;
pub mod formats;
mod gmsh;
mod gmsh_binary;
mod lammps_dump;
mod lex;
mod medit;
mod meshb;
mod npy;
mod particles;
mod parts;
mod surface;
mod tet;
mod tetgen;
mod vtk;
mod vtu;
mod xyz;

#[cfg(test)]
mod fuzz;

pub use extxyz::ExtxyzReader;
pub use gmsh::parse_gmsh;
pub use gmsh_binary::parse_gmsh_binary;
pub use lammps_dump::LammpsDumpReader;
pub use medit::parse_medit;
pub use meshb::parse_meshb;
pub use npy::{parse_npy, write_sites_npy};
pub use particles::{open_particles, FramePart, FrameReader, ParticleFrame};
pub use parts::{read_sites_part, read_values_part, CountLine, SitesPart, SitesPartSummary};
pub use surface::{parse_obj, parse_off, parse_ply, parse_stl, read_surface};
pub use tet::parse_tet;
pub use tetgen::parse_tetgen;
pub use vtk::parse_vtk;
pub use vtu::parse_vtu;
pub use xyz::{parse_values, parse_xyz};

use crate::numbers::Dec;
use cvd::error::{Error, Result};
use cvd::geom::mesh::{signed_volume, TetMesh};
use lex::parse_error;
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::Path;

/// Reads a tet mesh, choosing the format by the extension (any case) from
/// [`formats::MESHES`]; an extension no row names is an
/// [`Error::InvalidInput`] listing them.
pub fn read_mesh(path: &Path) -> Result<TetMesh> {
    formats::read(formats::MESHES, "mesh", path)
}

/// Reads sites, choosing the format by the extension (any case) from
/// [`formats::SITES`]: `.npy` (NumPy: an (N, 3) array of little-endian
/// float64 or float32, see [`parse_npy`]), anything else `.xyz` (text,
/// parsed on all of rayon's threads, see [`parse_xyz`]).
pub fn read_sites(path: &Path) -> Result<Vec<[f64; 3]>> {
    formats::read(formats::SITES, "sites", path)
}

/// Reads one number per line: see [`parse_values`].
pub fn read_values(path: &Path) -> Result<Vec<f64>> {
    parse_values(&read_text(path)?, &path.display().to_string())
}

/// Writes sites as `.xyz`: a line with the count, then `x y z` per line,
/// each coordinate written so that it reads back exactly (the shortest
/// decimal that parses to the same f64).
pub fn write_sites_xyz(path: &Path, sites: &[[f64; 3]]) -> Result<()> {
    write_file(path, |w| write_sites_xyz_rows(w, sites, Rows::whole(sites.len())))
}

/// Writes the `rows` of a sites `.xyz` that `sites` are (a part of a run in
/// parts; the count line, `rows.total`, with the first part's).
pub fn write_sites_xyz_rows(w: &mut dyn Write, sites: &[[f64; 3]], rows: Rows) -> std::io::Result<()> {
    if rows.first == 0 {
        writeln!(w, "{}", rows.total)?;
    }
    write_rows(w, sites.len(), |i, t| {
        let [x, y, z] = sites[i].map(Dec);
        writeln!(t, "{x} {y} {z}")
    })
}

/// Which rows of a table file a writer writes: from `first` (the header
/// with the rows from 0), of `total` in the file — a whole file, or one
/// part of it in a run in parts, whose parts laid end to end are the file
/// one process writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rows {
    /// The first row's index in the file.
    pub first: u64,
    /// Rows in the whole file.
    pub total: u64,
    /// A periodic box's file (neighbours with shifts) even where this part
    /// holds no face.
    pub periodic: bool,
}

impl Rows {
    /// All `n` rows of a file.
    pub fn whole(n: usize) -> Self {
        Self { first: 0, total: n as u64, periodic: false }
    }
}

/// Writes one value per line (as [`read_values`] reads them back, exactly:
/// the shortest decimal that parses to the same f64).
pub fn write_values(path: &Path, values: &[f64]) -> Result<()> {
    write_file(path, |w| write_values_rows(w, values))
}

/// Writes `values` one per line: a file of values, or one part of it in a
/// run in parts (the parts laid end to end are the whole file).
pub fn write_values_rows(w: &mut dyn Write, values: &[f64]) -> std::io::Result<()> {
    for &v in values {
        writeln!(w, "{}", Dec(v))?;
    }
    Ok(())
}

/// Writes a mesh as Medit ASCII `.mesh` (references 0 for vertices, 1 for
/// tets), coordinates written so that they read back exactly; version 2
/// tells other readers the reals are double precision.
pub fn write_medit(path: &Path, mesh: &TetMesh) -> Result<()> {
    write_file(path, |w| {
        writeln!(w, "MeshVersionFormatted 2\n\nDimension 3\n\nVertices\n{}", mesh.vertices.len())?;
        for [x, y, z] in &mesh.vertices {
            writeln!(w, "{x} {y} {z} 0")?;
        }
        writeln!(w, "\nTetrahedra\n{}", mesh.tets.len())?;
        for [a, b, c, d] in &mesh.tets {
            // u64: a u32 index plus 1 must not wrap.
            let [a, b, c, d] = [a, b, c, d].map(|&v| v as u64 + 1);
            writeln!(w, "{a} {b} {c} {d} 1")?;
        }
        writeln!(w, "\nEnd")
    })
}

/// A file's bytes; errors name the file.
fn read_bytes(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|source| Error::Io { path: path.display().to_string(), source })
}

/// A file's bytes as [`read_bytes`] reads them, a regular file's read by
/// all of rayon's threads at once, in blocks: for a large file in the page
/// cache, the copy and the page faults are most of the time of reading.
fn read_bytes_parallel(path: &Path) -> Result<Vec<u8>> {
    let io = |source| Error::Io { path: path.display().to_string(), source };
    let mut file = std::fs::File::open(path).map_err(io)?;
    let meta = file.metadata().map_err(io)?;
    let Some(len) = usize::try_from(meta.len()).ok().filter(|_| meta.is_file()) else {
        return read_bytes(path);
    };
    cvd::job::memory::check(&format!("reading {} whole", path.display()), len as u64, None)?;
    let mut bytes = vec![0; len];
    read_exact_at(&file, 0, &mut bytes).map_err(io)?;
    // Whatever was appended since the size was taken.
    file.seek(SeekFrom::Start(len as u64)).map_err(io)?;
    file.read_to_end(&mut bytes).map_err(io)?;
    Ok(bytes)
}

/// Fills `buf` with the file's bytes from `offset` on, in blocks read by
/// all of rayon's threads at once (Unix; elsewhere in one read).
fn read_exact_at(file: &std::fs::File, offset: u64, buf: &mut [u8]) -> std::io::Result<()> {
    #[cfg(unix)]
    {
        use rayon::prelude::*;
        use std::os::unix::fs::FileExt;
        const BLOCK: usize = 8 << 20;
        if buf.len() <= BLOCK {
            return file.read_exact_at(buf, offset);
        }
        buf.par_chunks_mut(BLOCK)
            .enumerate()
            .try_for_each(|(i, block)| file.read_exact_at(block, offset + (i * BLOCK) as u64))
    }
    #[cfg(not(unix))]
    {
        let mut file = file;
        file.seek(SeekFrom::Start(offset))?;
        file.read_exact(buf)
    }
}

/// A file's text. Bytes that are not UTF-8 become U+FFFD, so that a
/// binary or Latin-1 file still gets a parse error naming a line.
fn read_text(path: &Path) -> Result<String> {
    let bytes = read_bytes(path)?;
    Ok(String::from_utf8(bytes).unwrap_or_else(|e| String::from_utf8_lossy(e.as_bytes()).into_owned()))
}

/// Writes a file through a buffer; errors name the file.
pub(crate) fn write_file(path: &Path, body: impl FnOnce(&mut dyn Write) -> std::io::Result<()>) -> Result<()> {
    let io = |source| Error::Write { path: path.display().to_string(), source };
    let mut w = std::io::BufWriter::new(std::fs::File::create(path).map_err(io)?);
    body(&mut w).map_err(io)?;
    w.flush().map_err(io)
}

/// Writes rows `0..n` through `w` in order, each row's text made by
/// `row(i, buffer)`, formatted on every core: rows in blocks, a few
/// blocks per core at a time, each into its own buffer (so the memory
/// held is a few blocks' text, not the file's).
pub(crate) fn write_rows(
    w: &mut dyn Write,
    n: usize,
    row: impl Fn(usize, &mut Vec<u8>) -> std::io::Result<()> + Sync,
) -> std::io::Result<()> {
    use rayon::prelude::*;
    const BLOCK: usize = 4096;
    let batch = BLOCK * 4 * rayon::current_num_threads();
    for start in (0..n).step_by(batch) {
        let end = (start + batch).min(n);
        let blocks: Vec<std::io::Result<Vec<u8>>> = (start..end)
            .step_by(BLOCK)
            .collect::<Vec<_>>()
            .into_par_iter()
            .map(|b| {
                let mut text = Vec::with_capacity(BLOCK * 64);
                for i in b..(b + BLOCK).min(end) {
                    row(i, &mut text)?;
                }
                Ok(text)
            })
            .collect();
        for text in blocks {
            w.write_all(&text?)?;
        }
    }
    Ok(())
}

/// Tets as read, 0-based, with the line each came from so that the checks
/// made once all vertices are known can still name it.
#[derive(Default)]
struct TetList {
    tets: Vec<[u32; 4]>,
    lines: Vec<usize>,
}

impl TetList {
    fn with_capacity(n: usize) -> Self {
        Self { tets: Vec::with_capacity(n), lines: Vec::with_capacity(n) }
    }

    fn push(&mut self, tet: [u32; 4], line: usize) {
        self.tets.push(tet);
        self.lines.push(line);
    }
}

/// The mesh, after the checks of [`TetMesh::new`] made here first so that
/// errors name the tet's line (`base`: how the file numbers its vertices).
fn build(path: &str, vertices: Vec<[f64; 3]>, list: TetList, base: u32, end_line: usize) -> Result<TetMesh> {
    if list.tets.is_empty() {
        return Err(parse_error(path, end_line, "expected tetrahedra, found none (a surface mesh?)"));
    }
    let n = vertices.len();
    let base = base as u64;
    for (t, (tet, &line)) in list.tets.iter().zip(&list.lines).enumerate() {
        let numbers = || tet.map(|v| v as u64 + base);
        if let Some(&v) = tet.iter().find(|&&v| v as usize >= n) {
            let has = match n {
                0 => "no vertices".to_string(),
                _ => format!("{n} vertices, numbered {base} to {}", n as u64 - 1 + base),
            };
            let message =
                format!("tet {} {:?} refers to vertex {}, but the file has {has}", t + 1, numbers(), v as u64 + base);
            return Err(parse_error(path, line, message));
        }
        let [a, b, c, d] = tet.map(|v| vertices[v as usize]);
        if signed_volume(a, b, c, d) == 0.0 {
            let message = format!("tet {} {:?} has zero volume", t + 1, numbers());
            return Err(parse_error(path, line, message));
        }
    }
    TetMesh::new(vertices, list.tets)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;
    use std::time::Instant;

    /// A fresh path in the temporary directory.
    pub(super) fn temp_path(name: &str) -> PathBuf {
        std::env::temp_dir().join(format!("cvd-io-{}-{name}", std::process::id()))
    }

    /// The parse error's line and message, or a panic naming what came.
    pub(super) fn parse_err<T: std::fmt::Debug>(r: Result<T>) -> (usize, String) {
        match r {
            Err(Error::Parse { line, message, .. }) => (line, message),
            other => panic!("expected a parse error, got {other:?}"),
        }
    }

    /// Parses every prefix of `text`, the text with each token replaced by
    /// hostile values, and with each line removed or doubled: a fuzz-like
    /// check that nothing panics (the results are not looked at).
    pub(super) fn no_panic_on_mutations<T>(text: &str, parse: impl Fn(&str) -> Result<T>) {
        for (cut, _) in text.char_indices() {
            let _ = parse(&text[..cut]);
        }
        const HOSTILE: &[&str] = &[
            "",
            "0",
            "-1",
            "nan",
            "inf",
            "1e40",
            "1e300",
            "1e400",
            "0.5",
            "4294967296",
            "1000000000000",
            "18446744073709551616",
            "#",
            "x",
            "End",
            "Vertices",
            "$EndNodes",
            "$Nodes",
            "\u{fffd}",
        ];
        let mut at = 0;
        while let Some(start) = text[at..].find(|c: char| !c.is_ascii_whitespace()).map(|s| at + s) {
            let end = text[start..].find(|c: char| c.is_ascii_whitespace()).map_or(text.len(), |e| start + e);
            for h in HOSTILE {
                let _ = parse(&format!("{}{h}{}", &text[..start], &text[end..]));
            }
            at = end;
        }
        let lines: Vec<&str> = text.lines().collect();
        for i in 0..lines.len() {
            let mut without = lines.clone();
            without.remove(i);
            let _ = parse(&without.join("\n"));
            let mut doubled = lines.clone();
            doubled.insert(i, lines[i]);
            let _ = parse(&doubled.join("\n"));
        }
    }

    /// Two tets sharing the face 1 2 3 (1-based), volume 1/3 in all.
    pub(super) fn two_tets() -> TetMesh {
        let vertices = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 1.0, 1.0]];
        TetMesh::new(vertices, vec![[0, 1, 2, 3], [1, 2, 3, 4]]).unwrap()
    }

    /// A file of the shared models folder (`$CVD_MODELS` or
    /// `../shared/models` beside the workspace), or None with a message.
    fn model(name: &str) -> Option<PathBuf> {
        let dir = std::env::var_os("CVD_MODELS").map(PathBuf::from).unwrap_or_else(|| {
            Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join("..").join("shared").join("models")
        });
        let path = dir.join(name);
        if path.exists() {
            Some(path)
        } else {
            eprintln!("skipped: {} is absent", path.display());
            None
        }
    }

    fn check_model(name: &str, vertices: usize, tets: usize, volume: f64) {
        let Some(path) = model(name) else { return };
        let start = Instant::now();
        let mesh = read_mesh(&path).unwrap();
        eprintln!("{name}: read in {:.1} ms", start.elapsed().as_secs_f64() * 1e3);
        assert_eq!((mesh.vertices.len(), mesh.tets.len()), (vertices, tets));
        let v = mesh.volume();
        assert!((v - volume).abs() <= 1e-5 * volume, "{name}: volume {v}, expected {volume}");
    }

    #[test]
    fn reads_joint_31k_mesh() {
        check_model("joint_31k.mesh", 7265, 32730, 0.359608);
    }

    #[test]
    fn reads_torus_8k_mesh() {
        check_model("torus_8k.mesh", 2165, 8523, 0.142325);
    }

    #[test]
    fn reads_paper_joint_tet() {
        check_model("paper_joint.tet", 7369, 31349, 0.501127);
    }

    #[test]
    fn reads_the_other_models() {
        check_model("bunny_10k.mesh", 2452, 9478, 0.199478);
        check_model("fandisk_26k.mesh", 5515, 26018, 0.140657);
        check_model("joint_100k.mesh", 21404, 105279, 0.359658);
    }

    #[test]
    fn reads_paper_joint_sites() {
        let Some(path) = model("paper_joint_3000.xyz") else {
            return;
        };
        let sites = read_sites(&path).unwrap();
        assert_eq!(sites.len(), 3000);
        assert_eq!(sites[0], [0.368190565, 0.311753023, -0.155509743]);
    }

    #[test]
    fn medit_round_trip_through_files() {
        let mesh = two_tets();
        let path = temp_path("round_trip.mesh");
        write_medit(&path, &mesh).unwrap();
        let back = read_mesh(&path);
        std::fs::remove_file(&path).unwrap();
        assert_eq!(back.unwrap(), mesh);
    }

    #[test]
    fn sites_round_trip_exactly() {
        let sites = vec![
            [0.1, -2.5e-7, 3.0e300],
            [f64::MIN_POSITIVE, 1.0 / 3.0, -0.0],
            [123456.79, 5e-324, 7.0],
            // UTM-like coordinates keep every digit.
            [1000000.0145585263, 4649776.224345621, 0.30000000000000004],
        ];
        let path = temp_path("round_trip.xyz");
        write_sites_xyz(&path, &sites).unwrap();
        let back = read_sites(&path);
        std::fs::remove_file(&path).unwrap();
        assert_eq!(back.unwrap(), sites);
    }

    #[test]
    fn large_site_files_read_in_blocks_as_in_one_read() {
        // Over 8 MiB: read in blocks by several threads.
        let sites: Vec<[f64; 3]> =
            (0..200_000).map(|i| [i as f64 / 3.0, (i as f64).sqrt() * 1e-7, -(i as f64) * 1e5 / 7.0]).collect();
        let path = temp_path("large.xyz");
        write_sites_xyz(&path, &sites).unwrap();
        let bytes = read_bytes_parallel(&path).unwrap();
        assert!(bytes.len() > 8 << 20, "{} bytes", bytes.len());
        assert!(bytes == std::fs::read(&path).unwrap());
        let back = read_sites(&path).unwrap();
        assert!(back.iter().zip(&sites).all(|(a, b)| a.map(f64::to_bits) == b.map(f64::to_bits)));
        assert_eq!(back.len(), sites.len());
        // An error far into the file names its line (point i on line i + 1).
        let mut text = String::from_utf8(bytes).unwrap();
        let at = text.match_indices('\n').nth(150_000).unwrap().0 + 1;
        text.insert_str(at, "0 0\n");
        std::fs::write(&path, &text).unwrap();
        let (line, m) = parse_err(read_sites(&path));
        assert_eq!((line, m.as_str()), (150_002, "expected 3 coordinates x y z for point 150001, found 2 values"));
        // .npy by the extension, any case.
        let npy = temp_path("large.NPY");
        write_sites_npy(&npy, &sites).unwrap();
        let from_npy = read_sites(&npy);
        std::fs::remove_file(&path).unwrap();
        std::fs::remove_file(&npy).unwrap();
        assert!(from_npy.unwrap().iter().zip(&sites).all(|(a, b)| a.map(f64::to_bits) == b.map(f64::to_bits)));
    }

    #[test]
    fn tetgen_is_read_from_either_file() {
        let (node, ele) = (temp_path("pair.node"), temp_path("pair.ele"));
        std::fs::write(&node, "5 3 0 0\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n5 1 1 1\n").unwrap();
        std::fs::write(&ele, "2 4 0\n1 1 2 3 4\n2 2 3 4 5\n").unwrap();
        let (a, b) = (read_mesh(&node), read_mesh(&ele));
        std::fs::remove_file(&node).unwrap();
        std::fs::remove_file(&ele).unwrap();
        assert_eq!(a.unwrap(), two_tets());
        assert_eq!(b.unwrap(), two_tets());
    }

    #[test]
    fn missing_files_and_unknown_extensions() {
        let missing = temp_path("missing.mesh");
        assert!(matches!(read_mesh(&missing), Err(Error::Io { path, .. }) if path.contains("missing.mesh")));
        let e = read_mesh(Path::new("x.obj")).unwrap_err().to_string();
        assert!(matches!(read_mesh(Path::new("x.obj")), Err(Error::InvalidInput(_))));
        assert!(e.contains("x.obj") && e.contains(".mesh") && e.contains(".msh") && e.contains(".node"), "{e}");
    }

    #[test]
    fn binary_garbage_is_a_parse_error() {
        let path = temp_path("garbage.mesh");
        std::fs::write(&path, [0xff, 0xfe, 0x00, 0x9f, b'\n', 0x80]).unwrap();
        let r = read_mesh(&path);
        std::fs::remove_file(&path).unwrap();
        assert_eq!(parse_err(r).0, 1);
    }

    #[test]
    fn bad_tets_name_their_line() {
        let list = |tets: &[[u32; 4]]| TetList { tets: tets.to_vec(), lines: (10..10 + tets.len()).collect() };
        let v = two_tets().vertices;
        let (line, m) = parse_err(build("f", v.clone(), list(&[[0, 1, 2, 3], [0, 1, 2, 5]]), 1, 99));
        assert_eq!(
            (line, m.as_str()),
            (11, "tet 2 [1, 2, 3, 6] refers to vertex 6, but the file has 5 vertices, numbered 1 to 5")
        );
        let (line, m) = parse_err(build("f", v.clone(), list(&[[0, 1, 2, 2]]), 0, 99));
        assert_eq!((line, m.as_str()), (10, "tet 1 [0, 1, 2, 2] has zero volume"));
        let (line, m) = parse_err(build("f", vec![], list(&[[0, 1, 2, 3]]), 0, 99));
        assert_eq!((line, m.contains("the file has no vertices")), (10, true));
        assert_eq!(parse_err(build("f", v, TetList::default(), 0, 99)).0, 99);
    }
}
