//! Random bytes and random mutations of valid files, fed to every reader:
//! each must return a mesh or an error, never panic, and never claim more
//! memory than the text could fill; the particle readers must also end.

use super::gmsh::tests::{V22, V41};
use super::particles::tests::read_all_frames;
use super::{parse_gmsh, parse_medit, parse_tet, parse_tetgen, parse_xyz, ExtxyzReader, LammpsDumpReader};
use proptest::prelude::*;

const XYZ: &str = "3\n# three sites\n0 0 0\n1 0.5 0.25\n-1e-3 2 3\n";

/// Every reader on `text` (TetGen: as either file, the other one valid).
fn read_all(text: &str) {
    let _ = parse_medit(text, "f.mesh");
    let _ = parse_tet(text, "f.tet");
    let _ = parse_gmsh(text, "f.msh");
    let _ = parse_tetgen(text, "f.node", super::tetgen::tests::ELE, "f.ele");
    let _ = parse_tetgen(super::tetgen::tests::NODE, "f.node", text, "f.ele");
    let _ = parse_xyz(text, "f.xyz");
    let _ = super::parse_values(text, "f.txt");
    read_all_frames(text, |b| LammpsDumpReader::new(b, "f.dump"));
    read_all_frames(text, |b| ExtxyzReader::new(b, "f.extxyz"));
}

fn valid_files() -> Vec<&'static str> {
    vec![
        super::medit::tests::VALID,
        super::tet::tests::VALID,
        V22,
        V41,
        super::tetgen::tests::NODE,
        super::tetgen::tests::ELE,
        XYZ,
        super::lammps_dump::tests::VALID,
        super::extxyz::tests::VALID,
    ]
}

/// One edit: delete, insert or replace bytes at a position.
#[derive(Clone, Debug)]
enum Edit {
    Delete(usize, usize),
    Insert(usize, Vec<u8>),
    Replace(usize, u8),
}

fn apply(text: &str, edits: &[Edit]) -> String {
    let mut bytes = text.as_bytes().to_vec();
    for e in edits {
        let len = bytes.len().max(1);
        match e {
            Edit::Delete(at, n) => {
                let at = at % len;
                let end = (at + n).min(bytes.len());
                if at < end {
                    bytes.drain(at..end);
                }
            }
            Edit::Insert(at, b) => {
                let at = (at % len).min(bytes.len());
                bytes.splice(at..at, b.iter().copied());
            }
            Edit::Replace(at, b) => {
                if !bytes.is_empty() {
                    let at = at % bytes.len();
                    bytes[at] = *b;
                }
            }
        }
    }
    String::from_utf8_lossy(&bytes).into_owned()
}

fn edit() -> impl Strategy<Value = Edit> {
    // Bytes that matter to the formats: digits, signs, separators, letters.
    let byte = prop_oneof![prop::sample::select(b"0123456789-+.eE \n\t#$".to_vec()), any::<u8>(),];
    prop_oneof![
        (any::<usize>(), 1usize..8).prop_map(|(a, n)| Edit::Delete(a, n)),
        (any::<usize>(), prop::collection::vec(byte.clone(), 1..12)).prop_map(|(a, b)| Edit::Insert(a, b)),
        (any::<usize>(), byte).prop_map(|(a, b)| Edit::Replace(a, b)),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    #[test]
    fn random_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..400)) {
        read_all(&String::from_utf8_lossy(&bytes));
    }

    #[test]
    fn random_tokens_never_panic(tokens in prop::collection::vec(
        prop::sample::select(vec![
            "0", "1", "2", "3", "4", "-1", "1e9", "nan", "inf", "0.5", "4294967295", "\n", " ", "#",
            "vertices", "cells", "Vertices", "Tetrahedra", "End", "MeshVersionFormatted", "Dimension",
            "$MeshFormat", "$EndMeshFormat", "$Nodes", "$EndNodes", "$Elements", "$EndElements", "2.2", "4.1",
            "ITEM:", "TIMESTEP", "NUMBER OF ATOMS", "BOX BOUNDS", "ATOMS", "pp", "xy xz yz", "abc origin", "id", "x",
            "xs", "Lattice=\"1 0 0 0 1 0 0 0 1\"", "Properties=pos:R:3:id:I:1", "pbc=\"T F T\"", "\"",
        ]), 0..80)) {
        read_all(&tokens.join(" "));
    }

    #[test]
    fn mutated_valid_files_never_panic(file in 0usize..9, edits in prop::collection::vec(edit(), 1..6)) {
        read_all(&apply(valid_files()[file], &edits));
    }
}
