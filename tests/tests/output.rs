//! What `cvd run` writes: `cells.csv` read back, `summary.json`'s keys,
//! `pieces.vtu` read by an independent reader (Python's meshio), the
//! picture's pixels.

use cvd::exec::CpuBackend;
use cvd::{geom::points, Cells, ClippedVoronoi, Error, Pieces, Strategy, TetMesh};
use cvd_io::{Section, Summary};
use std::path::PathBuf;
use std::process::Command;

/// A fresh folder in the temporary directory.
fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("cvd-output-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A non-convex mesh away from the origin and not of unit size, so that
/// the pieces' world coordinates are tested.
fn moved_ell() -> TetMesh {
    let mut mesh = TetMesh::voxels(4, |i, j, _| i < 2 || j < 2);
    for v in &mut mesh.vertices {
        *v = [3.0 * v[0] + 10.0, 3.0 * v[1] - 5.0, 1.5 * v[2] + 0.25];
    }
    mesh
}

fn diagram(mesh: &TetMesh, sites: &[[f64; 3]]) -> (Cells, Pieces) {
    let cpu = CpuBackend::new(None).unwrap();
    ClippedVoronoi::new(mesh, sites).compute_with_pieces(&cpu).unwrap()
}

#[test]
fn cells_csv_reads_back_exactly() {
    let mesh = TetMesh::cube(3);
    let mut sites = points::uniform(60, 4);
    sites.push(sites[7]);
    sites.push([5.0, 5.0, 5.0]); // outside: an empty cell
    let cells = ClippedVoronoi::new(&mesh, &sites).compute().unwrap();
    let path = temp_dir("csv").join("cells.csv");
    cvd_io::write_cells_csv(&path, &cells).unwrap();
    let rows = cvd_io::read_cells_csv(&path).unwrap();
    assert_eq!(rows.len(), sites.len());
    for (i, row) in rows.iter().enumerate() {
        assert_eq!(row.site, i);
        assert_eq!((row.volume, row.centroid, row.energy), (cells.volume[i], cells.centroid[i], cells.energy[i]));
    }
    assert_eq!(rows[60].volume, 0.0, "the duplicate's cell is empty");
    assert_eq!(rows[61].volume, 0.0, "the far site's cell is empty");
    assert_eq!(rows[61].centroid, [5.0, 5.0, 5.0], "an empty cell's centroid is its site");
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(text.starts_with("site,volume,cx,cy,cz,energy\n0,"), "{}", &text[..40]);
    assert!(rows.iter().all(|r| r.area.is_none() && r.neighbors.is_none()));
    // With the faces: each cell's surface area and neighbour count too.
    let cells = ClippedVoronoi::new(&mesh, &sites).faces(true).compute().unwrap();
    cvd_io::write_cells_csv(&path, &cells).unwrap();
    let rows = cvd_io::read_cells_csv(&path).unwrap();
    let adjacency = cells.adjacency().unwrap();
    for (i, row) in rows.iter().enumerate() {
        assert_eq!(row.area, Some(adjacency.surface_area(i)));
        assert_eq!(row.neighbors, Some(adjacency.of(i).count()));
    }
    assert!(rows[5].neighbors.unwrap() > 3 && rows[60].neighbors == Some(0));
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(text.starts_with("site,volume,cx,cy,cz,energy,area,neighbors\n0,"), "{}", &text[..50]);
}

#[test]
fn bad_cells_csv_names_the_line() {
    let dir = temp_dir("bad-csv");
    let cases = [
        ("index,volume\n", 1, "expected the header"),
        ("site,volume,cx,cy,cz,energy\n0,1,2,3,4,5\n1,1,2,3\n", 3, "expected 6 comma-separated values"),
        ("site,volume,cx,cy,cz,energy\n0,1,2,x,4,5\n", 2, "column 4"),
        ("site,volume,cx,cy,cz,energy,area,neighbors\n0,1,2,3,4,5,6\n", 2, "expected 8 comma-separated values"),
        ("site,volume,cx,cy,cz,energy,area,neighbors\n0,1,2,3,4,5,6,-1\n", 2, "column 8"),
    ];
    for (k, (text, line, message)) in cases.into_iter().enumerate() {
        let path = dir.join(format!("{k}.csv"));
        std::fs::write(&path, text).unwrap();
        match cvd_io::read_cells_csv(&path) {
            Err(Error::Parse { line: l, message: m, path: p }) => {
                assert_eq!(l, line, "{m}");
                assert!(m.contains(message), "{m}");
                assert!(p.ends_with(&format!("{k}.csv")));
            }
            other => panic!("expected a parse error, got {other:?}"),
        }
    }
}

#[test]
fn summary_json_has_the_keys() {
    let mesh = TetMesh::cube(3);
    let sites = points::uniform(50, 2);
    let cpu = CpuBackend::new(Some(1)).unwrap();
    let cells = ClippedVoronoi::new(&mesh, &sites).backend(&cpu).compute().unwrap();
    let mut summary = Summary::new("cube", &mesh, sites.len(), Strategy::TetCell, &cpu, &cells);
    summary.pieces = Some(123);
    let path = temp_dir("json").join("summary.json");
    summary.write_json(&path).unwrap();
    let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    for key in [
        "model",
        "tets",
        "sites",
        "backend",
        "device",
        "strategy",
        "k",
        "mesh_volume",
        "volume_sum",
        "e_vol",
        "times",
        "counters",
    ] {
        assert!(json.get(key).is_some(), "summary.json lacks {key}: {json}");
    }
    for key in ["knn_s", "clip_s", "total_s"] {
        assert!(json["times"][key].as_f64().is_some_and(|t| t >= 0.0), "times.{key}: {json}");
    }
    assert_eq!(json["model"], "cube");
    assert_eq!(json["tets"], mesh.tets.len());
    assert_eq!(json["sites"], 50);
    assert_eq!(json["backend"], "cpu");
    assert_eq!(json["device"], "1 threads");
    assert_eq!(json["strategy"], "tet-cell");
    assert_eq!(json["pieces"], 123);
    assert_eq!(json["volume_sum"].as_f64(), Some(cells.total_volume));
    assert_eq!(json["counters"]["pairs"].as_u64(), Some(cells.counters.pairs));
    let t = &json["times"];
    let total = t["total_s"].as_f64().unwrap();
    assert!(t["knn_s"].as_f64().unwrap() + t["clip_s"].as_f64().unwrap() <= total * (1.0 + 1e-12));
    // The terminal table shows the same.
    let table = summary.to_string();
    for part in ["cube", "tet-cell", "cpu on 1 threads", "E_vol", "pieces"] {
        assert!(table.contains(part), "the table lacks {part}:\n{table}");
    }
}

/// The numbers of the `DataArray` named `name` in an ASCII VTU file.
fn data_array(vtu: &str, name: &str) -> Vec<f64> {
    let tag = format!("Name=\"{name}\"");
    let at = vtu.find(&tag).unwrap_or_else(|| panic!("no DataArray {name}"));
    let start = at + vtu[at..].find('>').unwrap() + 1;
    let end = start + vtu[start..].find("</DataArray>").unwrap();
    vtu[start..end].split_whitespace().map(|t| t.parse().unwrap_or_else(|_| panic!("{name}: {t:?}"))).collect()
}

/// Reads `pieces.vtu` back here, by the VTK layout alone: the polyhedra's
/// faces use only their own points, and their volumes (divergence
/// theorem over the faces) add up to each site's cell and to the mesh.
#[test]
fn vtu_polyhedra_add_up_to_the_cells() {
    let mesh = moved_ell();
    let sites = points::in_mesh(&mesh, 100, 3);
    let (cells, pieces) = diagram(&mesh, &sites);
    let path = temp_dir("vtu-here").join("pieces.vtu");
    cvd_io::write_pieces_vtu(&path, &pieces, &mut |_, _| {}).unwrap();
    let vtu = std::fs::read_to_string(&path).unwrap();
    assert!(vtu.contains(&format!("NumberOfCells=\"{}\"", pieces.len())));
    let points: Vec<[f64; 3]> = data_array(&vtu, "Points").chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
    let as_usize = |name: &str| data_array(&vtu, name).into_iter().map(|x| x as usize).collect::<Vec<_>>();
    let (connectivity, offsets, types) = (as_usize("connectivity"), as_usize("offsets"), as_usize("types"));
    let (faces, faceoffsets, site) = (as_usize("faces"), as_usize("faceoffsets"), as_usize("site"));
    let n = pieces.len();
    assert!(offsets.len() == n && types.len() == n && faceoffsets.len() == n && site.len() == n);
    assert!(types.iter().all(|&t| t == 42), "not all polyhedra");
    assert_eq!((offsets[n - 1], faceoffsets[n - 1]), (connectivity.len(), faces.len()));
    let mut per_site = vec![0.0; sites.len()];
    let (mut point_start, mut face_start) = (0, 0);
    for c in 0..n {
        let own = &connectivity[point_start..offsets[c]];
        let mut at = face_start;
        let mut six = 0.0;
        for _ in 0..faces[at] {
            let len = faces[at + 1];
            let loop_ = &faces[at + 2..at + 2 + len];
            assert!(
                len >= 3 && loop_.iter().all(|v| own.contains(v)),
                "cell {c}: a face {loop_:?} off its points {own:?}"
            );
            let p = |k: usize| points[loop_[k]];
            for k in 1..len - 1 {
                let (a, b, d) = (p(0), p(k), p(k + 1));
                six += a[0] * (b[1] * d[2] - b[2] * d[1])
                    + a[1] * (b[2] * d[0] - b[0] * d[2])
                    + a[2] * (b[0] * d[1] - b[1] * d[0]);
            }
            at += 1 + len;
        }
        assert_eq!(at + 1, faceoffsets[c], "cell {c}: faceoffsets");
        per_site[site[c]] += six / 6.0;
        (point_start, face_start) = (offsets[c], faceoffsets[c]);
    }
    let total: f64 = per_site.iter().sum();
    assert!((total - mesh.volume()).abs() <= 1e-5 * mesh.volume(), "{total} vs {}", mesh.volume());
    let typical = mesh.volume() / sites.len() as f64;
    for (i, (&got, &cell)) in per_site.iter().zip(&cells.volume).enumerate() {
        assert!((got - cell).abs() <= 1e-5 * cell.max(typical), "site {i}: {got:e} vs {cell:e}");
    }
}

/// Whether `python3` with meshio and numpy runs here (see
/// [`cvd_tests::python`]).
fn python_with_meshio() -> bool {
    cvd_tests::python(&["-c", "import meshio, numpy"], "meshio and numpy").is_some()
}

#[test]
fn meshio_reads_the_pieces_back() {
    if !python_with_meshio() {
        return;
    }
    let mesh = moved_ell();
    let sites = points::in_mesh(&mesh, 120, 9);
    let (cells, pieces) = diagram(&mesh, &sites);
    let path = temp_dir("vtu").join("pieces.vtu");
    let mut calls = 0;
    cvd_io::write_pieces_vtu(&path, &pieces, &mut |done, total| {
        assert!(done <= total);
        calls += 1;
    })
    .unwrap();
    assert!(calls > 0, "no progress reported");
    let script = cvd_tests::script("read_pieces.py");
    let run = Command::new("python3").arg(&script).arg(&path).output().unwrap();
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let read: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    assert_eq!(read["pieces"].as_u64(), Some(pieces.len() as u64));
    let total = read["volume"].as_f64().unwrap();
    let v = mesh.volume();
    assert!((total - v).abs() <= 1e-5 * v, "meshio's pieces add up to {total}, the mesh is {v}");
    let typical = v / sites.len() as f64;
    for (i, &expected) in cells.volume.iter().enumerate() {
        let got = read["sites"][i.to_string()].as_f64().unwrap_or(0.0);
        assert!(
            (got - expected).abs() <= 1e-5 * expected.max(typical),
            "site {i}: meshio {got:e}, library {expected:e}"
        );
    }
}

/// The picture of a holed block: the hole is white, cells have colours,
/// and two sites far apart on the plane have different ones.
#[test]
fn picture_shows_cells_and_the_hole() {
    let mesh = TetMesh::voxels(5, |i, j, _| !(i == 2 && j == 2));
    let mut sites = points::in_mesh(&mesh, 80, 1);
    sites.extend([[0.1, 0.1, 0.5], [0.9, 0.9, 0.5]]);
    let (_, pieces) = diagram(&mesh, &sites);
    let path = temp_dir("png").join("picture.png");
    cvd_io::write_section_png(&path, &mesh, &pieces, Section::middle(&mesh), 200, &mut |_, _| {}).unwrap();
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&path).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!((info.width, info.height), (200, 200));
    // The box [0, 1]² with a 2% margin on each side.
    let pixel = |x: f64, y: f64| {
        let scale = 200.0 / 1.04;
        let (c, r) = (((x + 0.02) * scale) as usize, ((1.02 - y) * scale) as usize);
        let at = (r * 200 + c) * 3;
        [buf[at], buf[at + 1], buf[at + 2]]
    };
    let white = [255; 3];
    assert_eq!(pixel(0.5, 0.5), white, "the hole");
    assert_eq!(pixel(0.0 - 0.015, 0.5), white, "the margin");
    assert_eq!(pixel(0.0, 0.5), [0; 3], "the outline");
    let (a, b) = (pixel(0.1, 0.1), pixel(0.9, 0.9));
    assert!(a != white && b != white && a != b, "cells: {a:?} {b:?}");
    assert!(a.iter().all(|&c| c >= 110) && b.iter().all(|&c| c >= 110), "light cell colours: {a:?} {b:?}");
}

/// The 3D view of a holed block's lower cells: the corners are background,
/// many cells show, each in several shades (its faces' orientations), and
/// no cell is drawn whose site is above the cut.
#[test]
fn the_3d_view_shows_the_lower_cells_shaded() {
    let mesh = TetMesh::voxels(5, |i, j, _| !(i == 2 && j == 2));
    let sites = points::in_mesh(&mesh, 120, 2);
    let (_, pieces) = diagram(&mesh, &sites);
    let path = temp_dir("view").join("cells.png");
    cvd_io::write_cells_view_png(&path, &mesh, &pieces, 0.5, 300, &mut |_, _| {}).unwrap();
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&path).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.width, 300);
    let pixels: Vec<[u8; 3]> = buf.as_chunks::<3>().0.to_vec();
    assert_eq!(pixels[0], [255; 3], "the background");
    let colours: std::collections::HashSet<[u8; 3]> = pixels.iter().copied().filter(|&p| p != [255; 3]).collect();
    // Each shown cell in a few shades (one per face orientation).
    let shown = sites.iter().filter(|s| s[2] <= 0.5).count();
    assert!(colours.len() > shown, "{} colours for {shown} cells", colours.len());
    let drawn = pixels.iter().filter(|&&p| p != [255; 3]).count();
    assert!(drawn > pixels.len() / 5, "{drawn} of {} pixels drawn", pixels.len());
    // Only the cells below the cut: below every site, nothing is drawn.
    cvd_io::write_cells_view_png(&path, &mesh, &pieces, -1.0, 300, &mut |_, _| {}).unwrap();
    let mut reader =
        png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&path).unwrap())).read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    reader.next_frame(&mut buf).unwrap();
    assert!(buf.iter().all(|&c| c == 255), "nothing below the lowest site");
}

/// The pictures drawn in parts — each rank the pieces of the cells it
/// builds, a sub-part's at a time, the ranks' images combined — are one
/// process's, byte for byte: on a holed block with a tight cluster in a
/// crowd (where most pixels of a cluster's cells are walls), for 1 to 3
/// ranks of 1 or 2 sub-parts each. The pieces the ranks are handed are
/// one process's, each once, by input index.
#[test]
fn pictures_drawn_in_parts_are_one_process_pictures() {
    use cvd::backends::distributed::{InProcess, Reduce};
    use cvd_io::{CellsView, SectionImage};
    let mesh = TetMesh::voxels(6, |i, j, _| !(i == 3 && j == 2));
    let mut sites = points::in_mesh(&mesh, 3000, 61);
    let centre = [0.3, 0.6, 0.5];
    sites
        .extend(points::clustered(600, 1, 0.01, 62).iter().map(|p| [0, 1, 2].map(|a| centre[a] + 0.05 * (p[a] - 0.5))));
    let n = sites.len();
    let whole = ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::Whole);
    let cpu = CpuBackend::new(Some(2)).unwrap();
    let (_, pieces) = whole.compute_with_pieces(&cpu).unwrap();
    let section = Section::middle(&mesh);
    let dir = temp_dir("parts-pictures");
    let png = |name: &str| std::fs::read(dir.join(name)).unwrap();
    cvd_io::write_section_png(&dir.join("one.png"), &mesh, &pieces, section, 400, &mut |_, _| {}).unwrap();
    cvd_io::write_cells_view_png(&dir.join("one-view.png"), &mesh, &pieces, section.z, 400, &mut |_, _| {}).unwrap();
    let key = |p: &cvd::Piece| (p.site, p.tet, p.vertices.len());
    let mut expected: Vec<_> = pieces.iter().map(|p| key(&p)).collect();
    expected.sort_unstable();
    for (ranks, per_rank) in [(1, 2), (2, 1), (3, 2)] {
        let what = format!("{ranks} ranks x {per_rank} parts");
        let rows = |r: usize| n * r / ranks..n * (r + 1) / ranks;
        let handed = InProcess::each(ranks, |comm| {
            let cv = ClippedVoronoi::new(&mesh, &sites[rows(comm.rank())]).strategy(Strategy::Whole);
            let cpu = CpuBackend::new(Some(1)).unwrap();
            let (mut image, mut view) = (SectionImage::new(&mesh, section, 400), CellsView::new(&mesh, section.z, 400));
            let mut handed = Vec::new();
            cv.parts_per_rank(per_rank)
                .compute_in_parts_visiting(comm, &cpu, &mut |pieces| {
                    image.draw(pieces, &mut |_, _| {});
                    view.draw(pieces, &mut |_, _| {});
                    handed.extend(pieces.iter().map(|p| key(&p)));
                    Ok(())
                })
                .unwrap();
            image.combine(&mut |v| comm.max(v)).unwrap();
            view.combine(&mut |v| comm.max(v)).unwrap();
            if comm.rank() == 0 {
                image.write_png(&dir.join(format!("{ranks}-{per_rank}.png"))).unwrap();
                view.write_png(&dir.join(format!("{ranks}-{per_rank}-view.png"))).unwrap();
            }
            handed
        });
        let mut handed: Vec<_> = handed.into_iter().flatten().collect();
        handed.sort_unstable();
        assert!(
            handed == expected,
            "{what}: the pieces handed are one process's ({} of {})",
            handed.len(),
            expected.len()
        );
        assert!(png(&format!("{ranks}-{per_rank}.png")) == png("one.png"), "{what}: picture.png");
        assert!(png(&format!("{ranks}-{per_rank}-view.png")) == png("one-view.png"), "{what}: cells.png");
    }
}
