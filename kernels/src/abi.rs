//! Types shared by the host and the kernels (push constants and buffer
//! records), defined once.
//!
//! # Layout rule
//! Storage buffers use the std430 layout, where a 3-vector has a 16-byte
//! alignment but a glam `Vec3` has a 12-byte stride on the host. So no `Vec3`
//! ever crosses the boundary: points are stored as 4-component records
//! (`[u32; 4]`, `[f32; 4]`) and every struct here is `#[repr(C)]`, made of
//! 4-byte scalars (or 8-byte ones at 8-byte offsets), with no implicit padding.
//! Push-constant structs follow the same rule.

use bytemuck::{Pod, Zeroable};

/// Coordinates are quantized to integers in `[0, QUANT_MAX]` on the host, so
/// that squared distances are exact in 64 bits (3 * (2^30)^2 < 2^64) and every
/// backend orders neighbours identically.
pub const QUANT_BITS: u32 = 30;
/// The largest quantized coordinate.
pub const QUANT_MAX: u32 = (1 << QUANT_BITS) - 1;

/// Marks "no site" (no index to exclude, an empty neighbour slot).
pub const NO_SITE: u32 = u32::MAX;

/// Threads per workgroup of every kernel.
pub const WORKGROUP_SIZE: u32 = 64;

/// A site or query point: quantized `x, y, z` and its original index.
pub type QuantPoint = [u32; 4];

/// A uniform grid over quantized space: cubic cells of side `cell_size`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct GridParams {
    /// Number of cells along x.
    pub dim_x: u32,
    /// Number of cells along y.
    pub dim_y: u32,
    /// Number of cells along z.
    pub dim_z: u32,
    /// Side of a cell in quantized units.
    pub cell_size: u32,
    /// Number of sites in the grid.
    pub n_sites: u32,
    /// `dim_x * dim_y * dim_z`.
    pub n_cells: u32,
    /// Padding to a 16-byte multiple.
    pub _pad: [u32; 2],
}

/// Push constants of the grid-building kernels.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct GridBuildParams {
    /// The grid being built.
    pub grid: GridParams,
    /// Number of blocks of the prefix sum (see [`crate::scan`]).
    pub n_blocks: u32,
    /// Padding to a 16-byte multiple.
    pub _pad: [u32; 3],
}

/// Push constants of the k-nearest-neighbour kernels.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct KnnParams {
    /// The grid over the sites (unused by brute force, but for `n_sites`).
    pub grid: GridParams,
    /// Number of query points.
    pub n_queries: u32,
    /// Neighbours per query (already clamped to what exists).
    pub k: u32,
    /// 1: query `i` is site `i` and excludes itself; 0: plain points.
    pub exclude_self: u32,
    /// Padding to a 16-byte multiple.
    pub _pad: u32,
}

/// The thread index of a 1D job dispatched as a 2D grid of workgroups
/// (`x` limited to 65535 groups): `id.y` rows of `groups_x * WORKGROUP_SIZE`.
#[inline]
pub fn thread_index(global_id_x: u32, global_id_y: u32, groups_x: u32) -> usize {
    global_id_y as usize * (groups_x * WORKGROUP_SIZE) as usize + global_id_x as usize
}
