//! # cvd: clipped Voronoi diagrams on Vulkan GPUs and CPU cores
//!
//! The algorithms live once in the `cvd-kernels` crate; this library runs
//! them on a Vulkan device ([`vulkan::VulkanBackend`]) or on CPU cores
//! ([`cpu::CpuBackend`]), behind one [`Backend`] trait.
//!
//! ```no_run
//! use cvd::{backends, KnnJob, KnnMethod};
//! let sites = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 2.0, 0.0]];
//! let backend = backends::open(&Default::default())?;
//! let nn = KnnJob::sites(&sites, 1, KnnMethod::Grid)?.run(backend.as_ref())?;
//! assert_eq!(nn.of(0), &[1]);
//! # Ok::<(), cvd::Error>(())
//! ```

// The layers, lowest first: a module imports only from its own layer or
// below (`cargo xtask layers` checks that no two import each other).
pub mod error;

pub mod geom;

pub mod job;

pub mod exec;

pub mod passes;

pub mod backend;

pub mod backends;

pub mod diagram;

pub mod cvt;

// Leaves beside the layers: meshing shapes over `geom`, the SPIR-V export.
pub mod mesher;
pub mod spirv;

pub use backend::Backend;
pub use backends::{BackendChoice, BackendOptions};
pub use diagram::particles::{IndexThresholds, ParticleCells, INDEX_ORDERS};
pub use diagram::periodic::{PeriodicCells, PeriodicVoronoi};
pub use diagram::trajectory::FrameLists;
pub use diagram::voronoi::{Cells, ClippedVoronoi, Counters};
pub use error::{Error, Result};
pub use exec::CpuBackend;
pub use geom::mesh::TetMesh;
pub use geom::periodic_box::PeriodicBox;
pub use job::clip::{JobShape, Pairing, Strategy};
pub use job::knn::{KnnJob, KnnMethod, Neighbors};
pub use job::BackendKind;
pub use passes::pieces::{Piece, Pieces};
