//! Buffers: device-local storage buffers and host-visible staging buffers.

use super::context::Context;
use crate::error::{Error, Result, VkContext};
use ash::vk;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

/// Bytes of device-local memory held by live buffers, and the most held
/// at once since the last reset.
#[derive(Default)]
pub(crate) struct MemoryUsage {
    live: AtomicU64,
    peak: AtomicU64,
}

impl MemoryUsage {
    fn add(&self, bytes: u64) {
        let live = self.live.fetch_add(bytes, Ordering::Relaxed) + bytes;
        self.peak.fetch_max(live, Ordering::Relaxed);
    }

    fn sub(&self, bytes: u64) {
        self.live.fetch_sub(bytes, Ordering::Relaxed);
    }

    pub(crate) fn peak(&self) -> u64 {
        self.peak.load(Ordering::Relaxed)
    }

    /// Starts a new peak from what is held now.
    pub(crate) fn reset_peak(&self) {
        self.peak.store(self.live.load(Ordering::Relaxed), Ordering::Relaxed);
    }
}

/// A buffer with its own memory allocation.
pub(crate) struct Buffer {
    device: ash::Device,
    /// Where the allocation's device-local bytes are counted (`None` for
    /// staging buffers).
    usage: Option<(Arc<MemoryUsage>, u64)>,
    pub(crate) buffer: vk::Buffer,
    memory: vk::DeviceMemory,
    /// Size in bytes.
    pub(crate) size: u64,
    mapped: *mut u8,
}

// SAFETY: the mapping is only touched through &mut self or after the GPU is
// done; Vulkan handles are plain identifiers.
unsafe impl Send for Buffer {}
unsafe impl Sync for Buffer {}

/// Where a buffer lives.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(crate) enum Location {
    /// GPU memory, read and written by kernels and transfers.
    Device,
    /// Host memory the GPU copies from.
    Upload,
    /// Host memory the GPU copies into (cached for fast reads).
    Readback,
}

fn find_memory_type(ctx: &Context, type_bits: u32, preferred: &[vk::MemoryPropertyFlags]) -> Option<u32> {
    let m = &ctx.memory;
    preferred.iter().find_map(|&want| {
        (0..m.memory_type_count)
            .find(|&i| type_bits & (1 << i) != 0 && m.memory_types[i as usize].property_flags.contains(want))
    })
}

impl Buffer {
    pub(crate) fn new(ctx: &Context, bytes: u64, location: Location) -> Result<Self> {
        // Zero-sized buffers are invalid; storage buffers hold 4-byte words.
        let size = bytes.max(16).next_multiple_of(16);
        let usage = match location {
            Location::Device => {
                vk::BufferUsageFlags::STORAGE_BUFFER
                    | vk::BufferUsageFlags::TRANSFER_SRC
                    | vk::BufferUsageFlags::TRANSFER_DST
            }
            Location::Upload => vk::BufferUsageFlags::TRANSFER_SRC,
            Location::Readback => vk::BufferUsageFlags::TRANSFER_DST,
        };
        let dev = &ctx.device;
        let info = vk::BufferCreateInfo::default().size(size).usage(usage).sharing_mode(vk::SharingMode::EXCLUSIVE);
        // SAFETY: valid create info.
        let buffer = unsafe { dev.create_buffer(&info, None) }.call("vkCreateBuffer")?;
        // SAFETY: valid buffer.
        let req = unsafe { dev.get_buffer_memory_requirements(buffer) };
        use vk::MemoryPropertyFlags as F;
        let preferred: &[F] = match location {
            Location::Device => &[F::DEVICE_LOCAL, F::empty()],
            Location::Upload => &[F::HOST_VISIBLE | F::HOST_COHERENT],
            Location::Readback => {
                &[F::HOST_VISIBLE | F::HOST_COHERENT | F::HOST_CACHED, F::HOST_VISIBLE | F::HOST_COHERENT]
            }
        };
        let Some(type_index) = find_memory_type(ctx, req.memory_type_bits, preferred) else {
            // SAFETY: the buffer is unused.
            unsafe { dev.destroy_buffer(buffer, None) };
            return Err(Error::MissingFeature {
                device: ctx.info.name.clone(),
                missing: "a suitable memory type".into(),
            });
        };
        let alloc = vk::MemoryAllocateInfo::default().allocation_size(req.size).memory_type_index(type_index);
        // SAFETY: valid allocate info.
        let memory = match unsafe { dev.allocate_memory(&alloc, None) } {
            Ok(m) => m,
            Err(e) => {
                // SAFETY: the buffer is unused.
                unsafe { dev.destroy_buffer(buffer, None) };
                return Err(Error::Vulkan { call: "vkAllocateMemory", result: e });
            }
        };
        let usage = (location == Location::Device).then(|| (ctx.usage.clone(), req.size));
        if let Some((u, bytes)) = &usage {
            u.add(*bytes);
        }
        let mut out = Self { device: dev.clone(), usage, buffer, memory, size, mapped: std::ptr::null_mut() };
        // SAFETY: memory matches the buffer's requirements.
        unsafe { dev.bind_buffer_memory(buffer, memory, 0) }.call("vkBindBufferMemory")?;
        if location != Location::Device {
            // SAFETY: host-visible memory, mapped once for the buffer's life.
            out.mapped = unsafe { dev.map_memory(memory, 0, vk::WHOLE_SIZE, vk::MemoryMapFlags::empty()) }
                .call("vkMapMemory")?
                .cast();
        }
        Ok(out)
    }

    /// Copies `data` into a mapped buffer.
    pub(crate) fn write<T: bytemuck::Pod>(&mut self, data: &[T]) {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        assert!(!self.mapped.is_null() && bytes.len() as u64 <= self.size);
        // SAFETY: mapped, large enough, not in use by the GPU.
        unsafe { std::ptr::copy_nonoverlapping(bytes.as_ptr(), self.mapped, bytes.len()) };
    }

    /// Reads `len` elements from a mapped buffer.
    pub(crate) fn read<T: bytemuck::Pod>(&self, len: usize) -> Vec<T> {
        let bytes = len * std::mem::size_of::<T>();
        assert!(!self.mapped.is_null() && bytes as u64 <= self.size);
        let mut out = vec![T::zeroed(); len];
        // SAFETY: mapped, large enough, the GPU has finished writing.
        unsafe { std::ptr::copy_nonoverlapping(self.mapped, out.as_mut_ptr().cast::<u8>(), bytes) };
        out
    }
}

impl Drop for Buffer {
    fn drop(&mut self) {
        // SAFETY: the owner drops buffers only after the GPU is done with them.
        unsafe {
            self.device.destroy_buffer(self.buffer, None);
            self.device.free_memory(self.memory, None);
        }
        if let Some((u, bytes)) = &self.usage {
            u.sub(*bytes);
        }
    }
}
