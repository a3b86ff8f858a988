//! The benchmark suite behind `cargo xtask bench paper`: the layout of the
//! paper's evaluation (Table 1, Figs. 7, 8, 12 and 13) and scale runs, on
//! every backend at hand, written as Markdown tables, JSON and PNG charts.
//!
//! It lives in the library so that a test can run it end to end in a
//! reduced size ([`Config::quick`]); its timings are reported, never
//! asserted.

mod paper;
mod report;

pub use paper::{run, Section};
pub use report::{Report, Row};

use cvd::backends::vulkan::{VulkanBackend, VulkanOptions};
use cvd::error::Result;
use cvd::exec::CpuBackend;
use cvd::TetMesh;
use std::path::PathBuf;

/// What to run and where to write.
#[derive(Clone, Debug)]
pub struct Config {
    /// Folder for the tables, JSON and charts.
    pub out: PathBuf,
    /// Folder of the paper's models (those present are used).
    pub models_dir: PathBuf,
    /// CPU threads (default: all cores).
    pub threads: Option<usize>,
    /// Run the Vulkan rows too (on `device`, or the best device).
    pub vulkan: bool,
    /// The Vulkan device's index or name.
    pub device: Option<String>,
    /// Runs per measurement; the fastest is reported.
    pub repeat: usize,
    /// Reduced sizes (a small mesh, hundreds of sites): checks the suite
    /// end to end in seconds.
    pub quick: bool,
    /// Lloyd iterations of Fig. 13.
    pub iterations: usize,
    /// The largest scale run's number of sites.
    pub scale_max: usize,
    /// The sections to run.
    pub sections: Vec<Section>,
    /// Only this model (by its name in the tables).
    pub only: Option<String>,
}

impl Config {
    /// The full suite into `out`.
    pub fn full(out: PathBuf) -> Self {
        Self {
            out,
            models_dir: default_models_dir(),
            threads: None,
            vulkan: true,
            device: None,
            repeat: 3,
            quick: false,
            iterations: 30,
            scale_max: 1_000_000,
            sections: Section::ALL.to_vec(),
            only: None,
        }
    }

    /// Whether model `name` runs (see [`Config::only`]).
    pub fn wants(&self, name: &str) -> bool {
        self.only.as_ref().is_none_or(|only| only == name)
    }

    /// Every section at a size that runs in seconds, for tests.
    pub fn quick(out: PathBuf) -> Self {
        Self { repeat: 1, quick: true, iterations: 3, scale_max: 20_000, ..Self::full(out) }
    }
}

/// `$CVD_MODELS`, else `../shared/models` next to the repository.
pub fn default_models_dir() -> PathBuf {
    std::env::var_os("CVD_MODELS").map(PathBuf::from).unwrap_or_else(|| {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..").join("..").join("shared").join("models")
    })
}

/// The backends a run measures, opened once.
pub struct Backends {
    /// The CPU backend.
    pub cpu: CpuBackend,
    /// The Vulkan backend with its kernels compiled, if asked for and present.
    pub vulkan: Option<VulkanBackend>,
    /// Seconds the Vulkan driver took to compile the kernels (paid once).
    pub compile_s: Option<f64>,
    /// Why there is no Vulkan backend, if there is none.
    pub no_vulkan: Option<String>,
}

impl Backends {
    /// Opens the CPU backend and, if `config.vulkan`, the Vulkan one with
    /// every pipeline created before anything is timed.
    pub fn open(config: &Config) -> Result<Self> {
        let cpu = CpuBackend::new(config.threads)?;
        if !config.vulkan {
            return Ok(Self { cpu, vulkan: None, compile_s: None, no_vulkan: Some("not asked for".into()) });
        }
        match VulkanBackend::new(&VulkanOptions { device: config.device.clone(), ..Default::default() }) {
            Ok(v) => {
                let compile = v.warm_up()?;
                Ok(Self { cpu, vulkan: Some(v), compile_s: Some(compile), no_vulkan: None })
            }
            Err(e) => Ok(Self { cpu, vulkan: None, compile_s: None, no_vulkan: Some(e.to_string()) }),
        }
    }
}

/// A model of the suite: a name, its mesh, and the paper's site count.
pub struct Model {
    /// Name in the tables.
    pub name: String,
    /// The mesh.
    pub mesh: TetMesh,
    /// Sites the paper uses with it (Table 1).
    pub sites: usize,
}

impl Model {
    /// A built-in model at `resolution` (default: its own).
    pub fn builtin(name: &str, resolution: Option<u32>) -> Result<Self> {
        let mesh = cvd::mesher::models::builtin(name, resolution)?;
        let sites = cvd::mesher::models::default_sites(name)?;
        Ok(Self { name: name.to_string(), mesh, sites })
    }

    /// `name.mesh` from the models folder, if it is there and reads.
    pub fn from_folder(config: &Config, name: &str, sites: usize) -> Option<Self> {
        let path = config.models_dir.join(format!("{name}.mesh"));
        let mesh = cvd_io::read_mesh(&path).ok()?;
        Some(Self { name: name.to_string(), mesh, sites })
    }
}
