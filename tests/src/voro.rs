//! voro++ (through `voro_rs`) as an oracle that shares no code with the
//! project: its radical (power) cells, in a box or a periodic box.

use voro_rs::prelude::*;

/// voro++'s radical cells of `sites` with weights `w` in the box `lo..hi`
/// (the weights shifted so that the least is 0, which changes no cell, and
/// given as radii `sqrt(w)`): volumes and centroids in input order (an
/// empty cell: volume 0, no centroid).
pub fn power_cells(lo: [f64; 3], hi: [f64; 3], sites: &[[f64; 3]], w: &[f64]) -> (Vec<f64>, Vec<Option<[f64; 3]>>) {
    radical_cells(lo, hi, sites, w, [false; 3])
}

/// voro++'s radical cells in the periodic box `lo..hi` (sites inside it):
/// volumes and centroids (`site + the cell's centroid about it`, not
/// wrapped), as [`power_cells`].
pub fn periodic_power_cells(
    lo: [f64; 3],
    hi: [f64; 3],
    sites: &[[f64; 3]],
    w: &[f64],
) -> (Vec<f64>, Vec<Option<[f64; 3]>>) {
    radical_cells(lo, hi, sites, w, [true; 3])
}

/// voro++'s radical cells in the box `lo..hi` periodic along the axes
/// flagged, walls along the others (sites inside it): volumes and
/// centroids, as [`periodic_power_cells`].
pub fn partly_periodic_power_cells(
    lo: [f64; 3],
    hi: [f64; 3],
    periodic: [bool; 3],
    sites: &[[f64; 3]],
    w: &[f64],
) -> (Vec<f64>, Vec<Option<[f64; 3]>>) {
    radical_cells(lo, hi, sites, w, periodic)
}

fn radical_cells(
    lo: [f64; 3],
    hi: [f64; 3],
    sites: &[[f64; 3]],
    w: &[f64],
    periodic: [bool; 3],
) -> (Vec<f64>, Vec<Option<[f64; 3]>>) {
    let least = w.iter().copied().fold(f64::INFINITY, f64::min);
    let blocks = ((sites.len() as f64 / 5.0).cbrt().ceil() as i32).max(1);
    let mut con = ContainerRad::new(lo, hi, [blocks; 3], periodic);
    for (i, (&p, &wi)) in sites.iter().zip(w).enumerate() {
        con.put(i as i32, p, (wi - least).sqrt());
    }
    assert_eq!(con.total_particles() as usize, sites.len(), "voro++ rejected a site");
    let mut volume = vec![0.0; sites.len()];
    let mut centroid = vec![None; sites.len()];
    let mut l = LoopAll::of_container_rad(&mut con);
    assert!(l.start());
    loop {
        let id = l.particle_id() as usize;
        if let Some(mut cell) = con.compute_cell(&mut l) {
            let cell: &mut VoroCellSgl = &mut cell;
            volume[id] = cell.volume();
            let (c, p) = (cell.centroid(), l.position());
            centroid[id] = Some([c[0] + p[0], c[1] + p[1], c[2] + p[2]]);
        }
        if !l.inc() {
            break;
        }
    }
    (volume, centroid)
}
