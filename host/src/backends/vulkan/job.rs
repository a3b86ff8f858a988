//! Records every phase of a job into one command buffer, with a timestamp
//! after each phase, submits it once and waits.

use super::context::Context;
use super::memory::{Buffer, Location};
use super::pipelines::Pipelines;
use crate::error::{Error, Result, VkContext};
use crate::geom::timing::Timings;
use ash::vk;
use cvd_kernels::abi::WORKGROUP_SIZE;

/// Most timestamps one job writes.
const MAX_MARKS: u32 = 64;
/// Storage buffers of the kernel that binds the most (the descriptor
/// pool's size per dispatch).
fn max_bindings() -> u32 {
    cvd_kernels::interface::ENTRY_POINTS.iter().map(|e| e.bindings.len() as u32).max().unwrap_or(1)
}
/// Most workgroups along x in one dispatch (the minimum limit in Vulkan).
const MAX_GROUPS_X: u64 = 65_535;

/// A job being recorded.
pub(crate) struct Job<'a> {
    ctx: &'a Context,
    pipelines: &'a Pipelines,
    pool: vk::CommandPool,
    cmd: vk::CommandBuffer,
    descriptors: vk::DescriptorPool,
    queries: vk::QueryPool,
    marks: Vec<String>,
    /// Every buffer the job uses; they live until the job has run.
    buffers: Vec<Buffer>,
}

/// A buffer of a job.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct BufId(usize);

/// A host buffer that receives a copy of a device buffer when the job runs.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Readback(BufId);

/// A job that has run: its timings and buffers.
pub(crate) struct Finished {
    pub timings: Timings,
    buffers: Vec<Buffer>,
}

impl Finished {
    /// The contents of a read-back buffer.
    pub(crate) fn read<T: bytemuck::Pod>(&self, r: Readback, len: usize) -> Vec<T> {
        self.buffers[r.0 .0].read(len)
    }
}

impl<'a> Job<'a> {
    /// Starts recording a job of at most `max_dispatches` dispatches.
    pub(crate) fn new(ctx: &'a Context, pipelines: &'a Pipelines, max_dispatches: u32) -> Result<Self> {
        let dev = &ctx.device;
        let info = vk::CommandPoolCreateInfo::default()
            .queue_family_index(ctx.queue_family)
            .flags(vk::CommandPoolCreateFlags::TRANSIENT);
        // SAFETY: valid create infos; the objects are destroyed in Drop.
        let pool = unsafe { dev.create_command_pool(&info, None) }.call("vkCreateCommandPool")?;
        let mut job = Self {
            ctx,
            pipelines,
            pool,
            cmd: vk::CommandBuffer::null(),
            descriptors: vk::DescriptorPool::null(),
            queries: vk::QueryPool::null(),
            marks: Vec::new(),
            buffers: Vec::new(),
        };
        let info = vk::CommandBufferAllocateInfo::default().command_pool(pool).command_buffer_count(1);
        job.cmd = unsafe { dev.allocate_command_buffers(&info) }.call("vkAllocateCommandBuffers")?[0];
        let sizes = [vk::DescriptorPoolSize::default()
            .ty(vk::DescriptorType::STORAGE_BUFFER)
            .descriptor_count(max_dispatches * max_bindings())];
        let info = vk::DescriptorPoolCreateInfo::default().max_sets(max_dispatches).pool_sizes(&sizes);
        job.descriptors = unsafe { dev.create_descriptor_pool(&info, None) }.call("vkCreateDescriptorPool")?;
        let info = vk::QueryPoolCreateInfo::default().query_type(vk::QueryType::TIMESTAMP).query_count(MAX_MARKS);
        job.queries = unsafe { dev.create_query_pool(&info, None) }.call("vkCreateQueryPool")?;
        let begin = vk::CommandBufferBeginInfo::default().flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
        unsafe {
            dev.begin_command_buffer(job.cmd, &begin).call("vkBeginCommandBuffer")?;
            dev.cmd_reset_query_pool(job.cmd, job.queries, 0, MAX_MARKS);
        }
        job.mark("start");
        Ok(job)
    }

    /// Ends the current phase: waits for all earlier work (a full barrier
    /// between phases, so every later command sees earlier writes) and
    /// writes a timestamp named `phase`.
    pub(crate) fn mark(&mut self, phase: &str) {
        assert!((self.marks.len() as u32) < MAX_MARKS, "too many phases in one job");
        if !self.marks.is_empty() {
            self.barrier();
        }
        // SAFETY: recording into our command buffer; the query index exists.
        unsafe {
            self.ctx.device.cmd_write_timestamp(
                self.cmd,
                vk::PipelineStageFlags::BOTTOM_OF_PIPE,
                self.queries,
                self.marks.len() as u32,
            )
        };
        self.marks.push(phase.to_string());
    }

    /// Makes all earlier transfer and compute writes visible to later
    /// transfer and compute commands.
    pub(crate) fn barrier(&self) {
        let stages = vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::TRANSFER;
        let barrier = [vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::SHADER_WRITE | vk::AccessFlags::TRANSFER_WRITE)
            .dst_access_mask(
                vk::AccessFlags::SHADER_READ
                    | vk::AccessFlags::SHADER_WRITE
                    | vk::AccessFlags::TRANSFER_READ
                    | vk::AccessFlags::TRANSFER_WRITE,
            )];
        // SAFETY: recording into our command buffer.
        unsafe {
            self.ctx.device.cmd_pipeline_barrier(
                self.cmd,
                stages,
                stages,
                vk::DependencyFlags::empty(),
                &barrier,
                &[],
                &[],
            )
        };
    }

    fn add(&mut self, bytes: u64, location: Location) -> Result<BufId> {
        self.buffers.push(Buffer::new(self.ctx, bytes, location)?);
        Ok(BufId(self.buffers.len() - 1))
    }

    /// A device buffer of `bytes`, uninitialised.
    pub(crate) fn buffer(&mut self, bytes: u64) -> Result<BufId> {
        self.add(bytes, Location::Device)
    }

    /// A device buffer of `bytes`, filled with zeros at this point of the job.
    pub(crate) fn zeroed(&mut self, bytes: u64) -> Result<BufId> {
        let id = self.buffer(bytes)?;
        // SAFETY: recording into our command buffer; whole-size fill.
        unsafe { self.ctx.device.cmd_fill_buffer(self.cmd, self.buffers[id.0].buffer, 0, vk::WHOLE_SIZE, 0) };
        Ok(id)
    }

    /// Fills `buf` with zeros at this point of the job.
    pub(crate) fn fill_zero(&self, buf: BufId) {
        // SAFETY: recording into our command buffer; whole-size fill.
        unsafe { self.ctx.device.cmd_fill_buffer(self.cmd, self.buffers[buf.0].buffer, 0, vk::WHOLE_SIZE, 0) };
    }

    /// A device buffer holding `data` from this point of the job.
    pub(crate) fn upload<T: bytemuck::Pod>(&mut self, data: &[T]) -> Result<BufId> {
        let bytes = std::mem::size_of_val(data) as u64;
        let id = self.buffer(bytes)?;
        if bytes > 0 {
            let staging = self.add(bytes, Location::Upload)?;
            self.buffers[staging.0].write(data);
            self.copy(staging, id, bytes);
        }
        Ok(id)
    }

    /// Copies the first `bytes` of `buf` to the host at this point of the job.
    pub(crate) fn download(&mut self, buf: BufId, bytes: u64) -> Result<Readback> {
        let staging = self.add(bytes, Location::Readback)?;
        if bytes > 0 {
            self.copy(buf, staging, bytes);
        }
        Ok(Readback(staging))
    }

    /// A host buffer of `bytes` for [`Self::download_into`].
    pub(crate) fn readback(&mut self, bytes: u64) -> Result<Readback> {
        Ok(Readback(self.add(bytes, Location::Readback)?))
    }

    /// Copies the first `bytes` of `buf` into `to` at this point of the
    /// job (a part's results, read after each [`Self::submit`]).
    pub(crate) fn download_into(&mut self, buf: BufId, to: Readback, bytes: u64) {
        if bytes > 0 {
            self.copy(buf, to.0, bytes);
        }
    }

    /// Copies the first `bytes` of `buf` into `to` at byte `offset` (parts
    /// of one result, each read back to its place).
    pub(crate) fn download_into_at(&mut self, buf: BufId, to: Readback, offset: u64, bytes: u64) {
        self.copy_to(buf, to.0, offset, bytes);
    }

    /// Copies the first `bytes` of `from` into `to` at byte `offset`, at
    /// this point of the job.
    pub(crate) fn copy_to(&mut self, from: BufId, to: BufId, offset: u64, bytes: u64) {
        if bytes > 0 {
            let region = [vk::BufferCopy::default().dst_offset(offset).size(bytes)];
            let (from, to) = (self.buffers[from.0].buffer, self.buffers[to.0].buffer);
            // SAFETY: recording a copy between live buffers of sufficient size.
            unsafe { self.ctx.device.cmd_copy_buffer(self.cmd, from, to, &region) };
        }
    }

    /// Copies `bytes` of `buf` from `offset` to the host at this point of
    /// the job.
    pub(crate) fn download_at(&mut self, buf: BufId, offset: u64, bytes: u64) -> Result<Readback> {
        let staging = self.add(bytes, Location::Readback)?;
        let region = [vk::BufferCopy::default().src_offset(offset).size(bytes)];
        let (from, to) = (self.buffers[buf.0].buffer, self.buffers[staging.0].buffer);
        // SAFETY: recording a copy between live buffers of sufficient size.
        unsafe { self.ctx.device.cmd_copy_buffer(self.cmd, from, to, &region) };
        Ok(Readback(staging))
    }

    /// The contents of a read-back buffer, once the part of the job that
    /// filled it has been submitted.
    pub(crate) fn read<T: bytemuck::Pod>(&self, r: Readback, len: usize) -> Vec<T> {
        self.buffers[r.0 .0].read(len)
    }

    fn copy(&self, from: BufId, to: BufId, bytes: u64) {
        let region = [vk::BufferCopy::default().size(bytes)];
        let (from, to) = (self.buffers[from.0].buffer, self.buffers[to.0].buffer);
        // SAFETY: recording a copy between live buffers of sufficient size.
        unsafe { self.ctx.device.cmd_copy_buffer(self.cmd, from, to, &region) };
    }

    /// Records kernel `name` over `threads` thread indices.
    pub(crate) fn dispatch<P: bytemuck::Pod>(
        &mut self,
        name: &str,
        buffers: &[BufId],
        push: &P,
        threads: u64,
    ) -> Result<()> {
        let kernel = self.pipelines.get(name)?;
        assert_eq!(buffers.len() as u32, kernel.spec.bindings, "kernel {name}: wrong number of buffers");
        assert!(kernel.spec.bindings <= max_bindings(), "kernel {name}: too many buffers for the descriptor pool");
        assert_eq!(std::mem::size_of::<P>() as u32, kernel.spec.push_size, "kernel {name}: wrong push constants");
        if threads == 0 {
            return Ok(());
        }
        let groups = threads.div_ceil(WORKGROUP_SIZE as u64);
        let gx = groups.min(MAX_GROUPS_X);
        let gy = groups.div_ceil(gx);
        if gy > self.ctx.limits.max_compute_work_group_count[1] as u64 {
            return Err(Error::InvalidInput(format!("{threads} threads exceed the device's dispatch limits")));
        }
        let dev = &self.ctx.device;
        let layouts = [kernel.set_layout];
        let info = vk::DescriptorSetAllocateInfo::default().descriptor_pool(self.descriptors).set_layouts(&layouts);
        // SAFETY: the pool was sized for the job's dispatches.
        let set = unsafe { dev.allocate_descriptor_sets(&info) }.call("vkAllocateDescriptorSets")?[0];
        let infos: Vec<[vk::DescriptorBufferInfo; 1]> = buffers
            .iter()
            .map(|b| {
                [vk::DescriptorBufferInfo::default().buffer(self.buffers[b.0].buffer).offset(0).range(vk::WHOLE_SIZE)]
            })
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
        // SAFETY: the set, buffers and pipeline are live; recording into our buffer.
        unsafe {
            dev.update_descriptor_sets(&writes, &[]);
            dev.cmd_bind_pipeline(self.cmd, vk::PipelineBindPoint::COMPUTE, kernel.pipeline);
            dev.cmd_bind_descriptor_sets(self.cmd, vk::PipelineBindPoint::COMPUTE, kernel.layout, 0, &[set], &[]);
            dev.cmd_push_constants(self.cmd, kernel.layout, vk::ShaderStageFlags::COMPUTE, 0, bytemuck::bytes_of(push));
            dev.cmd_dispatch(self.cmd, gx as u32, gy as u32, 1);
        }
        Ok(())
    }

    /// Submits the job, waits for it and returns the per-phase GPU times.
    pub(crate) fn run(mut self) -> Result<Finished> {
        let timings = self.submit_and_wait()?;
        Ok(Finished { timings, buffers: std::mem::take(&mut self.buffers) })
    }

    /// Submits what was recorded so far, waits for it, and starts recording
    /// again: buffers keep their contents, so a long loop can run in parts
    /// (descriptor sets and timestamps are recycled). Returns the per-phase
    /// times of the part submitted.
    pub(crate) fn submit(&mut self) -> Result<Timings> {
        let timings = self.submit_and_wait()?;
        let dev = &self.ctx.device;
        let begin = vk::CommandBufferBeginInfo::default().flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
        // SAFETY: the submitted work has completed, so the pools are idle.
        unsafe {
            dev.reset_command_pool(self.pool, vk::CommandPoolResetFlags::empty()).call("vkResetCommandPool")?;
            dev.reset_descriptor_pool(self.descriptors, vk::DescriptorPoolResetFlags::empty())
                .call("vkResetDescriptorPool")?;
            dev.begin_command_buffer(self.cmd, &begin).call("vkBeginCommandBuffer")?;
            dev.cmd_reset_query_pool(self.cmd, self.queries, 0, MAX_MARKS);
        }
        self.marks.clear();
        self.mark("start");
        Ok(timings)
    }

    fn submit_and_wait(&mut self) -> Result<Timings> {
        let dev = &self.ctx.device;
        // SAFETY: ending and submitting our command buffer, then waiting.
        unsafe {
            dev.end_command_buffer(self.cmd).call("vkEndCommandBuffer")?;
            let fence = dev.create_fence(&vk::FenceCreateInfo::default(), None).call("vkCreateFence")?;
            let cmds = [self.cmd];
            let submit = [vk::SubmitInfo::default().command_buffers(&cmds)];
            let submitted = {
                let _queue = self.ctx.queue_lock.lock().unwrap_or_else(|e| e.into_inner());
                dev.queue_submit(self.ctx.queue, &submit, fence).call("vkQueueSubmit")
            };
            let result = submitted.and_then(|_| dev.wait_for_fences(&[fence], true, u64::MAX).call("vkWaitForFences"));
            dev.destroy_fence(fence, None);
            result?;
        }
        let mut ticks = vec![0u64; self.marks.len()];
        // SAFETY: all queries written and complete (the fence has signalled).
        unsafe {
            dev.get_query_pool_results(
                self.queries,
                0,
                &mut ticks,
                vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT,
            )
        }
        .call("vkGetQueryPoolResults")?;
        let mut timings = Timings::default();
        for i in 1..ticks.len() {
            let dt = ticks[i].wrapping_sub(ticks[i - 1]) as f64 * self.ctx.timestamp_period * 1e-9;
            timings.push(self.marks[i].clone(), dt);
        }
        Ok(timings)
    }
}

impl Drop for Job<'_> {
    fn drop(&mut self) {
        // SAFETY: the job has completed or was never submitted.
        unsafe {
            let dev = &self.ctx.device;
            dev.destroy_query_pool(self.queries, None);
            dev.destroy_descriptor_pool(self.descriptors, None);
            dev.destroy_command_pool(self.pool, None);
        }
    }
}
