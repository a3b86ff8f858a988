//! The kernels as SPIR-V for other Vulkan engines: one module per entry
//! point, each declaring only the capabilities its own code needs, and a
//! manifest (`manifest.json`) that gives, for every module, its entry
//! point, workgroup size, descriptor bindings with their element layouts,
//! push-constant layout, capabilities, extensions and the Vulkan features
//! they need. The manifest is written from the same Rust types and table
//! the kernels and this library use (`cvd_kernels::layout`,
//! `cvd_kernels::interface`). `docs/EMBEDDING.md` describes a whole job.

use crate::error::{Error, Result};
use cvd_kernels::abi::{self, counter, lloyd_stat};
use cvd_kernels::interface::{self, Access, ENTRY_POINTS};
use cvd_kernels::layout::{Kind, TypeLayout};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};

/// One exported module.
#[derive(Clone, Copy, Debug)]
pub struct KernelModule {
    /// The entry point's name in `cvd_kernels::entry` (and the file's stem).
    pub name: &'static str,
    /// Its SPIR-V entry point name.
    pub entry_point: &'static str,
    /// The module.
    pub spirv: &'static [u8],
    /// The capabilities the module declares (SPIR-V names).
    pub capabilities: &'static [&'static str],
    /// The extensions the module declares.
    pub extensions: &'static [&'static str],
}

/// Every exported module, built by rust-gpu with the library.
pub const MODULES: &[KernelModule] = include!(concat!(env!("OUT_DIR"), "/kernel_modules.rs"));

/// The SPIR-V target the modules are compiled for.
pub const TARGET: &str = "spirv-unknown-vulkan1.2";

/// The Vulkan device feature a SPIR-V capability needs (structure and
/// member), if any.
pub fn feature_for(capability: &str) -> Option<&'static str> {
    Some(match capability {
        "Int8" => "VkPhysicalDeviceVulkan12Features.shaderInt8",
        "Int16" => "VkPhysicalDeviceFeatures.shaderInt16",
        "Int64" => "VkPhysicalDeviceFeatures.shaderInt64",
        "Float16" => "VkPhysicalDeviceVulkan12Features.shaderFloat16",
        "Float64" => "VkPhysicalDeviceFeatures.shaderFloat64",
        "Int64Atomics" => "VkPhysicalDeviceVulkan12Features.shaderBufferInt64Atomics",
        "VulkanMemoryModel" => "VkPhysicalDeviceVulkan12Features.vulkanMemoryModel",
        "VulkanMemoryModelDeviceScope" => "VkPhysicalDeviceVulkan12Features.vulkanMemoryModelDeviceScope",
        "AtomicFloat32AddEXT" => "VkPhysicalDeviceShaderAtomicFloatFeaturesEXT.shaderBufferFloat32AtomicAdd",
        _ => return None,
    })
}

fn layout_json(t: &TypeLayout) -> Value {
    let mut v = json!({ "type": t.name, "size": t.size, "align": t.align });
    match t.kind {
        Kind::Scalar => {}
        Kind::Array { element, len } => {
            v["len"] = json!(len);
            v["element"] = layout_json(&element());
        }
        Kind::Struct(fields) => {
            let fields: Vec<Value> = fields
                .iter()
                .map(|f| {
                    let mut field = json!({ "name": f.name, "offset": f.offset });
                    if let (Value::Object(to), Value::Object(from)) = (&mut field, layout_json(&(f.ty)())) {
                        to.extend(from);
                    }
                    field
                })
                .collect();
            v["fields"] = json!(fields);
        }
    }
    v
}

/// Every scalar of a type, flattened: `{ "path": "grid.dim_x", "offset", "type" }`.
fn scalars_json(t: &TypeLayout) -> Value {
    let mut out = Vec::new();
    t.for_each_scalar(&mut |path, index, offset, s| {
        let mut name = path.join(".");
        if let Some(i) = index {
            name.push_str(&format!("[{i}]"));
        }
        out.push(json!({ "path": name, "offset": offset, "type": s.name, "size": s.size }));
    });
    Value::Array(out)
}

/// The manifest of [`MODULES`].
pub fn manifest() -> Value {
    let modules: Vec<Value> = ENTRY_POINTS
        .iter()
        .map(|e| {
            let m = MODULES.iter().find(|m| m.entry_point == e.spirv_name);
            let (capabilities, extensions) = m.map_or((&[][..], &[][..]), |m| (m.capabilities, m.extensions));
            let features: Vec<&str> = capabilities.iter().filter_map(|c| feature_for(c)).collect();
            let push = (e.push_constants)();
            let bindings: Vec<Value> = e
                .bindings
                .iter()
                .enumerate()
                .map(|(i, b)| {
                    let element = (b.element)();
                    json!({
                        "set": 0,
                        "binding": i,
                        "name": b.name,
                        "descriptor_type": "STORAGE_BUFFER",
                        "access": match b.access { Access::ReadOnly => "read_only", Access::ReadWrite => "read_write" },
                        "array_stride": element.size,
                        "element": layout_json(&element),
                        "doc": b.doc,
                    })
                })
                .collect();
            json!({
                "name": e.name,
                "file": format!("{}.spv", e.name),
                "entry_point": e.spirv_name,
                "doc": e.doc,
                "workgroup_size": [e.workgroup_size, 1, 1],
                "capabilities": capabilities,
                "extensions": extensions,
                "device_features": features,
                "push_constants": {
                    "offset": 0,
                    "size": push.size,
                    "layout": layout_json(&push),
                    "scalars": scalars_json(&push),
                },
                "bindings": bindings,
            })
        })
        .collect();
    json!({
        "abi_version": interface::ABI_VERSION,
        "abi_fingerprint": format!("{:#018x}", interface::ABI_FINGERPRINT),
        "generator": concat!("cvd ", env!("CARGO_PKG_VERSION")),
        "spirv_target": TARGET,
        "vulkan_api_version": "1.2",
        "dispatch": "every kernel runs workgroup_size threads per workgroup on a 2D grid of workgroups: \
                     thread index = global_id.y * (num_workgroups.x * workgroup_size) + global_id.x; \
                     threads past the job's count return at once, so round up",
        "constants": {
            "WORKGROUP_SIZE": abi::WORKGROUP_SIZE,
            "QUANT_BITS": abi::QUANT_BITS,
            "QUANT_MAX": abi::QUANT_MAX,
            "NO_SITE": abi::NO_SITE,
            "INCOMPLETE_TET": abi::INCOMPLETE_TET,
            "OUT_OF_HALO": abi::OUT_OF_HALO,
            "ACCUM_PER_SITE": abi::ACCUM_PER_SITE,
            "SCAN_BLOCK": cvd_kernels::scan::SCAN_BLOCK,
            "CELL_RECORDS": cvd_kernels::clip::CELL_RECORDS,
            "counter": {
                "PAIRS": counter::PAIRS,
                "NONEMPTY": counter::NONEMPTY,
                "CLIPS": counter::CLIPS,
                "SECURITY_MISSED": counter::SECURITY_MISSED,
                "OVERFLOWS": counter::OVERFLOWS,
                "BROKEN": counter::BROKEN,
                "FILTERED": counter::FILTERED,
                "WALKS": counter::WALKS,
                "HALO": counter::HALO,
                "WHOLE": counter::WHOLE,
                "CUT": counter::CUT,
                "COUNT": counter::COUNT,
            },
            "lloyd_stat": {
                "ENERGY": lloyd_stat::ENERGY,
                "EMPTY": lloyd_stat::EMPTY,
                "UNFINISHED": lloyd_stat::UNFINISHED,
                "STILL": lloyd_stat::STILL,
                "COUNT": lloyd_stat::COUNT,
            },
        },
        "modules": modules,
    })
}

/// Writes every module (`NAME.spv`) and `manifest.json` into `dir`
/// (created if needed); returns the files written.
pub fn export(dir: &Path) -> Result<Vec<PathBuf>> {
    let io = |path: &Path, source: std::io::Error| Error::Write { path: path.display().to_string(), source };
    std::fs::create_dir_all(dir).map_err(|e| io(dir, e))?;
    let mut written = Vec::new();
    for m in MODULES {
        let path = dir.join(format!("{}.spv", m.name));
        std::fs::write(&path, m.spirv).map_err(|e| io(&path, e))?;
        written.push(path);
    }
    let path = dir.join("manifest.json");
    let text = serde_json::to_string_pretty(&manifest()).expect("the manifest is plain JSON") + "\n";
    std::fs::write(&path, text).map_err(|e| io(&path, e))?;
    written.push(path);
    Ok(written)
}
