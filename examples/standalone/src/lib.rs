//! The clipped Voronoi volumes of sites in a tet mesh, from the exported
//! SPIR-V modules and their `manifest.json`, with nothing but ash: a
//! Vulkan engine's view of the kernels (see `docs/EMBEDDING.md`).
//!
//! The job is the tet-cell strategy with flood pairing: build the site grid
//! (count, scan, scatter, sort), find each site's nearest sites and each
//! tet's nearest site, clip every tet (`clip_flood`), redo what the first
//! pass could not finish (`refine`), and read the fixed-point sums back.
//! The manifest gives each module's file, entry point, bindings and
//! push-constant layout; push constants are written field by field at the
//! offsets it lists.

use ash::vk;
use serde_json::Value;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// What [`run`] computes.
#[derive(Clone, Debug)]
pub struct Output {
    /// The Vulkan device used.
    pub device: String,
    /// Volume of each site's clipped cell, in input order.
    pub volumes: Vec<f64>,
    /// The kernels' counters (see the manifest's `constants.counter`).
    pub counters: Vec<i64>,
    /// Entries the first pass left to the second.
    pub unfinished_first: u32,
    /// Entries even the second pass could not finish (their volume is
    /// missing; the library finishes those on the host).
    pub unfinished_after: u32,
}

/// The unit cube in `n`³ sub-cubes of six tets each, positively oriented.
pub fn cube_mesh(n: u32) -> (Vec<[f64; 3]>, Vec<[u32; 4]>) {
    let id = |i: u32, j: u32, k: u32| (k * (n + 1) + j) * (n + 1) + i;
    let mut verts = Vec::new();
    for k in 0..=n {
        for j in 0..=n {
            for i in 0..=n {
                verts.push([i, j, k].map(|c| c as f64 / n as f64));
            }
        }
    }
    let mut tets = Vec::new();
    const PATHS: [[usize; 3]; 6] = [[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]];
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                for path in PATHS {
                    // From the corner (i, j, k) to the opposite one, one axis at a time.
                    let mut c = [i, j, k];
                    let mut t = [id(c[0], c[1], c[2]), 0, 0, 0];
                    for (s, &axis) in path.iter().enumerate() {
                        c[axis] += 1;
                        t[s + 1] = id(c[0], c[1], c[2]);
                    }
                    let p = t.map(|v| verts[v as usize]);
                    let e = [1, 2, 3].map(|a| [0, 1, 2].map(|x| p[a][x] - p[0][x]));
                    let det = e[0][0] * (e[1][1] * e[2][2] - e[1][2] * e[2][1])
                        - e[0][1] * (e[1][0] * e[2][2] - e[1][2] * e[2][0])
                        + e[0][2] * (e[1][0] * e[2][1] - e[1][1] * e[2][0]);
                    if det < 0.0 {
                        t.swap(2, 3);
                    }
                    tets.push(t);
                }
            }
        }
    }
    (verts, tets)
}

/// `n` pseudo-random sites inside the unit cube (a fixed sequence per seed).
pub fn sites(n: usize, seed: u64) -> Vec<[f64; 3]> {
    let mut state = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
    let mut unit = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..n).map(|_| [0; 3].map(|_| 0.02 + 0.96 * unit())).collect()
}

type Result<T> = std::result::Result<T, String>;

fn vk_err(call: &'static str) -> impl Fn(vk::Result) -> String {
    move |e| format!("{call} failed: {e}")
}

/// A push-constant value.
#[derive(Clone, Copy, Debug)]
enum Num {
    U(u64),
    F(f64),
}

/// The manifest and the folder it lies in.
struct Manifest {
    json: Value,
    dir: PathBuf,
}

impl Manifest {
    fn load(dir: &Path) -> Result<Self> {
        let path = dir.join("manifest.json");
        let text = std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
        let json: Value = serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))?;
        Ok(Self { json, dir: dir.to_path_buf() })
    }

    fn module(&self, name: &str) -> Result<&Value> {
        let modules = self.json["modules"].as_array().ok_or("the manifest lists no modules")?;
        modules.iter().find(|m| m["name"] == name).ok_or_else(|| format!("the manifest has no module {name}"))
    }

    fn constant(&self, name: &str) -> Result<u64> {
        self.json["constants"][name].as_u64().ok_or_else(|| format!("the manifest has no constant {name}"))
    }

    /// The push-constant bytes of module `name`: every scalar the manifest
    /// lists, from `values` by path (padding left zero).
    fn push_bytes(&self, name: &str, values: &[(String, Num)]) -> Result<Vec<u8>> {
        let push = &self.module(name)?["push_constants"];
        let size = push["size"].as_u64().ok_or("push_constants.size")? as usize;
        let scalars = push["scalars"].as_array().ok_or("push_constants.scalars")?;
        let mut bytes = vec![0u8; size];
        for (path, _) in values {
            if !scalars.iter().any(|s| s["path"] == path.as_str()) {
                return Err(format!("{name}: the manifest has no push constant {path} (another ABI version?)"));
            }
        }
        for s in scalars {
            let path = s["path"].as_str().ok_or("a scalar's path")?;
            let at = s["offset"].as_u64().ok_or("a scalar's offset")? as usize;
            let value = match values.iter().find(|(p, _)| p == path) {
                Some((_, v)) => *v,
                None if path.contains("_pad") => continue,
                None => return Err(format!("{name}: push constant {path} not set")),
            };
            let raw: Vec<u8> = match (s["type"].as_str(), value) {
                (Some("u32"), Num::U(v)) => (v as u32).to_le_bytes().to_vec(),
                (Some("f32"), Num::F(v)) => (v as f32).to_le_bytes().to_vec(),
                (Some("u64"), Num::U(v)) => v.to_le_bytes().to_vec(),
                (t, v) => return Err(format!("{name}: push constant {path} is {t:?}, given {v:?}")),
            };
            bytes[at..at + raw.len()].copy_from_slice(&raw);
        }
        Ok(bytes)
    }
}

/// A host-visible storage buffer, zero-filled.
struct Buf {
    buffer: vk::Buffer,
    memory: vk::DeviceMemory,
    ptr: *mut u8,
    size: usize,
}

/// A module's shader module, set layout, pipeline layout and pipeline.
type Pipeline = (vk::ShaderModule, vk::DescriptorSetLayout, vk::PipelineLayout, vk::Pipeline);

/// The device, its queue and what the job made on it.
struct Gpu {
    instance: ash::Instance,
    device: ash::Device,
    queue: vk::Queue,
    memory: vk::PhysicalDeviceMemoryProperties,
    buffers: Vec<Buf>,
    pipelines: HashMap<String, Pipeline>,
    pool: vk::CommandPool,
    cmd: vk::CommandBuffer,
    descriptors: vk::DescriptorPool,
    /// The loader, kept loaded until everything above is destroyed.
    _entry: ash::Entry,
}

/// The Vulkan 1.2 feature behind a manifest `device_features` entry.
fn feature<'a>(
    name: &str,
    core: &'a mut vk::PhysicalDeviceFeatures,
    f12: &'a mut vk::PhysicalDeviceVulkan12Features,
) -> Option<&'a mut vk::Bool32> {
    Some(match name {
        "VkPhysicalDeviceFeatures.shaderInt64" => &mut core.shader_int64,
        "VkPhysicalDeviceFeatures.shaderInt16" => &mut core.shader_int16,
        "VkPhysicalDeviceFeatures.shaderFloat64" => &mut core.shader_float64,
        "VkPhysicalDeviceVulkan12Features.shaderInt8" => &mut f12.shader_int8,
        "VkPhysicalDeviceVulkan12Features.shaderFloat16" => &mut f12.shader_float16,
        "VkPhysicalDeviceVulkan12Features.shaderBufferInt64Atomics" => &mut f12.shader_buffer_int64_atomics,
        "VkPhysicalDeviceVulkan12Features.vulkanMemoryModel" => &mut f12.vulkan_memory_model,
        "VkPhysicalDeviceVulkan12Features.vulkanMemoryModelDeviceScope" => &mut f12.vulkan_memory_model_device_scope,
        _ => return None,
    })
}

impl Gpu {
    /// The first Vulkan 1.2 device with a compute queue, with the features
    /// the listed modules need.
    fn open(manifest: &Manifest, modules: &[&str]) -> Result<(Self, String)> {
        // SAFETY: loading the system's Vulkan loader.
        let entry = unsafe { ash::Entry::load() }.map_err(|e| format!("no Vulkan loader: {e}"))?;
        let app =
            vk::ApplicationInfo::default().application_name(c"cvd-embed-example").api_version(vk::API_VERSION_1_2);
        let info = vk::InstanceCreateInfo::default().application_info(&app);
        // SAFETY: valid create info.
        let instance = unsafe { entry.create_instance(&info, None) }.map_err(vk_err("vkCreateInstance"))?;
        // SAFETY: a live instance throughout.
        let physical =
            unsafe { instance.enumerate_physical_devices() }.map_err(vk_err("vkEnumeratePhysicalDevices"))?;
        let found = physical.into_iter().find_map(|pd| {
            let props = unsafe { instance.get_physical_device_properties(pd) };
            let families = unsafe { instance.get_physical_device_queue_family_properties(pd) };
            let family = families.iter().position(|f| f.queue_flags.contains(vk::QueueFlags::COMPUTE))?;
            (props.api_version >= vk::API_VERSION_1_2).then_some((pd, props, family as u32))
        });
        let Some((pd, props, family)) = found else {
            // SAFETY: nothing was made from the instance.
            unsafe { instance.destroy_instance(None) };
            return Err("no Vulkan 1.2 device with a compute queue".into());
        };
        let name = props.device_name_as_c_str().map_or("?".into(), |n| n.to_string_lossy().into_owned());

        // The features the modules' capabilities need (the manifest names them).
        let mut wanted = Vec::new();
        for m in modules {
            for f in manifest.module(m)?["device_features"].as_array().ok_or("device_features")? {
                let f = f.as_str().ok_or("a device feature")?.to_string();
                if !wanted.contains(&f) {
                    wanted.push(f);
                }
            }
        }
        let mut have12 = vk::PhysicalDeviceVulkan12Features::default();
        let mut have = {
            let mut f2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut have12);
            // SAFETY: valid physical device and feature chain.
            unsafe { instance.get_physical_device_features2(pd, &mut f2) };
            f2.features
        };
        let (mut core, mut f12) =
            (vk::PhysicalDeviceFeatures::default(), vk::PhysicalDeviceVulkan12Features::default());
        for f in &wanted {
            let supported = feature(f, &mut have, &mut have12).ok_or_else(|| format!("unknown feature {f}"))?;
            if *supported != vk::TRUE {
                return Err(format!("{name} lacks {f}"));
            }
            *feature(f, &mut core, &mut f12).expect("known above") = vk::TRUE;
        }
        let priorities = [1.0f32];
        let queues = [vk::DeviceQueueCreateInfo::default().queue_family_index(family).queue_priorities(&priorities)];
        let info =
            vk::DeviceCreateInfo::default().queue_create_infos(&queues).enabled_features(&core).push_next(&mut f12);
        // SAFETY: valid create infos; the features were checked above.
        let device = unsafe { instance.create_device(pd, &info, None) }.map_err(vk_err("vkCreateDevice"))?;
        let queue = unsafe { device.get_device_queue(family, 0) };
        let memory = unsafe { instance.get_physical_device_memory_properties(pd) };
        let info = vk::CommandPoolCreateInfo::default().queue_family_index(family);
        let pool = unsafe { device.create_command_pool(&info, None) }.map_err(vk_err("vkCreateCommandPool"))?;
        let info = vk::CommandBufferAllocateInfo::default().command_pool(pool).command_buffer_count(1);
        let cmd = unsafe { device.allocate_command_buffers(&info) }.map_err(vk_err("vkAllocateCommandBuffers"))?[0];
        let sizes = [vk::DescriptorPoolSize::default().ty(vk::DescriptorType::STORAGE_BUFFER).descriptor_count(256)];
        let info = vk::DescriptorPoolCreateInfo::default().max_sets(32).pool_sizes(&sizes);
        let descriptors =
            unsafe { device.create_descriptor_pool(&info, None) }.map_err(vk_err("vkCreateDescriptorPool"))?;
        let gpu = Self {
            instance,
            device,
            queue,
            memory,
            buffers: Vec::new(),
            pipelines: HashMap::new(),
            pool,
            cmd,
            descriptors,
            _entry: entry,
        };
        let begin = vk::CommandBufferBeginInfo::default().flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
        unsafe { gpu.device.begin_command_buffer(cmd, &begin) }.map_err(vk_err("vkBeginCommandBuffer"))?;
        Ok((gpu, name))
    }

    /// A zero-filled host-visible storage buffer holding `data` (or `bytes`
    /// zeros); returns its index.
    fn buffer(&mut self, bytes: usize, data: &[u8]) -> Result<usize> {
        let size = bytes.max(data.len()).max(16);
        let dev = &self.device;
        let info = vk::BufferCreateInfo::default().size(size as u64).usage(vk::BufferUsageFlags::STORAGE_BUFFER);
        // SAFETY: valid create infos; the memory is mapped while the buffer lives.
        unsafe {
            let buffer = dev.create_buffer(&info, None).map_err(vk_err("vkCreateBuffer"))?;
            let req = dev.get_buffer_memory_requirements(buffer);
            let want = vk::MemoryPropertyFlags::HOST_VISIBLE | vk::MemoryPropertyFlags::HOST_COHERENT;
            let m = &self.memory;
            let index = (0..m.memory_type_count)
                .find(|&i| {
                    req.memory_type_bits & (1 << i) != 0 && m.memory_types[i as usize].property_flags.contains(want)
                })
                .ok_or("no host-visible coherent memory")?;
            let alloc = vk::MemoryAllocateInfo::default().allocation_size(req.size).memory_type_index(index);
            let memory = dev.allocate_memory(&alloc, None).map_err(vk_err("vkAllocateMemory"))?;
            dev.bind_buffer_memory(buffer, memory, 0).map_err(vk_err("vkBindBufferMemory"))?;
            let ptr = dev
                .map_memory(memory, 0, vk::WHOLE_SIZE, vk::MemoryMapFlags::empty())
                .map_err(vk_err("vkMapMemory"))? as *mut u8;
            std::ptr::write_bytes(ptr, 0, size);
            std::ptr::copy_nonoverlapping(data.as_ptr(), ptr, data.len());
            self.buffers.push(Buf { buffer, memory, ptr, size });
        }
        Ok(self.buffers.len() - 1)
    }

    fn read(&self, buf: usize, len: usize, width: usize) -> Vec<[u8; 8]> {
        let b = &self.buffers[buf];
        assert!(len * width <= b.size);
        // SAFETY: the mapping covers `size` bytes and the device is idle.
        let bytes = unsafe { std::slice::from_raw_parts(b.ptr, len * width) };
        bytes.chunks_exact(width).map(|c| core::array::from_fn(|i| c.get(i).copied().unwrap_or(0))).collect()
    }

    /// The pipeline of module `name`, made from its file and manifest entry.
    fn pipeline(&mut self, manifest: &Manifest, name: &str) -> Result<Pipeline> {
        if let Some(p) = self.pipelines.get(name) {
            return Ok(*p);
        }
        let m = manifest.module(name)?;
        let file = manifest.dir.join(m["file"].as_str().ok_or("a module's file")?);
        let bytes = std::fs::read(&file).map_err(|e| format!("{}: {e}", file.display()))?;
        let words =
            ash::util::read_spv(&mut std::io::Cursor::new(bytes)).map_err(|e| format!("{}: {e}", file.display()))?;
        let bindings: Vec<_> = m["bindings"]
            .as_array()
            .ok_or("bindings")?
            .iter()
            .map(|b| {
                vk::DescriptorSetLayoutBinding::default()
                    .binding(b["binding"].as_u64().unwrap_or(0) as u32)
                    .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                    .descriptor_count(1)
                    .stage_flags(vk::ShaderStageFlags::COMPUTE)
            })
            .collect();
        let push_size = m["push_constants"]["size"].as_u64().ok_or("push_constants.size")? as u32;
        let entry =
            std::ffi::CString::new(m["entry_point"].as_str().ok_or("entry_point")?).map_err(|e| e.to_string())?;
        let dev = &self.device;
        // SAFETY: valid create infos.
        unsafe {
            let module = dev
                .create_shader_module(&vk::ShaderModuleCreateInfo::default().code(&words), None)
                .map_err(vk_err("vkCreateShaderModule"))?;
            let info = vk::DescriptorSetLayoutCreateInfo::default().bindings(&bindings);
            let set_layout =
                dev.create_descriptor_set_layout(&info, None).map_err(vk_err("vkCreateDescriptorSetLayout"))?;
            let ranges = [vk::PushConstantRange::default().stage_flags(vk::ShaderStageFlags::COMPUTE).size(push_size)];
            let sets = [set_layout];
            let info = vk::PipelineLayoutCreateInfo::default().set_layouts(&sets).push_constant_ranges(&ranges);
            let layout = dev.create_pipeline_layout(&info, None).map_err(vk_err("vkCreatePipelineLayout"))?;
            let stage = vk::PipelineShaderStageCreateInfo::default()
                .stage(vk::ShaderStageFlags::COMPUTE)
                .module(module)
                .name(&entry);
            let info = [vk::ComputePipelineCreateInfo::default().stage(stage).layout(layout)];
            let pipeline = dev
                .create_compute_pipelines(vk::PipelineCache::null(), &info, None)
                .map_err(|(_, e)| format!("vkCreateComputePipelines ({name}) failed: {e}"))?[0];
            let made = (module, set_layout, layout, pipeline);
            self.pipelines.insert(name.to_string(), made);
            Ok(made)
        }
    }

    /// Records module `name` over `threads` threads with `buffers` at
    /// bindings 0.., then a barrier.
    fn dispatch(
        &mut self,
        manifest: &Manifest,
        name: &str,
        buffers: &[usize],
        push: &[(String, Num)],
        threads: u64,
    ) -> Result<()> {
        let m = manifest.module(name)?;
        let n_bindings = m["bindings"].as_array().ok_or("bindings")?.len();
        if n_bindings != buffers.len() {
            return Err(format!("{name} takes {n_bindings} buffers, given {}", buffers.len()));
        }
        let wg = m["workgroup_size"][0].as_u64().ok_or("workgroup_size")?;
        let push = manifest.push_bytes(name, push)?;
        let (_, set_layout, layout, pipeline) = self.pipeline(manifest, name)?;
        if threads == 0 {
            return Ok(());
        }
        // A 1D job on a 2D grid of workgroups (the manifest's `dispatch`).
        let groups = threads.div_ceil(wg);
        let gx = groups.min(65_535);
        let gy = groups.div_ceil(gx);
        let dev = &self.device;
        let layouts = [set_layout];
        let info = vk::DescriptorSetAllocateInfo::default().descriptor_pool(self.descriptors).set_layouts(&layouts);
        // SAFETY: live objects; recording into our command buffer.
        unsafe {
            let set = dev.allocate_descriptor_sets(&info).map_err(vk_err("vkAllocateDescriptorSets"))?[0];
            let infos: Vec<[vk::DescriptorBufferInfo; 1]> = buffers
                .iter()
                .map(|&b| [vk::DescriptorBufferInfo::default().buffer(self.buffers[b].buffer).range(vk::WHOLE_SIZE)])
                .collect();
            let writes: Vec<_> = infos
                .iter()
                .enumerate()
                .map(|(i, info)| {
                    vk::WriteDescriptorSet::default()
                        .dst_set(set)
                        .dst_binding(i as u32)
                        .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                        .buffer_info(info)
                })
                .collect();
            dev.update_descriptor_sets(&writes, &[]);
            dev.cmd_bind_pipeline(self.cmd, vk::PipelineBindPoint::COMPUTE, pipeline);
            dev.cmd_bind_descriptor_sets(self.cmd, vk::PipelineBindPoint::COMPUTE, layout, 0, &[set], &[]);
            dev.cmd_push_constants(self.cmd, layout, vk::ShaderStageFlags::COMPUTE, 0, &push);
            dev.cmd_dispatch(self.cmd, gx as u32, gy as u32, 1);
            let barrier =
                [vk::MemoryBarrier::default().src_access_mask(vk::AccessFlags::SHADER_WRITE).dst_access_mask(
                    vk::AccessFlags::SHADER_READ | vk::AccessFlags::SHADER_WRITE | vk::AccessFlags::HOST_READ,
                )];
            dev.cmd_pipeline_barrier(
                self.cmd,
                vk::PipelineStageFlags::COMPUTE_SHADER,
                vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::HOST,
                vk::DependencyFlags::empty(),
                &barrier,
                &[],
                &[],
            );
        }
        Ok(())
    }

    /// Submits everything recorded and waits.
    fn submit(&self) -> Result<()> {
        let dev = &self.device;
        // SAFETY: our command buffer, a fence we wait for and destroy.
        unsafe {
            dev.end_command_buffer(self.cmd).map_err(vk_err("vkEndCommandBuffer"))?;
            let fence = dev.create_fence(&vk::FenceCreateInfo::default(), None).map_err(vk_err("vkCreateFence"))?;
            let cmds = [self.cmd];
            let submit = [vk::SubmitInfo::default().command_buffers(&cmds)];
            let done = dev
                .queue_submit(self.queue, &submit, fence)
                .and_then(|_| dev.wait_for_fences(&[fence], true, u64::MAX));
            dev.destroy_fence(fence, None);
            done.map_err(vk_err("vkQueueSubmit"))
        }
    }
}

impl Drop for Gpu {
    fn drop(&mut self) {
        // SAFETY: the device is idle (or nothing was submitted).
        unsafe {
            let dev = &self.device;
            let _ = dev.device_wait_idle();
            for (module, set_layout, layout, pipeline) in self.pipelines.values() {
                dev.destroy_pipeline(*pipeline, None);
                dev.destroy_pipeline_layout(*layout, None);
                dev.destroy_descriptor_set_layout(*set_layout, None);
                dev.destroy_shader_module(*module, None);
            }
            for b in &self.buffers {
                dev.destroy_buffer(b.buffer, None);
                dev.free_memory(b.memory, None);
            }
            dev.destroy_descriptor_pool(self.descriptors, None);
            dev.destroy_command_pool(self.pool, None);
            dev.destroy_device(None);
            self.instance.destroy_instance(None);
        }
    }
}

fn u32_bytes(v: impl IntoIterator<Item = u32>) -> Vec<u8> {
    v.into_iter().flat_map(u32::to_le_bytes).collect()
}

fn f32_bytes(v: impl IntoIterator<Item = f32>) -> Vec<u8> {
    v.into_iter().flat_map(f32::to_le_bytes).collect()
}

fn named(prefix: &str, values: &[(&str, Num)]) -> Vec<(String, Num)> {
    values.iter().map(|(n, v)| (format!("{prefix}{n}"), *v)).collect()
}

/// The clipped Voronoi volumes of `sites` in the tet mesh (`verts`,
/// `tets`; positively oriented tets), on the first Vulkan 1.2 device, from
/// the modules and manifest in `spirv_dir`.
pub fn run(spirv_dir: &Path, verts: &[[f64; 3]], tets: &[[u32; 4]], sites: &[[f64; 3]]) -> Result<Output> {
    use Num::{F, U};
    let manifest = Manifest::load(spirv_dir)?;
    let (n, nt) = (sites.len(), tets.len());
    if n < 2 || nt == 0 {
        return Err("need at least two sites and one tet".into());
    }
    let accum = manifest.constant("ACCUM_PER_SITE")? as usize;
    let scan_block = manifest.constant("SCAN_BLOCK")? as usize;
    let quant_max = manifest.constant("QUANT_MAX")? as f64;
    let n_counters = manifest.json["constants"]["counter"]["COUNT"].as_u64().ok_or("counter.COUNT")? as usize;

    // The clipping frame: the mesh's box, longest side 1.
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in verts {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    let scale = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
    let local = |p: &[f64; 3]| [0, 1, 2].map(|a| (p[a] - lo[a]) / scale);
    let sites_l: Vec<[f64; 3]> = sites.iter().map(local).collect();
    let verts_l: Vec<[f64; 3]> = verts.iter().map(local).collect();
    let centroids: Vec<[f64; 3]> =
        tets.iter().map(|t| [0, 1, 2].map(|a| t.iter().map(|&v| verts_l[v as usize][a]).sum::<f64>() / 4.0)).collect();

    // Quantized coordinates (exact integer distances for the k-NN): the box
    // of sites and mesh, scaled by a power of two into [0, QUANT_MAX].
    let mut qlo = [f64::INFINITY; 3];
    let mut qhi = [f64::NEG_INFINITY; 3];
    for p in sites_l.iter().chain(&verts_l) {
        for a in 0..3 {
            qlo[a] = qlo[a].min(p[a]);
            qhi[a] = qhi[a].max(p[a]);
        }
    }
    let extent = (0..3).map(|a| qhi[a] - qlo[a]).fold(0.0, f64::max);
    let qscale = (quant_max / extent).log2().floor().exp2();
    let quant = |p: &[f64; 3], i: usize| {
        let q = [0, 1, 2].map(|a| ((p[a] - qlo[a]) * qscale).round().clamp(0.0, quant_max) as u32);
        [q[0], q[1], q[2], i as u32]
    };
    let qsites: Vec<[u32; 4]> = sites_l.iter().enumerate().map(|(i, p)| quant(p, i)).collect();
    let qcentroids: Vec<[u32; 4]> = centroids.iter().enumerate().map(|(i, p)| quant(p, i)).collect();

    // The site grid: about 5 sites per cubic cell over the quantized box.
    let mut ext = [1u64; 3];
    for q in qsites.iter().chain(&verts_l.iter().map(|p| quant(p, 0)).collect::<Vec<_>>()) {
        for a in 0..3 {
            ext[a] = ext[a].max(q[a] as u64 + 1);
        }
    }
    let volume: f64 = ext.iter().map(|&e| e as f64).product();
    let mut cell = (volume * 5.0 / n as f64).cbrt().ceil().clamp(1.0, quant_max) as u64;
    while ext.iter().map(|e| e.div_ceil(cell)).product::<u64>() > 2 * n as u64 + 64 {
        cell *= 2;
    }
    let dims = ext.map(|e| e.div_ceil(cell));
    let n_cells = (dims[0] * dims[1] * dims[2]) as usize;
    let n_blocks = n_cells.div_ceil(scan_block);
    let grid = [
        ("dim_x", U(dims[0])),
        ("dim_y", U(dims[1])),
        ("dim_z", U(dims[2])),
        ("cell_size", U(cell)),
        ("n_sites", U(n as u64)),
        ("n_cells", U(n_cells as u64)),
    ];
    let k_site = 90.min(n - 1);

    // Fixed-point scale of the sums and the box of Algorithm 1.
    let diag = (0..3).map(|a| (qhi[a] - qlo[a]).powi(2)).sum::<f64>().sqrt();
    let margin = 0.01 * diag.max(1e-3);
    let bits = 61.0 - (3.0 * (1.0 + diag).powi(2)).log2().ceil();
    let fixed_scale = bits.exp2();
    let clip = [
        ("n_sites", U(n as u64)),
        ("n_tets", U(nt as u64)),
        ("k_site", U(k_site as u64)),
        ("k_tet", U(1)),
        ("fixed_scale", F(fixed_scale)),
        ("box_lo_x", F(qlo[0] - margin)),
        ("box_lo_y", F(qlo[1] - margin)),
        ("box_lo_z", F(qlo[2] - margin)),
        ("box_hi_x", F(qhi[0] + margin)),
        ("box_hi_y", F(qhi[1] + margin)),
        ("box_hi_z", F(qhi[2] + margin)),
        ("tet_base", U(0)),
        // Every site's list is bound, and this dispatch answers for all.
        ("nbr_base", U(0)),
        ("nbr_end", U(n as u64)),
        ("own_lo", U(0)),
        ("own_hi", U(n as u64)),
        // No face sums (faces_base 0: `tet_faces` is bound but not read).
        ("faces_base", U(0)),
        ("area_scale", F(0.0)),
        ("walk_margin", F(4.0 / qscale + 1e-6)),
        ("capacity", U(nt as u64)),
        // Voronoi cells: no power weights (the sites' w is 0).
        ("weight_range", F(0.0)),
        // No face sums, so no face masses.
        ("face_masses", U(0)),
        // The lists as knn_grid writes them: plain u32 entries.
        ("list_bits", U(32)),
        // Face sums, were there any, for every site.
        ("faces_first", U(0)),
    ];

    let used = [
        "grid_count",
        "scan_blocks",
        "scan_totals",
        "scan_offsets",
        "grid_scatter",
        "grid_sort",
        "knn_grid",
        "clip_flood",
        "refine",
    ];
    let (mut gpu, device) = Gpu::open(&manifest, &used)?;
    let g = &mut gpu;
    // Points as hi + lo (the manifest's SplitPoint): f32 rounding, then
    // what it left; w: 0 for sites, the density 1 for vertices.
    let split = |p: &[f64; 3], w: f32| {
        let hi = p.map(|c| c as f32);
        let lo = [0, 1, 2].map(|a| (p[a] - hi[a] as f64) as f32);
        [hi[0], hi[1], hi[2], w, lo[0], lo[1], lo[2], 0.0]
    };
    let sites_f = g.buffer(0, &f32_bytes(sites_l.iter().flat_map(|p| split(p, 0.0))))?;
    let verts_f = g.buffer(0, &f32_bytes(verts_l.iter().flat_map(|p| split(p, 1.0))))?;
    let tets_b = g.buffer(0, &u32_bytes(tets.iter().flatten().copied()))?;
    let qsites_b = g.buffer(0, &u32_bytes(qsites.iter().flatten().copied()))?;
    let qcent_b = g.buffer(0, &u32_bytes(qcentroids.iter().flatten().copied()))?;
    let site_cell = g.buffer(n * 4, &[])?;
    let cell_count = g.buffer(n_cells * 4, &[])?;
    let cell_start = g.buffer(n_cells * 4, &[])?;
    let cursor = g.buffer(n_cells * 4, &[])?;
    let block_sums = g.buffer(n_blocks * 4, &[])?;
    let sorted = g.buffer(n * 16, &[])?;
    let nbrs = g.buffer(n * k_site * 4, &[])?;
    let nbr_d2 = g.buffer(n * k_site * 8, &[])?;
    let tet_sites = g.buffer(nt * 4, &[])?;
    let tet_d2 = g.buffer(nt * 8, &[])?;
    let sums = g.buffer((n * accum + nt) * 8, &[])?;
    let counters = g.buffer(n_counters * 8, &[])?;
    let unfinished = g.buffer((1 + 2 * nt) * 4, &[])?;
    let still = g.buffer((1 + 2 * nt) * 4, &[])?;
    let scratch = g.buffer(n_counters * 8, &[])?;
    let tet_faces = g.buffer(4, &[])?;

    // 1. The site grid: count, prefix sum, scatter, order within cells.
    let mut build = named("grid.", &grid);
    build.push(("n_blocks".into(), U(n_blocks as u64)));
    let m = &manifest;
    g.dispatch(m, "grid_count", &[qsites_b, site_cell, cell_count], &build, n as u64)?;
    g.dispatch(m, "scan_blocks", &[cell_count, cell_start, block_sums], &build, n_blocks as u64)?;
    g.dispatch(m, "scan_totals", &[block_sums], &build, 1)?;
    g.dispatch(m, "scan_offsets", &[block_sums, cell_start], &build, n_blocks as u64)?;
    g.dispatch(m, "grid_scatter", &[qsites_b, site_cell, cell_start, cursor, sorted], &build, n as u64)?;
    g.dispatch(m, "grid_sort", &[cell_start, cell_count, sorted], &build, n_cells as u64)?;
    // 2. The k_site nearest other sites of each site; the nearest site of
    // each tet's centroid (flood pairing's seed).
    let mut knn = named("grid.", &grid);
    knn.extend(named(
        "",
        &[
            ("n_queries", U(n as u64)),
            ("k", U(k_site as u64)),
            ("exclude_self", U(1)),
            ("query_base", U(0)),
            ("in_order", U(0)),
            // Each thread sorts its list in its own slots of the outputs.
            ("local_lists", U(0)),
        ],
    ));
    g.dispatch(m, "knn_grid", &[qsites_b, cell_start, cell_count, sorted, nbrs, nbr_d2], &knn, n as u64)?;
    let mut knn = named("grid.", &grid);
    knn.extend(named(
        "",
        &[
            ("n_queries", U(nt as u64)),
            ("k", U(1)),
            ("exclude_self", U(0)),
            ("query_base", U(0)),
            ("in_order", U(0)),
            ("local_lists", U(0)),
        ],
    ));
    g.dispatch(m, "knn_grid", &[qcent_b, cell_start, cell_count, sorted, tet_sites, tet_d2], &knn, nt as u64)?;
    // 3. Clip every tet by flooding its sites; a piece its site's list does
    // not settle walks the site grid. 4. The second pass over the entries
    // the first left unfinished. Both take the clipping and grid parameters.
    let mut refine = named("clip.", &clip);
    refine.extend(named("grid.", &grid));
    refine.extend(named(
        "",
        &[
            ("grid_lo_x", F(qlo[0])),
            ("grid_lo_y", F(qlo[1])),
            ("grid_lo_z", F(qlo[2])),
            ("cell_len", F(cell as f64 / qscale)),
            // Every grid cell's sites are held (a part of a distributed job
            // would hold a box of them).
            ("held_lo_x", U(0)),
            ("held_lo_y", U(0)),
            ("held_lo_z", U(0)),
            ("held_dim_x", U(dims[0])),
            ("held_dim_y", U(dims[1])),
            ("held_dim_z", U(dims[2])),
        ],
    ));
    let args = [
        sites_f, verts_f, tets_b, tet_sites, nbrs, cell_start, cell_count, sorted, sums, counters, unfinished,
        tet_faces,
    ];
    g.dispatch(m, "clip_flood", &args, &refine, nt as u64)?;
    let args = [
        sites_f, verts_f, tets_b, tet_sites, unfinished, nbrs, cell_start, cell_count, sorted, sums, scratch, still,
        tet_faces,
    ];
    g.dispatch(m, "refine", &args, &refine, nt as u64)?;
    g.submit()?;

    let word = |b: [u8; 8]| i64::from_le_bytes(b);
    let sums = g.read(sums, n * accum, 8);
    let volumes = (0..n).map(|i| word(sums[i * accum]) as f64 / fixed_scale * scale.powi(3)).collect();
    let counters = g.read(counters, n_counters, 8).into_iter().map(word).collect();
    let count = |b: usize| u32::from_le_bytes(g.read(b, 1, 4)[0][..4].try_into().expect("4 bytes"));
    Ok(Output { device, volumes, counters, unfinished_first: count(unfinished), unfinished_after: count(still) })
}
