//! What the model benchmarks share: where the models are, and the Vulkan
//! device with its kernels compiled before anything is timed.

use cvd::vulkan::{VulkanBackend, VulkanOptions};
use std::path::PathBuf;

/// `$CVD_MODELS`, else `../shared/models` next to the repository.
pub fn default_models_dir() -> PathBuf {
    std::env::var_os("CVD_MODELS").map(PathBuf::from).unwrap_or_else(|| {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..").join("..").join("shared").join("models")
    })
}

/// The Vulkan backend with every pipeline created (drivers may compile
/// for seconds on first use), or `None` — said on stdout — without one.
pub fn warm_vulkan(device: Option<String>) -> Option<VulkanBackend> {
    match VulkanBackend::new(&VulkanOptions { device, validation: false }) {
        Ok(v) => {
            let compile = v.warm_up().expect("warm-up");
            println!("Vulkan device: {} (kernel compilation on first use, paid once: {compile:.2} s)", v.device().name);
            Some(v)
        }
        Err(e) => {
            println!("Vulkan: {e} (Vulkan rows skipped)");
            None
        }
    }
}
