//! # cvd: clipped Voronoi diagrams on Vulkan GPUs and CPU cores
//!
//! The algorithms live once in the `cvd-kernels` crate; this library runs
//! them on a Vulkan device ([`vulkan::VulkanBackend`]) or on CPU cores
//! ([`cpu::CpuBackend`]), behind one [`Backend`] trait.
//!
//! ```no_run
//! use cvd::{backend, KnnJob, KnnMethod};
//! let sites = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 2.0, 0.0]];
//! let backend = backend::open(&Default::default())?;
//! let nn = KnnJob::sites(&sites, 1, KnnMethod::Grid)?.run(backend.as_ref())?;
//! assert_eq!(nn.of(0), &[1]);
//! # Ok::<(), cvd::Error>(())
//! ```

pub mod backend;
pub mod bench;
pub mod cpu;
pub mod cvt;
pub mod density;
pub mod diagram;
pub mod distributed;
pub mod error;
pub mod io;
pub mod knn;
pub mod mesh;
pub mod mesher;
pub mod output;
pub mod points;
pub mod quantize;
pub mod site_grid;
pub mod spirv;
pub mod surface;
pub mod timing;
pub mod vec3;
pub mod vulkan;

pub use backend::{Backend, BackendKind, BackendOptions};
pub use diagram::periodic::{PeriodicBox, PeriodicCells, PeriodicVoronoi};
pub use diagram::pieces::{Piece, Pieces};
pub use diagram::voronoi::{Cells, ClippedVoronoi, Counters, Pairing, Strategy};
pub use error::{Error, Result};
pub use knn::{KnnJob, KnnMethod, Neighbors};
pub use mesh::TetMesh;
