//! Kernels for clipped Voronoi diagrams, written once.
//!
//! Every algorithm here is a plain function over slices (a *body*), called
//! once per thread index. The same body is compiled to SPIR-V by rust-gpu and
//! called by thin `#[spirv(compute)]` entry points ([`entry`]), and it is
//! called natively by the host's CPU backend, one call per thread index. So
//! the CPU and the GPU run the same code, and the tests compare the two.
//!
//! Types that cross the CPU/GPU boundary live in [`abi`], defined once.
//! On the host, [`layout`] describes their memory layout and [`interface`]
//! lists every entry point's bindings and push constants: the exported
//! SPIR-V's manifest is written from them (see `docs/EMBEDDING.md`).
#![no_std]
#![deny(missing_docs)]
// Kernel bodies take each buffer they touch as an argument.
#![allow(clippy::too_many_arguments)]

#[cfg(test)]
extern crate std;

/// The glam the kernels use (spirv-std's), for hosts that call the bodies.
pub use spirv_std::glam;

pub mod abi;
pub mod buffers;
pub mod cell;
pub mod clip;
pub mod entry;
pub mod grid;
#[cfg(not(target_arch = "spirv"))]
pub mod interface;
pub mod knn;
#[cfg(not(target_arch = "spirv"))]
pub mod layout;
pub mod lists;
pub mod lloyd;
pub mod polyhedron;
pub mod refine;
pub mod scan;
pub mod walk;
pub mod whole;
