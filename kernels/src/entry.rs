//! Compute-shader entry points: read the thread index, call a body.
//!
//! Every kernel runs [`WORKGROUP_SIZE`](crate::abi::WORKGROUP_SIZE) threads
//! per workgroup and is dispatched as a 2D grid of workgroups (see
//! [`thread_index`]). Descriptor set 0 holds storage buffers in the order of
//! the parameters; push constants hold the `*Params` struct.

use crate::abi::{
    thread_index, ClipParams, DomainParams, GridBuildParams, KnnParams, LloydParams, QuantPoint, RefineParams,
    SplitPoint,
};
use crate::buffers::{DeviceCounters, DeviceList, DeviceSums};
use crate::clip::{FaceInputs, NoPieces};
use crate::polyhedron::{CELL_PLANES, CELL_VERTS};
use crate::walk::GridWalk;
use crate::whole::{self, Domain};
use crate::{clip, grid, knn, lloyd, refine, scan};
use spirv_std::glam::UVec3;
use spirv_std::spirv;

/// Bins each site into the grid and counts the sites per cell.
#[spirv(compute(threads(64)))]
pub fn grid_count(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(num_workgroups)] groups: UVec3,
    #[spirv(push_constant)] p: &GridBuildParams,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] sites: &[QuantPoint],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] site_cell: &mut [u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] cell_count: &mut [u32],
) {
    let i = thread_index(id.x, id.y, groups.x);
    grid::count_site(i, &p.grid, sites, site_cell, &mut DeviceCounters(cell_count));
}

/// Orders each cell's sites by index (after the scatter).
#[spirv(compute(threads(64)))]
pub fn grid_sort(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(num_workgroups)] groups: UVec3,
    #[spirv(push_constant)] p: &GridBuildParams,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] cell_start: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] cell_count: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] sorted: &mut [QuantPoint],
) {
    let c = thread_index(id.x, id.y, groups.x);
    grid::sort_cell(c, &p.grid, cell_start, cell_count, sorted);
}

/// Prefix sum, step 1: scans each block of cell counts.
#[spirv(compute(threads(64)))]
pub fn scan_blocks(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(num_workgroups)] groups: UVec3,
    #[spirv(push_constant)] p: &GridBuildParams,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] cell_count: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] cell_start: &mut [u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] block_sums: &mut [u32],
) {
    let b = thread_index(id.x, id.y, groups.x);
    scan::scan_block(b, p.grid.n_cells as usize, cell_count, cell_start, block_sums);
}

/// Prefix sum, step 2: one thread scans the block totals.
#[spirv(compute(threads(64)))]
pub fn scan_totals(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(push_constant)] p: &GridBuildParams,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] block_sums: &mut [u32],
) {
    if id.x == 0 && id.y == 0 {
        scan::scan_block_sums(p.n_blocks as usize, block_sums);
    }
}

/// Prefix sum, step 3: adds each block's offset.
#[spirv(compute(threads(64)))]
pub fn scan_offsets(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(num_workgroups)] groups: UVec3,
    #[spirv(push_constant)] p: &GridBuildParams,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] block_sums: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] cell_start: &mut [u32],
) {
    let b = thread_index(id.x, id.y, groups.x);
    scan::add_block_offset(b, p.grid.n_cells as usize, cell_start, block_sums);
}

/// Moves each site into its cell's range of the sorted site array.
#[spirv(compute(threads(64)))]
pub fn grid_scatter(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(num_workgroups)] groups: UVec3,
    #[spirv(push_constant)] p: &GridBuildParams,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] sites: &[QuantPoint],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] site_cell: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] cell_start: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] cursor: &mut [u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] sorted: &mut [QuantPoint],
) {
    let i = thread_index(id.x, id.y, groups.x);
    grid::scatter_site(i, &p.grid, sites, site_cell, cell_start, &mut DeviceCounters(cursor), sorted);
}

/// k nearest sites of each query by grid ring search.
#[spirv(compute(threads(64)))]
pub fn knn_grid(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(num_workgroups)] groups: UVec3,
    #[spirv(push_constant)] p: &KnnParams,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] queries: &[QuantPoint],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] cell_start: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] cell_count: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] sorted: &[QuantPoint],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] neighbors: &mut [u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 5)] neighbor_d2: &mut [u64],
) {
    let i = thread_index(id.x, id.y, groups.x);
    let _ = knn::grid_thread(i, p, queries, cell_start, cell_count, sorted, neighbors, neighbor_d2);
}

/// k nearest sites of each query by brute force.
#[spirv(compute(threads(64)))]
pub fn knn_brute(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(num_workgroups)] groups: UVec3,
    #[spirv(push_constant)] p: &KnnParams,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] queries: &[QuantPoint],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] sites: &[QuantPoint],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] neighbors: &mut [u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] neighbor_d2: &mut [u64],
) {
    let i = thread_index(id.x, id.y, groups.x);
    let _ = knn::brute_thread(i, p, queries, sites, neighbors, neighbor_d2);
}

/// Tet-cell strategy: one thread per (tet, paired site).
#[spirv(compute(threads(64)))]
pub fn clip_tet_cell(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(num_workgroups)] groups: UVec3,
    #[spirv(push_constant)] p: &ClipParams,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] sites: &[SplitPoint],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] verts: &[SplitPoint],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] tets: &[[u32; 4]],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] tet_sites: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] site_nbrs: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 5)] sums: &mut [i64],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 6)] counters: &mut [i64],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 7)] unfinished: &mut [u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 8)] tet_faces: &[u32],
) {
    let pair = thread_index(id.x, id.y, groups.x);
    clip::tet_cell_pair(
        pair,
        p,
        sites,
        verts,
        tets,
        tet_sites,
        site_nbrs,
        tet_faces,
        &mut DeviceSums(sums),
        &mut DeviceSums(counters),
        &mut DeviceList(unfinished),
        &mut NoPieces,
    );
}

/// Algorithm 1: the Voronoi cell of each site, stored for the cell-tet strategy.
#[spirv(compute(threads(64)))]
pub fn voronoi_cells(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(num_workgroups)] groups: UVec3,
    #[spirv(push_constant)] p: &ClipParams,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] sites: &[SplitPoint],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] site_nbrs: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] cells: &mut [[f32; 4]],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] counters: &mut [i64],
) {
    let i = thread_index(id.x, id.y, groups.x);
    clip::voronoi_cell(i, p, sites, site_nbrs, cells, &mut DeviceSums(counters));
}

/// Cell-tet strategy: one thread per (tet, paired site).
#[spirv(compute(threads(64)))]
pub fn clip_cell_tet(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(num_workgroups)] groups: UVec3,
    #[spirv(push_constant)] p: &ClipParams,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] sites: &[SplitPoint],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] verts: &[SplitPoint],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] tets: &[[u32; 4]],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] tet_sites: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] cells: &[[f32; 4]],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 5)] sums: &mut [i64],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 6)] counters: &mut [i64],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 7)] unfinished: &mut [u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 8)] site_nbrs: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 9)] tet_faces: &[u32],
) {
    let pair = thread_index(id.x, id.y, groups.x);
    clip::cell_tet_pair(
        pair,
        p,
        sites,
        verts,
        tets,
        tet_sites,
        cells,
        site_nbrs,
        tet_faces,
        &mut DeviceSums(sums),
        &mut DeviceSums(counters),
        &mut DeviceList(unfinished),
        &mut NoPieces,
    );
}

/// Flood pairing (tet-cell): one thread per tet.
#[spirv(compute(threads(64)))]
pub fn clip_flood(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(num_workgroups)] groups: UVec3,
    #[spirv(push_constant)] p: &RefineParams,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] sites: &[SplitPoint],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] verts: &[SplitPoint],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] tets: &[[u32; 4]],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] tet_sites: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] site_nbrs: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 5)] cell_start: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 6)] cell_count: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 7)] sorted: &[QuantPoint],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 8)] sums: &mut [i64],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 9)] counters: &mut [i64],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 10)] unfinished: &mut [u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 11)] tet_faces: &[u32],
) {
    let t = thread_index(id.x, id.y, groups.x);
    let w = GridWalk::new(p, site_nbrs, cell_start, cell_count, sorted);
    clip::flood_tet(
        t,
        p,
        w,
        sites,
        verts,
        tets,
        tet_sites,
        FaceInputs { site_nbrs, tet_faces },
        &mut DeviceSums(sums),
        &mut DeviceSums(counters),
        &mut DeviceList(unfinished),
        &mut NoPieces,
    );
}

/// Whole cells: one thread per site; its cell integrated whole where the
/// boundary does not meet it, else clipped by the tets it meets.
#[spirv(compute(threads(64)))]
pub fn clip_whole(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(num_workgroups)] groups: UVec3,
    #[spirv(push_constant)] p: &RefineParams,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] sites: &[SplitPoint],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] verts: &[SplitPoint],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] tets: &[[u32; 4]],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] site_nbrs: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] cell_start: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 5)] cell_count: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 6)] sorted: &[QuantPoint],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 7)] sums: &mut [i64],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 8)] counters: &mut [i64],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 9)] unfinished: &mut [u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 10)] tet_faces: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 11)] domain: &[DomainParams],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 12)] voxel_start: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 13)] voxel_tets: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 14)] tet_voxel: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 15)] nodes: &[[f32; 4]],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 16)] tris: &[[u32; 4]],
) {
    let i = thread_index(id.x, id.y, groups.x);
    let w = GridWalk::new(p, site_nbrs, cell_start, cell_count, sorted);
    let d = Domain { params: domain[0], voxel_start, voxel_tets, tet_voxel, nodes, tris };
    whole::whole_cell::<CELL_PLANES, CELL_VERTS, _, _, _, _>(
        i,
        p,
        w,
        sites,
        verts,
        tets,
        d,
        FaceInputs { site_nbrs, tet_faces },
        &mut DeviceSums(sums),
        &mut DeviceSums(counters),
        &mut DeviceList(unfinished),
        &mut NoPieces,
    );
}

/// Second pass: one thread per entry of the first pass's unfinished list.
#[spirv(compute(threads(64)))]
pub fn refine(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(num_workgroups)] groups: UVec3,
    #[spirv(push_constant)] p: &RefineParams,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] sites: &[SplitPoint],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] verts: &[SplitPoint],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] tets: &[[u32; 4]],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] tet_sites: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] list: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 5)] site_nbrs: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 6)] cell_start: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 7)] cell_count: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 8)] sorted: &[QuantPoint],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 9)] sums: &mut [i64],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 10)] counters: &mut [i64],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 11)] still: &mut [u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 12)] tet_faces: &[u32],
) {
    let e = thread_index(id.x, id.y, groups.x);
    let w = GridWalk::new(p, site_nbrs, cell_start, cell_count, sorted);
    refine::refine_entry(
        e,
        p,
        w,
        sites,
        verts,
        tets,
        tet_sites,
        list,
        FaceInputs { site_nbrs, tet_faces },
        &mut DeviceSums(sums),
        &mut DeviceSums(counters),
        &mut DeviceList(still),
        &mut NoPieces,
    );
}

/// Lloyd: one thread per site moves it to its cell's centroid.
#[spirv(compute(threads(64)))]
pub fn move_sites(
    #[spirv(global_invocation_id)] id: UVec3,
    #[spirv(num_workgroups)] groups: UVec3,
    #[spirv(push_constant)] p: &LloydParams,
    #[spirv(storage_buffer, descriptor_set = 0, binding = 0)] sums: &[i64],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 1)] unfinished: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 2)] still: &[u32],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 3)] sites: &mut [SplitPoint],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 4)] quant: &mut [QuantPoint],
    #[spirv(storage_buffer, descriptor_set = 0, binding = 5)] stats: &mut [i64],
) {
    let i = thread_index(id.x, id.y, groups.x);
    lloyd::move_site(i, p, sums, unfinished, still, sites, quant, &mut DeviceSums(stats));
}
