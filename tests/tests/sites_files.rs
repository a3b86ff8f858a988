//! Sites files written by a real tool: NumPy's `.npy` (numpy, installed
//! from PyPI), every version, dtype and order it writes for an (N, 3)
//! array, read to the bit; arrays that are not sites are named errors.

/// The bits of each coordinate.
fn bits(sites: &[[f64; 3]]) -> Vec<u64> {
    sites.iter().flatten().map(|c| c.to_bits()).collect()
}

/// What numpy writes: float64 and float32 (N, 3) arrays, C and Fortran
/// order, .npy versions 1.0 to 3.0, read to the bit (numpy prints each
/// value's bits, float32 widened by numpy); the same sites as `.xyz`
/// written with Python's repr give the same cells; arrays that are not
/// sites are refused by name.
#[test]
fn numpy_files_are_read_exactly() {
    let dir = std::env::temp_dir().join(format!("cvd-sites-files-numpy-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let script = r#"
import sys
import numpy as np
d = sys.argv[1]
rng = np.random.default_rng(7)
a = rng.random((1000, 3))
a[0] = [0.1, 1 / 3, -0.0]
a[1] = [5e-324, 2.2250738585072014e-308, 1.7976931348623157e308]
a[2] = [4649776.224345621, 1000000.0145585263, 1e-300]
f = (rng.random((500, 3)) * 100 - 50).astype('<f4')
f[0] = [np.float32(0.1), np.float32(1e-45), np.float32(3.4e38)]
np.save(d + '/f8.npy', a)
np.save(d + '/f4.npy', f)
np.save(d + '/f8_fortran.npy', np.asfortranarray(a))
with open(d + '/f8_v2.npy', 'wb') as o:
    np.lib.format.write_array(o, a, version=(2, 0))
with open(d + '/f4_v3_fortran.npy', 'wb') as o:
    np.lib.format.write_array(o, np.asfortranarray(f), version=(3, 0))
np.save(d + '/int.npy', np.arange(6).reshape(2, 3))
np.save(d + '/big.npy', a.astype('>f8'))
np.save(d + '/flat.npy', a.ravel())
np.save(d + '/xy.npy', a[:, :2].copy())
np.save(d + '/half.npy', a.astype('<f2'))
# Sites inside the unit cube, as .npy and as .xyz with repr.
s = rng.random((300, 3)) * 0.98 + 0.01
np.save(d + '/cube.npy', s)
with open(d + '/cube.xyz', 'w') as o:
    o.write(''.join(' '.join(repr(float(c)) for c in p) + '\n' for p in s))
for name, arr in [('f8', a), ('f4', f.astype(np.float64))]:
    print(name, ' '.join(str(b) for b in np.ascontiguousarray(arr).view('<u8').ravel()))
"#;
    let Some(out) = cvd_tests::python(&["-c", script, dir.to_str().unwrap()], "numpy") else { return };
    let out = String::from_utf8_lossy(&out);
    let printed = |name: &str| -> Vec<u64> {
        let line = out.lines().find(|l| l.starts_with(&format!("{name} "))).unwrap();
        line.split_whitespace().skip(1).map(|b| b.parse().unwrap()).collect()
    };
    let (f8, f4) = (printed("f8"), printed("f4"));
    assert_eq!((f8.len(), f4.len()), (3000, 1500));
    let read = |file: &str| cvd_io::read_sites(&dir.join(file)).unwrap_or_else(|e| panic!("{file}: {e}"));
    for file in ["f8.npy", "f8_fortran.npy", "f8_v2.npy"] {
        assert_eq!(bits(&read(file)), f8, "{file}");
    }
    for file in ["f4.npy", "f4_v3_fortran.npy"] {
        assert_eq!(bits(&read(file)), f4, "{file}");
    }
    let header = |file: &str| String::from_utf8_lossy(&std::fs::read(dir.join(file)).unwrap()[..128]).into_owned();
    assert!(header("f8_fortran.npy").contains("'fortran_order': True"), "{}", header("f8_fortran.npy"));
    assert_eq!(std::fs::read(dir.join("f8_v2.npy")).unwrap()[6..8], [2, 0], "format version 2.0");
    for (file, expected) in [
        ("int.npy", "dtype '<i8': expected little-endian float64 '<f8' or float32 '<f4'"),
        ("big.npy", "dtype '>f8' (big-endian)"),
        ("half.npy", "dtype '<f2'"),
        ("flat.npy", "shape (3000,): expected (N, 3)"),
        ("xy.npy", "shape (1000, 2): expected (N, 3)"),
    ] {
        let e = cvd_io::read_sites(&dir.join(file)).unwrap_err().to_string();
        assert!(e.contains(file) && e.contains(expected), "{file}: {e}");
    }
    // The same sites from numpy's .npy and from Python's repr in .xyz.
    assert_eq!(bits(&read("cube.npy")), bits(&read("cube.xyz")));
    let cells = |file: &str| {
        let mesh = cvd::TetMesh::cube(3);
        let sites = read(file);
        let cpu = cvd::exec::CpuBackend::new(None).unwrap();
        cvd::ClippedVoronoi::new(&mesh, &sites).backend(&cpu).compute().unwrap()
    };
    let (a, b) = (cells("cube.npy"), cells("cube.xyz"));
    assert_eq!(a.volume.len(), 300);
    assert!(a.volume.iter().zip(&b.volume).all(|(x, y)| x.to_bits() == y.to_bits()));
    assert!(a.centroid.iter().zip(&b.centroid).all(|(x, y)| x.map(f64::to_bits) == y.map(f64::to_bits)));
    std::fs::remove_dir_all(&dir).ok();
}
