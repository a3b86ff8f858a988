//! With the `vulkan` feature (the default), compiles the kernels crate with
//! rust-gpu into one SPIR-V module per entry point (rust-gpu's multimodule
//! output), each keeping only the capabilities its own code needs. The
//! library's Vulkan backend loads them, and exports them to other engines
//! (`cvd::spirv`, `cargo xtask spirv`): the modules it runs are the ones it
//! exports. They are embedded through a generated table,
//! `$OUT_DIR/kernel_modules.rs`. (rust-gpu's single module with every
//! entry point is not built: `spirv-opt` over the whole module took about
//! five times as long as over every entry point's module in turn.)
//!
//! Without it the table is empty: the CPU backend needs no SPIR-V, and the
//! build takes minutes less.

fn main() {
    #[cfg(feature = "vulkan")]
    kernels::build();
    #[cfg(not(feature = "vulkan"))]
    {
        println!("cargo::rerun-if-changed=build.rs");
        let out = std::path::PathBuf::from(std::env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
        std::fs::write(out.join("kernel_modules.rs"), "&[]").unwrap_or_else(|e| fail("writing kernel_modules.rs", e));
    }
}

fn fail(what: &str, e: impl std::fmt::Display) -> ! {
    eprintln!("{what} failed: {e}");
    std::process::exit(1);
}

#[cfg(feature = "vulkan")]
mod kernels {
    use super::fail;
    use spirv_builder::{Capability, ModuleResult, SpirvBuilder};
    use std::fmt::Write as _;
    use std::path::{Path, PathBuf};

    fn builder(kernels: &Path) -> SpirvBuilder {
        let mut builder = SpirvBuilder::new(kernels, "spirv-unknown-vulkan1.2")
            .capability(Capability::Int64)
            .capability(Capability::Int64Atomics)
            .capability(Capability::VulkanMemoryModelDeviceScope);
        builder.build_script.defaults = true;
        builder
    }

    pub(super) fn build() {
        // Cargo's runtime value: this script's compile-time one may be
        // another clone's when clones share a target directory.
        let manifest = std::env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR");
        let kernels = PathBuf::from(manifest).join("..").join("kernels");
        let multi = builder(&kernels).multimodule(true);
        let multi = multi.build().unwrap_or_else(|e| fail("building the SPIR-V kernels", e));

        let ModuleResult::MultiModule(modules) = &multi.module else {
            fail("building the SPIR-V kernels", "rust-gpu returned a single module, not one per entry point");
        };
        let out = PathBuf::from(std::env::var_os("OUT_DIR").expect("cargo sets OUT_DIR")).join("modules");
        std::fs::create_dir_all(&out).unwrap_or_else(|e| fail("creating OUT_DIR/modules", e));
        let mut table = String::from("&[\n");
        for (entry, path) in modules {
            let bytes = std::fs::read(path).unwrap_or_else(|e| fail(&format!("reading {}", path.display()), e));
            let (words, caps, exts) = trim_capabilities(&bytes);
            let name = entry.strip_prefix("entry::").unwrap_or(entry);
            let file = out.join(format!("{name}.spv"));
            let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
            std::fs::write(&file, bytes).unwrap_or_else(|e| fail(&format!("writing {}", file.display()), e));
            writeln!(
                table,
                "    KernelModule {{ name: {name:?}, entry_point: {entry:?}, spirv: include_bytes!({:?}), \
                 capabilities: &{caps:?}, extensions: &{exts:?} }},",
                file.display().to_string()
            )
            .expect("writing to a String");
        }
        table.push(']');
        let generated =
            PathBuf::from(std::env::var_os("OUT_DIR").expect("cargo sets OUT_DIR")).join("kernel_modules.rs");
        std::fs::write(&generated, table).unwrap_or_else(|e| fail("writing kernel_modules.rs", e));
    }

    /// SPIR-V opcodes read here.
    mod op {
        pub const EXTENSION: u32 = 10;
        pub const CAPABILITY: u32 = 17;
        pub const TYPE_INT: u32 = 21;
        pub const TYPE_FLOAT: u32 = 22;
        pub const CONTROL_BARRIER: u32 = 224;
        pub const MEMORY_BARRIER: u32 = 225;
        pub const ATOMIC_LOAD: u32 = 227;
        pub const ATOMIC_STORE: u32 = 228;
        pub const ATOMIC_XOR: u32 = 242;
    }

    /// Drops the capabilities a module split from a larger one no longer needs
    /// (rust-gpu computes them for the whole crate before splitting): integer
    /// and float widths no type of the module has, 64-bit atomics when no
    /// atomic works on a 64-bit integer, device scope when there is no atomic
    /// and no barrier. Returns the words, the capabilities kept and the
    /// extensions, by name.
    fn trim_capabilities(bytes: &[u8]) -> (Vec<u32>, Vec<String>, Vec<String>) {
        assert!(bytes.len().is_multiple_of(4) && bytes.len() >= 20, "a SPIR-V module is a sequence of words");
        let words: Vec<u32> = bytes.as_chunks::<4>().0.iter().map(|c| u32::from_le_bytes(*c)).collect();
        assert_eq!(words[0], 0x0723_0203, "SPIR-V magic number");
        let words = &words[..];
        let instructions = || {
            let mut at = 5;
            std::iter::from_fn(move || {
                let w = *words.get(at)?;
                let len = ((w >> 16) as usize).max(1);
                let inst = (at, w & 0xffff, &words[at + 1..(at + len).min(words.len())]);
                at += len;
                Some(inst)
            })
        };
        let mut int_widths = Vec::new();
        let mut float_widths = Vec::new();
        let mut int64_types = Vec::new();
        let (mut atomics, mut atomic_store, mut barriers) = (Vec::new(), false, false);
        let mut extensions = Vec::new();
        for (_, opcode, operands) in instructions() {
            match opcode {
                op::TYPE_INT => {
                    int_widths.push(operands[1]);
                    if operands[1] == 64 {
                        int64_types.push(operands[0]);
                    }
                }
                op::TYPE_FLOAT => float_widths.push(operands[1]),
                op::CONTROL_BARRIER | op::MEMORY_BARRIER => barriers = true,
                op::ATOMIC_STORE => atomic_store = true,
                op::ATOMIC_LOAD..=op::ATOMIC_XOR => atomics.push(operands[0]),
                op::EXTENSION => {
                    let bytes: Vec<u8> =
                        operands.iter().flat_map(|w| w.to_le_bytes()).take_while(|&b| b != 0).collect();
                    extensions.push(String::from_utf8_lossy(&bytes).into_owned());
                }
                _ => {}
            }
        }
        let atomic_int64 = (atomic_store && !int64_types.is_empty()) || atomics.iter().any(|t| int64_types.contains(t));
        let any_atomic = atomic_store || !atomics.is_empty();
        let needed = |cap: Capability| match cap {
            Capability::Int8 => int_widths.contains(&8),
            Capability::Int16 => int_widths.contains(&16),
            Capability::Int64 => int_widths.contains(&64),
            Capability::Float16 => float_widths.contains(&16),
            Capability::Float64 => float_widths.contains(&64),
            Capability::Int64Atomics => atomic_int64,
            Capability::VulkanMemoryModelDeviceScope => any_atomic || barriers,
            _ => true,
        };
        let mut kept = Vec::new();
        let mut out = words[..5].to_vec();
        for (at, opcode, operands) in instructions() {
            let len = (words[at] >> 16) as usize;
            if opcode == op::CAPABILITY {
                let cap = Capability::from_u32(operands[0]).expect("a known capability");
                if !needed(cap) {
                    continue;
                }
                kept.push(format!("{cap:?}"));
            }
            out.extend_from_slice(&words[at..at + len.max(1)]);
        }
        (out, kept, extensions)
    }
}
