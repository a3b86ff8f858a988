use cvd::{points, ClippedVoronoi};
#[test]
fn pieces_sum() {
    let mesh = cvd::mesher::models::builtin("joint", Some(16)).unwrap();
    let sites = points::in_mesh(&mesh, 600, 5);
    let cpu = cvd::cpu::CpuBackend::new(None).unwrap();
    let (cells, pieces) = ClippedVoronoi::new(&mesh, &sites).faces(true).compute_with_pieces(&cpu).unwrap();
    let mut v = vec![0.0; sites.len()];
    for p in &pieces {
        v[p.site as usize] += p.volume();
    }
    let mut worst = (0.0, 0);
    for i in 0..sites.len() {
        let e = (v[i] - cells.volume[i]).abs() / cells.volume[i];
        if e > worst.0 {
            worst = (e, i);
        }
    }
    println!("worst {:?} cell 396 {:e} vs {:e}; counters {:?}", worst, v[396], cells.volume[396], cells.counters);
    for p in pieces.iter().filter(|p| p.site == 396) {
        println!("tet {} vol {:e} makers {:?}", p.tet, p.volume(), p.face_makers);
    }
}
