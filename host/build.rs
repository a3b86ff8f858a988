//! Compiles the kernels crate to one SPIR-V module with rust-gpu and tells
//! the library where it is (`CVD_KERNELS_SPV`), so the module is embedded.

use spirv_builder::{Capability, SpirvBuilder};
use std::path::PathBuf;

fn main() {
    let kernels = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..").join("kernels");
    let mut builder = SpirvBuilder::new(&kernels, "spirv-unknown-vulkan1.2")
        .capability(Capability::Int64)
        .capability(Capability::Int64Atomics)
        .capability(Capability::VulkanMemoryModelDeviceScope);
    builder.build_script.defaults = true;
    let result = match builder.build() {
        Ok(result) => result,
        Err(e) => {
            eprintln!("building the SPIR-V kernels failed: {e}");
            std::process::exit(1);
        }
    };
    let module = result.module.unwrap_single();
    println!("cargo::rustc-env=CVD_KERNELS_SPV={}", module.display());
    let entry_points = result.entry_points.join(",");
    println!("cargo::rustc-env=CVD_KERNELS_ENTRY_POINTS={entry_points}");
}
