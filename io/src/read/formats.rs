//! The input formats, one table per kind of input: [`MESHES`],
//! [`SURFACES`], [`SITES`] and [`PARTICLES`]. Each row gives a format's
//! extensions, its name, a note on the variants read, and its reader
//! (for particles, which are read frame by frame, the opening of a
//! reader).
//!
//! The tables drive everything that lists the formats: [`read_mesh`],
//! [`read_surface`], [`read_sites`] and [`open_particles`] choose the row
//! by the file's extension (any case); the error for an unknown extension
//! lists the table; [`help`] (and [`mesh_help`], [`surface_help`],
//! [`sites_help`], [`particles_help`]) gives the same list for the command
//! line's help; [`extensions`] lists
//! a table's extensions. Adding a reader is one file in `io/src/read/`
//! plus one row here (and a sample in this file's tests, which check that
//! every row reads one). `docs/FORMATS.md` describes the formats for users.
//!
//! ```
//! use cvd_io::formats::{extensions, mesh_help, SURFACES};
//!
//! assert!(mesh_help().contains(".node/.ele (TetGen"));
//! assert_eq!(extensions(SURFACES).collect::<Vec<_>>(), ["stl", "obj", "off", "ply"]);
//! ```
//!
//! [`read_mesh`]: super::read_mesh
//! [`read_surface`]: super::read_surface
//! [`read_sites`]: super::read_sites
//! [`open_particles`]: super::open_particles

use super::surface::text;
use super::{gmsh, npy, tetgen, xyz};
use super::{parse_medit, parse_meshb, parse_obj, parse_off, parse_ply, parse_stl, parse_tet, parse_vtk, parse_vtu};
use super::{read_bytes, read_bytes_parallel, read_text};
use super::{ExtxyzReader, FrameReader, LammpsDumpReader};
use cvd::error::{Error, Result};
use cvd::geom::mesh::TetMesh;
use cvd::geom::surface::TriSurface;
use std::fmt::Write;
use std::path::Path;

/// One input format: a row of [`MESHES`], [`SURFACES`], [`SITES`] or
/// [`PARTICLES`].
pub struct Format<T> {
    /// The extensions that choose it, lowercase and without the dot (they
    /// match in any case). TetGen's `.node` and `.ele` are one format: a
    /// mesh is read from both files, whichever is given.
    pub extensions: &'static [&'static str],
    /// What the format is called, e.g. "Medit ASCII".
    pub name: &'static str,
    /// The variants read, e.g. "versions 2.2 and 4.1, ASCII or binary"
    /// (may be empty).
    pub detail: &'static str,
    /// Whether this format also reads files of any extension no row names
    /// (only `.xyz`, in [`SITES`]); a table with no such row refuses them.
    pub fallback: bool,
    read: fn(&Path) -> Result<T>,
}

impl<T> Format<T> {
    /// Reads `path` with this format's reader.
    pub fn read(&self, path: &Path) -> Result<T> {
        (self.read)(path)
    }

    /// Whether `extension` (without the dot, any case) is one of this
    /// format's.
    pub fn matches(&self, extension: &str) -> bool {
        self.extensions.iter().any(|e| e.eq_ignore_ascii_case(extension))
    }
}

/// A file's name, for errors.
fn name(path: &Path) -> String {
    path.display().to_string()
}

/// Tet meshes ([`read_mesh`](super::read_mesh)).
pub const MESHES: &[Format<TetMesh>] = &[
    Format {
        extensions: &["mesh"],
        name: "Medit ASCII",
        detail: "",
        fallback: false,
        read: |path| parse_medit(&read_text(path)?, &name(path)),
    },
    Format {
        extensions: &["node", "ele"],
        name: "TetGen",
        detail: "both files are read",
        fallback: false,
        read: tetgen::read_pair,
    },
    Format {
        extensions: &["tet"],
        name: "the paper's code",
        detail: "",
        fallback: false,
        read: |path| parse_tet(&read_text(path)?, &name(path)),
    },
    Format {
        extensions: &["msh"],
        name: "Gmsh",
        detail: "versions 2.2 and 4.1, ASCII or binary",
        fallback: false,
        read: gmsh::read_msh,
    },
    Format {
        extensions: &["vtk"],
        name: "legacy VTK",
        detail: "versions 2 to 5.1, ASCII or binary",
        fallback: false,
        read: |path| parse_vtk(&read_bytes(path)?, &name(path)),
    },
    Format {
        extensions: &["vtu"],
        name: "VTK XML",
        detail: "inline or appended, ASCII, base64 or raw, zlib or uncompressed",
        fallback: false,
        read: |path| parse_vtu(&read_bytes(path)?, &name(path)),
    },
    Format {
        extensions: &["meshb"],
        name: "Medit binary",
        detail: "versions 1 to 4",
        fallback: false,
        read: |path| parse_meshb(&read_bytes(path)?, &name(path)),
    },
];

/// Triangle surfaces ([`read_surface`](super::read_surface)), in the order
/// the command line looks for a model's surface.
pub const SURFACES: &[Format<TriSurface>] = &[
    Format {
        extensions: &["stl"],
        name: "STL",
        detail: "binary or ASCII",
        fallback: false,
        read: |path| parse_stl(&read_bytes(path)?, &name(path)),
    },
    Format {
        extensions: &["obj"],
        name: "Wavefront OBJ",
        detail: "",
        fallback: false,
        read: |path| parse_obj(&read_bytes(path)?, &name(path)),
    },
    Format {
        extensions: &["off"],
        name: "OFF",
        detail: "",
        fallback: false,
        read: |path| {
            let (bytes, name) = (read_bytes(path)?, name(path));
            parse_off(text(&bytes, &name)?, &name)
        },
    },
    Format {
        extensions: &["ply"],
        name: "PLY",
        detail: "binary or ASCII",
        fallback: false,
        read: |path| parse_ply(&read_bytes(path)?, &name(path)),
    },
];

/// Sites ([`read_sites`](super::read_sites)): `.npy`, and `.xyz` for any
/// other extension.
pub const SITES: &[Format<Vec<[f64; 3]>>] = &[
    Format {
        extensions: &["npy"],
        name: "NumPy",
        detail: "an (N, 3) array of float64 or float32",
        fallback: false,
        read: npy::read_npy,
    },
    Format {
        extensions: &["xyz"],
        name: "text",
        detail: "x y z per line, optional count line",
        fallback: true,
        read: |path| xyz::parse_xyz_bytes(&read_bytes_parallel(path)?, &name(path)),
    },
];

/// Particle trajectories ([`open_particles`](super::open_particles)),
/// read frame by frame: a row opens a reader of the file's frames.
pub const PARTICLES: &[Format<Box<dyn FrameReader>>] = &[
    Format {
        extensions: &["dump", "lammpstrj"],
        name: "LAMMPS text dump",
        detail: "also files named dump.*; orthogonal, triclinic or general triclinic boxes; x, xu, xs or xsu columns",
        fallback: false,
        read: |path| Ok(Box::new(LammpsDumpReader::open(path)?)),
    },
    Format {
        extensions: &["extxyz"],
        name: "extended XYZ",
        detail: "Lattice, pbc and Properties as ASE writes them",
        fallback: false,
        read: |path| Ok(Box::new(ExtxyzReader::open(path)?)),
    },
];

/// The row of [`PARTICLES`] that reads `path`: by its extension as
/// [`find`] does, else the LAMMPS dump's for a file named `dump.*` (any
/// case; LAMMPS's examples name their dumps so, e.g. `dump.lj`).
pub fn find_particles(path: &Path) -> Option<&'static Format<Box<dyn FrameReader>>> {
    find(PARTICLES, path).or_else(|| {
        let name = path.file_name()?.to_str()?;
        let dump = name.get(..5).is_some_and(|p| p.eq_ignore_ascii_case("dump.")) && name.len() > 5;
        dump.then_some(&PARTICLES[0])
    })
}

/// The row of `formats` that reads `path`: the one naming its extension
/// (any case), else the fallback row if there is one.
pub fn find<'a, T>(formats: &'a [Format<T>], path: &Path) -> Option<&'a Format<T>> {
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
    formats.iter().find(|f| f.matches(ext)).or_else(|| formats.iter().find(|f| f.fallback))
}

/// Reads `path` with the row [`find`] gives, or fails with
/// [`unknown`]'s error (`kind`: "mesh", "surface").
pub(super) fn read<T>(formats: &[Format<T>], kind: &str, path: &Path) -> Result<T> {
    match find(formats, path) {
        Some(format) => format.read(path),
        None => Err(unknown(formats, kind, path)),
    }
}

/// The error for a file no row of `formats` reads: "NAME: unknown KIND
/// format; supported extensions: " and the table as [`help`] lists it.
pub(super) fn unknown<T>(formats: &[Format<T>], kind: &str, path: &Path) -> Error {
    Error::InvalidInput(format!("{}: unknown {kind} format; supported extensions: {}", name(path), help(formats)))
}

/// The formats as one line, for help texts and errors: each row's
/// extensions, then its name and detail in parentheses, e.g.
/// `.mesh (Medit ASCII), .node/.ele (TetGen, both files are read), ...`;
/// a fallback row says "or any other extension".
pub fn help<T>(formats: &[Format<T>]) -> String {
    let mut out = String::new();
    for (i, f) in formats.iter().enumerate() {
        if i > 0 {
            out += ", ";
        }
        for (k, e) in f.extensions.iter().enumerate() {
            out += if k > 0 { "/." } else { "." };
            out += e;
        }
        if f.fallback {
            out += " or any other extension";
        }
        let _ = match f.detail {
            "" => write!(out, " ({})", f.name),
            detail => write!(out, " ({}, {detail})", f.name),
        };
    }
    out
}

/// A table's extensions, lowercase and without the dot, in the table's
/// order (e.g. `extensions(SURFACES)`: stl, obj, off, ply).
pub fn extensions<T>(formats: &'static [Format<T>]) -> impl Iterator<Item = &'static str> {
    formats.iter().flat_map(|f| f.extensions.iter().copied())
}

/// [`help`] of [`MESHES`].
pub fn mesh_help() -> String {
    help(MESHES)
}

/// [`help`] of [`SURFACES`].
pub fn surface_help() -> String {
    help(SURFACES)
}

/// [`help`] of [`SITES`].
pub fn sites_help() -> String {
    help(SITES)
}

/// [`help`] of [`PARTICLES`].
pub fn particles_help() -> String {
    help(PARTICLES)
}

#[cfg(test)]
mod tests {
    use super::super::tests::{temp_path, two_tets};
    use super::super::{extxyz, lammps_dump};
    use super::super::{gmsh, gmsh_binary, medit, meshb, surface, tet, tetgen, vtk, vtu};
    use super::super::{open_particles, read_mesh, read_sites, read_surface, write_sites_npy};
    use super::*;
    use std::collections::HashSet;

    type Row = (&'static [&'static str], &'static str, bool);

    /// A table's rows: extensions, name, fallback.
    fn rows<T>(formats: &[Format<T>]) -> Vec<Row> {
        formats.iter().map(|f| (f.extensions, f.name, f.fallback)).collect()
    }

    /// Each table's rows, by the table's name.
    fn tables() -> [(&'static str, Vec<Row>); 4] {
        [("meshes", rows(MESHES)), ("surfaces", rows(SURFACES)), ("sites", rows(SITES)), ("particles", rows(PARTICLES))]
    }

    #[test]
    fn extensions_are_lowercase_and_unique() {
        for (table, rows) in tables() {
            let mut seen = HashSet::new();
            for (exts, name, _) in &rows {
                assert!(!name.is_empty(), "{table}: a row without a name");
                assert!(!exts.is_empty(), "{table}: {name} has no extension");
                for e in *exts {
                    let ok = !e.is_empty() && e.bytes().all(|b| b.is_ascii_lowercase() || b.is_ascii_digit());
                    assert!(ok, "{table}: {name}'s extension {e:?} is not lowercase letters and digits");
                    assert!(seen.insert(*e), "{table}: .{e} is in two rows");
                }
            }
            // Unknown extensions are refused by name, except sites' `.xyz`.
            let fallbacks: Vec<_> = rows.iter().filter(|r| r.2).map(|r| r.0).collect();
            let expected: &[&[&str]] = if table == "sites" { &[&["xyz"]] } else { &[] };
            assert_eq!(fallbacks, expected, "{table}");
        }
    }

    #[test]
    fn dispatch_ignores_case() {
        fn check<T>(formats: &[Format<T>]) {
            for (i, f) in formats.iter().enumerate() {
                for e in f.extensions {
                    let mixed: String = e
                        .chars()
                        .enumerate()
                        .map(|(k, c)| if k % 2 == 0 { c.to_ascii_uppercase() } else { c })
                        .collect();
                    for ext in [e.to_string(), e.to_ascii_uppercase(), mixed] {
                        let found = find(formats, Path::new(&format!("dir.x/a.b.{ext}")));
                        assert!(found.is_some_and(|g| std::ptr::eq(g, &formats[i])), ".{ext} is not {}", f.name);
                    }
                }
            }
            let fallback = formats.iter().position(|f| f.fallback);
            for path in ["x", "x.", "x.unknown", "x.mesh.gz", ".mesh"] {
                let found = find(formats, Path::new(path)).map(|g| formats.iter().position(|f| std::ptr::eq(f, g)));
                assert_eq!(found, fallback.map(Some), "{path}");
            }
        }
        check(MESHES);
        check(SURFACES);
        check(SITES);
        check(PARTICLES);
        // Particles: files named dump.* are LAMMPS dumps, whatever their
        // extension; other names are not.
        for name in ["dump.lj", "dir/DUMP.melt", "dump.1000.txt", "dump.xyz", "a/dump.dump"] {
            assert!(find_particles(Path::new(name)).is_some_and(|f| std::ptr::eq(f, &PARTICLES[0])), "{name}");
        }
        assert!(find_particles(Path::new("run.EXTXYZ")).is_some_and(|f| std::ptr::eq(f, &PARTICLES[1])));
        for name in ["dump.", "dump", "mydump.lj", "dump_lj", "dir.dump/x.lj", "x.xyz"] {
            assert!(find_particles(Path::new(name)).is_none(), "{name}");
        }
        // Files read in any case, TetGen's sibling in the given one's.
        let (mesh, node, ele) = (temp_path("case.MeSh"), temp_path("case.NODE"), temp_path("case.ELE"));
        std::fs::write(&mesh, medit::tests::VALID).unwrap();
        std::fs::write(&node, tetgen::tests::NODE).unwrap();
        std::fs::write(&ele, tetgen::tests::ELE).unwrap();
        let read = [read_mesh(&mesh), read_mesh(&node), read_mesh(&ele)];
        [mesh, node, ele].iter().for_each(|p| std::fs::remove_file(p).unwrap());
        for r in read {
            assert_eq!(r.unwrap(), two_tets());
        }
    }

    #[test]
    fn unknown_extensions_are_errors_naming_every_row() {
        let names = |table: &[Row], e: &str| {
            for (exts, name, _) in table {
                assert!(e.contains(name), "{e}: no {name}");
                exts.iter().for_each(|x| assert!(e.contains(&format!(".{x}")), "{e}: no .{x}"));
            }
        };
        let tables = tables();
        let e = read_mesh(Path::new("missing/x.obj"));
        let prefix =
            "missing/x.obj: unknown mesh format; supported extensions: .mesh (Medit ASCII), .node/.ele (TetGen";
        assert!(matches!(&e, Err(Error::InvalidInput(m)) if m.starts_with(prefix)), "{e:?}");
        names(&tables[0].1, &e.unwrap_err().to_string());
        // A surface is read before its extension is looked at, as ever:
        // a missing file is an I/O error, an existing one an unknown format.
        assert!(matches!(read_surface(&temp_path("missing.xyz")), Err(Error::Io { .. })));
        let path = temp_path("surface.mesh");
        std::fs::write(&path, medit::tests::VALID).unwrap();
        let e = read_surface(&path);
        std::fs::remove_file(&path).unwrap();
        let prefix = format!("{}: unknown surface format; supported extensions: .stl (STL", path.display());
        assert!(matches!(&e, Err(Error::InvalidInput(m)) if m.starts_with(&prefix)), "{e:?}");
        names(&tables[1].1, &e.unwrap_err().to_string());
        // Sites have no unknown extension: anything else is `.xyz`.
        let path = temp_path("sites.MESH");
        std::fs::write(&path, "2\n0 0 0\n1 2 3\n").unwrap();
        let read = read_sites(&path);
        std::fs::remove_file(&path).unwrap();
        assert_eq!(read.unwrap(), [[0.0; 3], [1.0, 2.0, 3.0]]);
        // Particles: refused before the file is opened.
        let e = open_particles(Path::new("missing/run.xyz")).err().unwrap();
        let prefix = "missing/run.xyz: unknown particle format; supported extensions: .dump/.lammpstrj (LAMMPS";
        assert!(matches!(&e, Error::InvalidInput(m) if m.starts_with(prefix)), "{e:?}");
        names(&tables[3].1, &e.to_string());
    }

    #[test]
    fn help_names_every_extension() {
        let helps = [mesh_help(), surface_help(), sites_help(), particles_help()];
        for (help, (table, rows)) in helps.into_iter().zip(tables()) {
            for (exts, name, _) in rows {
                assert!(help.contains(name), "{table}: {help}");
                exts.iter().for_each(|e| assert!(help.contains(&format!(".{e}")), "{table}: {help}"));
            }
        }
        assert!(mesh_help().starts_with(".mesh (Medit ASCII), .node/.ele (TetGen, both files are read), "));
        assert!(sites_help().ends_with(".xyz or any other extension (text, x y z per line, optional count line)"));
        let all: Vec<_> = extensions(MESHES).collect();
        assert_eq!(all, ["mesh", "node", "ele", "tet", "msh", "vtk", "vtu", "meshb"]);
        assert_eq!(extensions(SURFACES).collect::<Vec<_>>(), ["stl", "obj", "off", "ply"]);
        assert_eq!(extensions(SITES).collect::<Vec<_>>(), ["npy", "xyz"]);
        assert_eq!(extensions(PARTICLES).collect::<Vec<_>>(), ["dump", "lammpstrj", "extxyz"]);
        assert!(particles_help().starts_with(".dump/.lammpstrj (LAMMPS text dump, also files named dump.*; "));
    }

    /// Writes `files` (name suffix, contents) to the temporary directory,
    /// reads the first with `read`, removes them.
    fn read_files<T>(tag: &str, files: &[(&str, &[u8])], read: impl Fn(&Path) -> Result<T>) -> Result<T> {
        let paths: Vec<_> = files.iter().map(|(ext, _)| temp_path(&format!("{tag}.{ext}"))).collect();
        for (p, (_, bytes)) in paths.iter().zip(files) {
            std::fs::write(p, bytes).unwrap();
        }
        let r = read(&paths[0]);
        paths.iter().for_each(|p| std::fs::remove_file(p).unwrap());
        r
    }

    #[test]
    fn every_mesh_row_reads_a_valid_file() {
        let text = |s: &str| s.as_bytes().to_vec();
        // The files of each sample (extension, contents): the first is read.
        let mut samples: Vec<Vec<(&str, Vec<u8>)>> = vec![
            vec![("mesh", text(medit::tests::VALID))],
            vec![("node", text(tetgen::tests::NODE)), ("ele", text(tetgen::tests::ELE))],
            vec![("ele", text(tetgen::tests::ELE)), ("node", text(tetgen::tests::NODE))],
            vec![("tet", text(tet::tests::VALID))],
            vec![("msh", text(gmsh::tests::V22))],
            vec![("msh", text(gmsh::tests::V41))],
            vec![("msh", gmsh_binary::tests::two_tets())],
            vec![("vtk", text(vtk::tests::TWO_TETS))],
            vec![("vtu", text(vtu::tests::TWO_TETS))],
        ];
        samples.extend((1..=4).map(|version| vec![("meshb", meshb::tests::two_tets(version))]));
        for (i, files) in samples.iter().enumerate() {
            let ext = files[0].0;
            let files: Vec<(&str, &[u8])> = files.iter().map(|(e, b)| (*e, b.as_slice())).collect();
            let read = read_files(&format!("row{i}"), &files, read_mesh).unwrap_or_else(|e| panic!(".{ext}: {e}"));
            assert_eq!(read, two_tets(), "sample {i}, .{ext}");
        }
        for f in MESHES {
            let sampled = |e: &&str| samples.iter().any(|files| files[0].0 == *e);
            assert!(f.extensions.iter().all(sampled), "no sample of {}", f.name);
        }
    }

    #[test]
    fn every_surface_and_sites_row_reads_a_valid_file() {
        let s = TriSurface::cuboid([0.0; 3], [1.0, 2.0, 3.0]);
        let samples: Vec<(&str, Vec<u8>)> = vec![
            ("stl", surface::tests::as_stl(&s, true)),
            ("stl", surface::tests::as_stl(&s, false)),
            ("obj", surface::tests::as_obj(&s).into_bytes()),
            ("off", surface::tests::as_off(&s).into_bytes()),
            ("ply", surface::tests::as_ply_ascii(&s).into_bytes()),
            ("ply", surface::tests::as_ply_binary(&s)),
        ];
        for (i, (ext, bytes)) in samples.iter().enumerate() {
            let read = read_files(&format!("surface{i}"), &[(ext, bytes)], read_surface);
            let read = read.unwrap_or_else(|e| panic!(".{ext}: {e}"));
            assert_eq!((read.vertices.len(), read.triangles.len()), (8, 12), ".{ext}");
        }
        for f in SURFACES {
            assert!(f.extensions.iter().all(|e| samples.iter().any(|s| s.0 == *e)), "no sample of {}", f.name);
        }

        let sites = vec![[0.5, -1.0, 3.25], [1e6, 2.0, -0.0]];
        let npy = temp_path("row.npy");
        write_sites_npy(&npy, &sites).unwrap();
        let bytes = std::fs::read(&npy).unwrap();
        std::fs::remove_file(&npy).unwrap();
        let samples: [(&str, &[u8]); 2] = [("npy", &bytes), ("xyz", b"# two\n0.5 -1 3.25\n1e6 2 -0\n")];
        for (i, (ext, bytes)) in samples.iter().enumerate() {
            let read = read_files(&format!("sites{i}"), &[(ext, bytes)], read_sites);
            assert_eq!(read.unwrap_or_else(|e| panic!(".{ext}: {e}")), sites, ".{ext}");
        }
        for f in SITES {
            assert!(f.extensions.iter().all(|e| samples.iter().any(|s| s.0 == *e)), "no sample of {}", f.name);
        }
    }

    #[test]
    fn every_particles_row_reads_a_valid_file() {
        let samples: [(&str, &str, &str); 4] = [
            ("dump", "", lammps_dump::tests::VALID),
            ("lammpstrj", "", lammps_dump::tests::VALID),
            ("lj", "dump.", lammps_dump::tests::VALID),
            ("extxyz", "", extxyz::tests::VALID),
        ];
        let dir = temp_path("particles");
        std::fs::create_dir_all(&dir).unwrap();
        for (i, (ext, prefix, text)) in samples.iter().enumerate() {
            let path = dir.join(format!("{prefix}row{i}.{ext}"));
            std::fs::write(&path, text).unwrap();
            let frames: Result<Vec<_>> = open_particles(&path).map(|r| r.collect()).and_then(|f| f);
            std::fs::remove_file(&path).unwrap();
            let frames = frames.unwrap_or_else(|e| panic!(".{ext}: {e}"));
            assert_eq!(frames.len(), 2, ".{ext}");
            assert_eq!(frames[0].positions, [[0.5, 0.25, -1.0], [9.0, 9.0, 4.0], [1.5, 2.5, 3.5]], ".{ext}");
            assert_eq!(frames[0].domain.periodic(), [true, true, false], ".{ext}");
        }
        std::fs::remove_dir(&dir).unwrap();
        for f in PARTICLES {
            assert!(f.extensions.iter().all(|e| samples.iter().any(|s| s.0 == *e)), "no sample of {}", f.name);
        }
    }

    /// `docs/FORMATS.md` names every format and extension.
    #[test]
    fn the_users_table_names_every_row() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/FORMATS.md");
        let Ok(doc) = std::fs::read_to_string(&path) else {
            eprintln!("skipped: {} is absent", path.display());
            return;
        };
        for (table, rows) in tables() {
            for (exts, name, _) in rows {
                assert!(doc.contains(name), "{table}: {name} is not in {}", path.display());
                for e in exts {
                    assert!(doc.contains(&format!("`.{e}`")), "{table}: `.{e}` is not in {}", path.display());
                }
            }
        }
    }
}
