//! The backends — the CPU runtime's ([`CpuBackend`]), Vulkan's
//! ([`vulkan`]) and a job in parts ([`distributed`]) — and how one is
//! chosen and opened from [`BackendOptions`].

mod cpu;
pub mod distributed;
pub mod vulkan;

use crate::backend::Backend;
use crate::error::{Error, Result};
use crate::exec::CpuBackend;
use vulkan::{list_devices, DeviceInfo, VulkanBackend, VulkanOptions, HAS_KERNELS};

/// A backend and why it was chosen.
pub struct Chosen {
    /// The backend.
    pub backend: Box<dyn Backend>,
    /// Why this one, in a few words (e.g. "asked for", "auto: the GPU
    /// NAME", "auto: no Vulkan device").
    pub why: String,
}

/// What [`BackendChoice::Auto`] does with the Vulkan devices found.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum AutoChoice {
    /// Vulkan on the device of this index.
    Gpu(usize),
    /// The CPU backend, for this reason.
    Cpu(String),
}

/// [`BackendChoice::Auto`]'s rule: the first real GPU, by kind (discrete,
/// integrated, virtual), when this build has the kernels; otherwise the CPU
/// backend, saying why.
pub fn auto_choice(devices: &[DeviceInfo], has_kernels: bool) -> AutoChoice {
    let gpu = devices.iter().filter_map(|d| Some((d.gpu_rank()?, d))).min_by_key(|&(rank, d)| (rank, d.index));
    match gpu.map(|(_, d)| d) {
        Some(d) if has_kernels => AutoChoice::Gpu(d.index),
        Some(d) => AutoChoice::Cpu(format!(
            "auto: the GPU {} was found, but this build has no SPIR-V kernels (build with --features vulkan)",
            d.name
        )),
        None if devices.is_empty() => AutoChoice::Cpu("auto: no Vulkan device".into()),
        None => {
            let names: Vec<&str> = devices.iter().map(|d| d.name.as_str()).collect();
            AutoChoice::Cpu(format!(
                "auto: no GPU ({} is Vulkan on the CPU, slower than the CPU backend: --backend vulkan uses it)",
                names.join(", ")
            ))
        }
    }
}

/// Opens the backend the options ask for (see [`choose`]).
pub fn open(options: &BackendOptions) -> Result<Box<dyn Backend>> {
    choose(options).map(|c| c.backend)
}

/// Opens the backend the options ask for, and says why. With `Auto`, a
/// Vulkan device is used only if it is a real GPU (or `--device` names
/// one): see [`auto_choice`]; a GPU that cannot run the kernels leaves the
/// CPU backend to serve, with the reason.
pub fn choose(options: &BackendOptions) -> Result<Chosen> {
    Ok(match decide(options)? {
        Decided::Cpu(why) => Chosen { backend: Box::new(CpuBackend::new(options.threads)?), why },
        Decided::Vulkan(vulkan, why) => Chosen { backend: vulkan, why },
    })
}

/// What [`decide`] settled on.
pub enum Decided {
    /// The CPU backend (not opened: the caller opens it, once), for this
    /// reason.
    Cpu(String),
    /// A Vulkan device, opened, and why.
    Vulkan(Box<VulkanBackend>, String),
}

/// [`choose`]'s decision, opening a Vulkan device when it takes one and
/// leaving the CPU backend to its caller (who may hold one already).
pub fn decide(options: &BackendOptions) -> Result<Decided> {
    let vulkan = |vulkan: &VulkanOptions, why: String| Ok(Decided::Vulkan(Box::new(VulkanBackend::new(vulkan)?), why));
    match options.choice {
        BackendChoice::Cpu => Ok(Decided::Cpu("asked for".into())),
        BackendChoice::Vulkan => vulkan(&options.vulkan, "asked for".into()),
        BackendChoice::Auto if options.vulkan.device.is_some() => {
            vulkan(&options.vulkan, "the device asked for".into())
        }
        BackendChoice::Auto => {
            // Loading the Vulkan drivers costs tens of megabytes that stay
            // mapped: not where no GPU can be.
            if let Some(why) = no_gpu_node() {
                return Ok(Decided::Cpu(format!("auto: no GPU ({why})")));
            }
            let devices = match list_devices() {
                Ok(devices) => devices,
                Err(Error::VulkanUnavailable(why)) => {
                    return Ok(Decided::Cpu(format!("auto: no Vulkan device ({why})")))
                }
                Err(e) => return Ok(Decided::Cpu(format!("auto: no Vulkan device ({e})"))),
            };
            match auto_choice(&devices, HAS_KERNELS) {
                AutoChoice::Cpu(why) => Ok(Decided::Cpu(why)),
                AutoChoice::Gpu(index) => {
                    let name = devices.iter().find(|d| d.index == index).map_or("", |d| &d.name);
                    let chosen = VulkanOptions { device: Some(index.to_string()), ..options.vulkan.clone() };
                    match VulkanBackend::new(&chosen) {
                        Ok(vk) => Ok(Decided::Vulkan(Box::new(vk), format!("auto: the GPU {name}"))),
                        Err(e) => Ok(Decided::Cpu(format!("auto: the GPU {name} cannot run the kernels ({e})"))),
                    }
                }
            }
        }
    }
}

/// On Linux, why no GPU can be here: none of the device nodes a GPU's
/// driver opens (DRM's `/dev/dri`, NVIDIA's `/dev/nvidia*`, WSL's
/// `/dev/dxg`) exists. `None` elsewhere, or where one does.
fn no_gpu_node() -> Option<String> {
    if !cfg!(target_os = "linux") {
        return None;
    }
    let any_in = |dir: &str, prefixes: &[&str]| {
        std::fs::read_dir(dir).is_ok_and(|entries| {
            entries.flatten().any(|e| prefixes.iter().any(|p| e.file_name().to_string_lossy().starts_with(p)))
        })
    };
    let node = any_in("/dev/dri", &["renderD", "card"]) || any_in("/dev", &["nvidia", "dxg"]);
    (!node).then(|| "no device node: /dev/dri, /dev/nvidia*, /dev/dxg".into())
}

/// Which backend to use.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum BackendChoice {
    /// Vulkan on a real GPU (discrete, integrated or virtual) if there is
    /// one, else the CPU backend. A Vulkan device that runs on the CPU
    /// (lavapipe, SwiftShader) is slower than the CPU backend: it is used
    /// only when asked for.
    #[default]
    Auto,
    /// The CPU backend (rayon).
    Cpu,
    /// The Vulkan backend on the best device (or `--device`), GPU or not;
    /// fails if there is none.
    Vulkan,
}

impl BackendChoice {
    /// Its name on the command line: `auto`, `cpu`, `vulkan`.
    pub fn name(self) -> &'static str {
        match self {
            BackendChoice::Auto => "auto",
            BackendChoice::Cpu => "cpu",
            BackendChoice::Vulkan => "vulkan",
        }
    }

    /// Every choice, in the order above.
    pub const ALL: [BackendChoice; 3] = [BackendChoice::Auto, BackendChoice::Cpu, BackendChoice::Vulkan];

    /// The choice of this [`name`](Self::name), if any.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|c| c.name() == name)
    }
}

/// Options for choosing and configuring a backend.
#[derive(Clone, Debug, Default)]
pub struct BackendOptions {
    /// Which backend.
    pub choice: BackendChoice,
    /// CPU threads (None: all cores).
    pub threads: Option<usize>,
    /// Vulkan device selection and validation.
    pub vulkan: VulkanOptions,
}

#[cfg(test)]
mod tests {
    use super::*;
    use ash::vk::PhysicalDeviceType as T;

    fn device(index: usize, name: &str, kind: T) -> DeviceInfo {
        DeviceInfo { index, name: name.into(), kind, api_version: ash::vk::API_VERSION_1_3 }
    }

    #[test]
    fn auto_never_picks_a_cpu_implemented_device() {
        let lavapipe = device(0, "llvmpipe (LLVM 15.0.6, 256 bits)", T::CPU);
        let swiftshader = device(1, "SwiftShader Device (Subzero)", T::CPU);
        let AutoChoice::Cpu(why) = auto_choice(&[lavapipe.clone(), swiftshader], true) else {
            panic!("auto picked a CPU-implemented Vulkan device");
        };
        assert!(why.contains("llvmpipe") && why.contains("--backend vulkan"), "{why}");
        assert_eq!(auto_choice(&[], true), AutoChoice::Cpu("auto: no Vulkan device".into()));
        // A real GPU wins wherever it is listed, the discrete one first.
        let igpu = device(1, "Intel(R) UHD Graphics", T::INTEGRATED_GPU);
        let dgpu = device(2, "NVIDIA GeForce RTX 4090", T::DISCRETE_GPU);
        assert_eq!(auto_choice(&[lavapipe.clone(), igpu.clone()], true), AutoChoice::Gpu(1));
        assert_eq!(auto_choice(&[lavapipe.clone(), igpu.clone(), dgpu], true), AutoChoice::Gpu(2));
        assert_eq!(auto_choice(&[device(0, "virtio-gpu", T::VIRTUAL_GPU)], true), AutoChoice::Gpu(0));
        // A build without the kernels cannot use the GPU, and says so.
        let AutoChoice::Cpu(why) = auto_choice(&[lavapipe, igpu], false) else {
            panic!("a build without kernels picked Vulkan");
        };
        assert!(why.contains("Intel(R) UHD Graphics") && why.contains("no SPIR-V kernels"), "{why}");
    }

    #[test]
    fn auto_skips_the_drivers_only_where_no_gpu_can_be() {
        // Without a GPU's device node, no device the drivers list is a GPU
        // (here: lavapipe alone, or no Vulkan at all).
        if no_gpu_node().is_some() {
            let devices = list_devices().unwrap_or_default();
            assert!(devices.iter().all(|d| d.gpu_rank().is_none()), "a GPU without a device node: {devices:?}");
            let options = BackendOptions { choice: BackendChoice::Auto, threads: Some(1), ..Default::default() };
            let Ok(Decided::Cpu(why)) = decide(&options) else { panic!("auto took a device") };
            assert!(why.starts_with("auto: no GPU (no device node"), "{why}");
        }
        let asked = BackendOptions { choice: BackendChoice::Cpu, ..Default::default() };
        assert!(matches!(decide(&asked), Ok(Decided::Cpu(why)) if why == "asked for"));
    }
}
