//! The commands besides `run`: `devices`, `knn` and `spirv`.

use crate::args::KnnArgs;
use cvd::backends::{self, vulkan};
use cvd::{geom::points, KnnJob};
use std::path::Path;

/// `cvd knn`: the k nearest neighbours of uniform sites on a backend,
/// checked against the CPU backend.
pub fn knn(args: &KnnArgs) -> cvd::Result<()> {
    let backend = backends::open(&args.backend.options())?;
    // The sites, their quantized copy, and three runs' lists and distances.
    let bytes = (args.sites as u64).saturating_mul(64 + 36 * args.k as u64);
    cvd::job::memory::check(&format!("k-NN of {} sites", args.sites), bytes, None)?;
    let sites = points::uniform(args.sites, args.seed);
    let job = KnnJob::sites(&sites, args.k, args.method)?;
    println!("k-NN of {} uniform sites, k = {}, {:?}, on {}", args.sites, job.params.k, args.method, backend.name());
    let first = job.run(backend.as_ref())?;
    let again = job.run(backend.as_ref())?;
    println!("first run: {}", first.timings);
    println!("second run: {} (total {:.3} ms)", again.timings, again.timings.total() * 1e3);
    let reference = job.run(&cvd::exec::CpuBackend::new(args.backend.threads)?)?;
    let same = reference.indices == again.indices && reference.dist2 == again.dist2;
    println!("same neighbours as the CPU backend: {}", if same { "yes" } else { "NO" });
    if !same {
        return Err(cvd::Error::Internal("the backend disagrees with the CPU backend".into()));
    }
    Ok(())
}

/// `cvd devices`: the Vulkan devices, or none (no loader, no driver).
pub fn devices(json: bool) -> cvd::Result<()> {
    let devices = match vulkan::list_devices() {
        Ok(devices) => devices,
        Err(cvd::Error::VulkanUnavailable(why)) => {
            if !json {
                println!("no Vulkan device: {why}");
            }
            Vec::new()
        }
        Err(e) => return Err(e),
    };
    if json {
        let list: Vec<serde_json::Value> = devices
            .iter()
            .map(|d| serde_json::json!({ "index": d.index, "name": d.name, "type": d.kind_name(), "gpu": d.is_gpu() }))
            .collect();
        let text = serde_json::to_string_pretty(&list).map_err(|e| cvd::Error::Internal(e.to_string()))?;
        println!("{text}");
        return Ok(());
    }
    for d in &devices {
        println!("{}: {} ({})", d.index, d.name, d.kind_name());
    }
    if !vulkan::HAS_KERNELS {
        println!("(this build has no SPIR-V kernels: it runs on the CPU backend only)");
    }
    Ok(())
}

/// `cvd spirv`: the kernels as SPIR-V modules and their manifest in `out`.
pub fn spirv(out: &Path) -> cvd::Result<()> {
    let files = cvd::spirv::export(out)?;
    println!("wrote {} files into {} (ABI version {})", files.len(), out.display(), abi_version());
    Ok(())
}

fn abi_version() -> u64 {
    cvd::spirv::manifest()["abi_version"].as_u64().unwrap_or(0)
}
