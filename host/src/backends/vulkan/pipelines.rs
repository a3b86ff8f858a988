//! Compute pipelines for the kernels' entry points, each from its own
//! embedded SPIR-V module (the modules the library exports:
//! [`crate::spirv::MODULES`]), created on first use (a driver may take
//! seconds to compile one: lavapipe does).

use super::context::Context;
use crate::error::{Error, Result, VkContext};
use ash::vk;
use cvd_kernels::interface::EntryPoint;
use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

/// The interface of one entry point: storage buffers at bindings
/// `0..bindings` of set 0, and a push-constant block.
#[derive(Clone, Copy, Debug)]
pub(crate) struct KernelSpec {
    pub name: &'static str,
    pub spirv_name: &'static str,
    pub bindings: u32,
    pub push_size: u32,
}

/// Every entry point in `cvd_kernels::entry`, from the kernels' own table
/// (the one the exported manifest is written from).
pub(crate) const KERNELS: &[EntryPoint] = cvd_kernels::interface::ENTRY_POINTS;

/// A ready compute pipeline.
pub(crate) struct Kernel {
    pub spec: KernelSpec,
    module: vk::ShaderModule,
    pub set_layout: vk::DescriptorSetLayout,
    pub layout: vk::PipelineLayout,
    pub pipeline: vk::Pipeline,
}

/// The pipelines made so far.
pub(crate) struct Pipelines {
    device: ash::Device,
    cache: vk::PipelineCache,
    made: Mutex<HashMap<&'static str, Arc<Kernel>>>,
    /// Nanoseconds spent creating pipelines (the driver compiles them).
    compile_ns: AtomicU64,
}

impl Pipelines {
    pub(crate) fn new(ctx: &Context) -> Result<Self> {
        // SAFETY: empty cache.
        let cache = unsafe { ctx.device.create_pipeline_cache(&vk::PipelineCacheCreateInfo::default(), None) }
            .call("vkCreatePipelineCache")?;
        Ok(Self { device: ctx.device.clone(), cache, made: Mutex::new(HashMap::new()), compile_ns: AtomicU64::new(0) })
    }

    /// The pipeline for entry point `name`, created if needed.
    pub(crate) fn get(&self, name: &str) -> Result<Arc<Kernel>> {
        let mut made = self.made.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(k) = made.get(name) {
            return Ok(k.clone());
        }
        let e = KERNELS
            .iter()
            .find(|k| k.name == name)
            .ok_or_else(|| Error::InvalidInput(format!("no kernel named {name}")))?;
        let spec = KernelSpec {
            name: e.name,
            spirv_name: e.spirv_name,
            bindings: e.bindings.len() as u32,
            push_size: e.push_size() as u32,
        };
        let start = std::time::Instant::now();
        let kernel = Arc::new(self.create(spec)?);
        self.compile_ns.fetch_add(start.elapsed().as_nanos() as u64, Ordering::Relaxed);
        made.insert(spec.name, kernel.clone());
        Ok(kernel)
    }

    /// Seconds spent creating pipelines so far.
    pub(crate) fn compile_seconds(&self) -> f64 {
        self.compile_ns.load(Ordering::Relaxed) as f64 * 1e-9
    }

    fn create(&self, spec: KernelSpec) -> Result<Kernel> {
        let dev = &self.device;
        let spirv = crate::spirv::MODULES.iter().find(|m| m.entry_point == spec.spirv_name).map(|m| m.spirv);
        let spirv = spirv.ok_or_else(|| Error::Internal(format!("no SPIR-V module for the kernel {}", spec.name)))?;
        let words = ash::util::read_spv(&mut std::io::Cursor::new(spirv))
            .map_err(|e| Error::Internal(format!("the embedded SPIR-V of {} is malformed: {e}", spec.name)))?;
        // SAFETY: valid SPIR-V from the build.
        let module = unsafe { dev.create_shader_module(&vk::ShaderModuleCreateInfo::default().code(&words), None) }
            .call("vkCreateShaderModule")?;
        let bindings: Vec<_> = (0..spec.bindings)
            .map(|b| {
                vk::DescriptorSetLayoutBinding::default()
                    .binding(b)
                    .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                    .descriptor_count(1)
                    .stage_flags(vk::ShaderStageFlags::COMPUTE)
            })
            .collect();
        let info = vk::DescriptorSetLayoutCreateInfo::default().bindings(&bindings);
        // SAFETY: valid create infos throughout.
        let set_layout =
            unsafe { dev.create_descriptor_set_layout(&info, None) }.call("vkCreateDescriptorSetLayout")?;
        let ranges = [vk::PushConstantRange::default().stage_flags(vk::ShaderStageFlags::COMPUTE).size(spec.push_size)];
        let set_layouts = [set_layout];
        let info = vk::PipelineLayoutCreateInfo::default().set_layouts(&set_layouts).push_constant_ranges(&ranges);
        let layout = unsafe { dev.create_pipeline_layout(&info, None) }.call("vkCreatePipelineLayout")?;
        let entry = std::ffi::CString::new(spec.spirv_name).expect("kernel names have no NUL");
        let stage = vk::PipelineShaderStageCreateInfo::default()
            .stage(vk::ShaderStageFlags::COMPUTE)
            .module(module)
            .name(&entry);
        let info = [vk::ComputePipelineCreateInfo::default().stage(stage).layout(layout)];
        let pipeline = unsafe { dev.create_compute_pipelines(self.cache, &info, None) }
            .map_err(|(_, e)| Error::Vulkan { call: "vkCreateComputePipelines", result: e })?[0];
        Ok(Kernel { spec, module, set_layout, layout, pipeline })
    }
}

impl Drop for Pipelines {
    fn drop(&mut self) {
        let made = self.made.get_mut().unwrap_or_else(|e| e.into_inner());
        // SAFETY: the device is idle when the backend is dropped.
        unsafe {
            for k in made.values() {
                self.device.destroy_pipeline(k.pipeline, None);
                self.device.destroy_pipeline_layout(k.layout, None);
                self.device.destroy_descriptor_set_layout(k.set_layout, None);
                self.device.destroy_shader_module(k.module, None);
            }
            self.device.destroy_pipeline_cache(self.cache, None);
        }
    }
}
