//! What the benchmarks share: the Vulkan device with its kernels compiled
//! before anything is timed.

use cvd::backends::vulkan::{VulkanBackend, VulkanOptions};

pub use cvd_bench::default_models_dir;

/// The Vulkan backend with every pipeline created (drivers may compile
/// for seconds on first use), or `None` — said on stdout — without one.
pub fn warm_vulkan(device: Option<String>) -> Option<VulkanBackend> {
    match VulkanBackend::new(&VulkanOptions { device, ..Default::default() }) {
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
