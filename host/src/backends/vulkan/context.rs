//! Instance, device and queue: found at run time, checked for what the
//! kernels need.

use crate::error::{Error, Result, VkContext};
use ash::vk;
use std::ffi::{c_void, CStr};
use std::sync::atomic::{AtomicUsize, Ordering};

/// Device selection and debugging options.
#[derive(Clone, Debug, Default)]
pub struct VulkanOptions {
    /// A device index (as listed by `cvd devices`) or part of its name.
    pub device: Option<String>,
    /// Enable the Khronos validation layer (also with `CVD_VALIDATION=1`).
    pub validation: bool,
    /// Most device memory a job may hold, in bytes (default: 80 % of the
    /// device's largest device-local heap). Larger jobs run in chunks.
    pub memory_budget: Option<u64>,
}

const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";

static VALIDATION_ERRORS: AtomicUsize = AtomicUsize::new(0);

/// Validation-layer errors reported since the process started.
pub fn validation_errors() -> usize {
    VALIDATION_ERRORS.load(Ordering::SeqCst)
}

unsafe extern "system" fn debug_callback(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _types: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    _user: *mut c_void,
) -> vk::Bool32 {
    // SAFETY: the layer passes a valid callback-data pointer for the call.
    let message = unsafe { data.as_ref().and_then(|d| d.message_as_c_str()) }
        .map(|m| m.to_string_lossy().into_owned())
        .unwrap_or_default();
    if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::ERROR) {
        VALIDATION_ERRORS.fetch_add(1, Ordering::SeqCst);
        eprintln!("cvd: Vulkan validation error: {message}");
    } else {
        eprintln!("cvd: Vulkan validation warning: {message}");
    }
    vk::FALSE
}

/// A description of a physical device.
#[derive(Clone, Debug)]
pub struct DeviceInfo {
    /// Index among the instance's devices.
    pub index: usize,
    /// Driver-reported name.
    pub name: String,
    /// Discrete, integrated, CPU, ...
    pub kind: vk::PhysicalDeviceType,
    /// Vulkan API version.
    pub api_version: u32,
}

impl DeviceInfo {
    /// A real GPU (discrete, integrated or virtual), not a device that
    /// implements Vulkan on the CPU (lavapipe, SwiftShader).
    pub fn is_gpu(&self) -> bool {
        self.gpu_rank().is_some()
    }

    /// For a real GPU, its rank in the default choice: discrete 0,
    /// integrated 1, virtual 2.
    pub fn gpu_rank(&self) -> Option<u8> {
        match self.kind {
            vk::PhysicalDeviceType::DISCRETE_GPU => Some(0),
            vk::PhysicalDeviceType::INTEGRATED_GPU => Some(1),
            vk::PhysicalDeviceType::VIRTUAL_GPU => Some(2),
            _ => None,
        }
    }

    /// What kind of device it is, in words.
    pub fn kind_name(&self) -> &'static str {
        match self.kind {
            vk::PhysicalDeviceType::DISCRETE_GPU => "discrete GPU",
            vk::PhysicalDeviceType::INTEGRATED_GPU => "integrated GPU",
            vk::PhysicalDeviceType::VIRTUAL_GPU => "virtual GPU",
            vk::PhysicalDeviceType::CPU => "Vulkan on the CPU",
            _ => "other device",
        }
    }
}

/// An open Vulkan device with one compute queue.
pub struct Context {
    _entry: ash::Entry,
    pub(crate) instance: ash::Instance,
    debug: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    pub(crate) device: ash::Device,
    pub(crate) queue: vk::Queue,
    /// Vulkan requires external synchronisation of queue submissions.
    pub(crate) queue_lock: std::sync::Mutex<()>,
    pub(crate) queue_family: u32,
    pub(crate) memory: vk::PhysicalDeviceMemoryProperties,
    pub(crate) limits: vk::PhysicalDeviceLimits,
    /// Nanoseconds per timestamp tick.
    pub(crate) timestamp_period: f64,
    pub(crate) info: DeviceInfo,
    /// Device-local memory held by the buffers.
    pub(crate) usage: std::sync::Arc<super::memory::MemoryUsage>,
    /// Most device memory one job may hold, in bytes.
    pub(crate) memory_budget: std::sync::atomic::AtomicU64,
}

fn load_entry() -> Result<ash::Entry> {
    // SAFETY: loading the system's Vulkan loader library.
    unsafe { ash::Entry::load() }.map_err(|e| Error::VulkanUnavailable(format!("no Vulkan loader ({e})")))
}

fn create_instance(entry: &ash::Entry, validation: bool) -> Result<ash::Instance> {
    let app = vk::ApplicationInfo::default().application_name(c"cvd").api_version(vk::API_VERSION_1_2);
    let mut layers = Vec::new();
    let mut extensions = Vec::new();
    if validation {
        // SAFETY: plain enumeration calls.
        let available =
            unsafe { entry.enumerate_instance_layer_properties() }.call("vkEnumerateInstanceLayerProperties")?;
        if !available.iter().any(|l| l.layer_name_as_c_str() == Ok(VALIDATION_LAYER)) {
            return Err(Error::VulkanUnavailable(
                "validation was asked for but VK_LAYER_KHRONOS_validation is not installed (Debian: vulkan-validationlayers)".into(),
            ));
        }
        layers.push(VALIDATION_LAYER.as_ptr());
        extensions.push(ash::ext::debug_utils::NAME.as_ptr());
    }
    let info = vk::InstanceCreateInfo::default()
        .application_info(&app)
        .enabled_layer_names(&layers)
        .enabled_extension_names(&extensions);
    // SAFETY: valid create info.
    unsafe { entry.create_instance(&info, None) }
        .map_err(|e| Error::VulkanUnavailable(format!("vkCreateInstance failed: {e}")))
}

/// Lists the Vulkan devices (for `cvd devices`).
pub fn list_devices() -> Result<Vec<DeviceInfo>> {
    let entry = load_entry()?;
    let instance = create_instance(&entry, false)?;
    let out = describe_devices(&instance);
    // SAFETY: nothing else uses the instance.
    unsafe { instance.destroy_instance(None) };
    out.map(|d| d.into_iter().map(|(_, info)| info).collect())
}

fn describe_devices(instance: &ash::Instance) -> Result<Vec<(vk::PhysicalDevice, DeviceInfo)>> {
    // SAFETY: valid instance.
    let devices = unsafe { instance.enumerate_physical_devices() }.call("vkEnumeratePhysicalDevices")?;
    Ok(devices
        .into_iter()
        .enumerate()
        .map(|(index, pd)| {
            // SAFETY: valid physical device.
            let props = unsafe { instance.get_physical_device_properties(pd) };
            let name = props.device_name_as_c_str().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            (pd, DeviceInfo { index, name, kind: props.device_type, api_version: props.api_version })
        })
        .collect())
}

fn pick_device(devices: &[(vk::PhysicalDevice, DeviceInfo)], wanted: Option<&str>) -> Result<usize> {
    let listing = || devices.iter().map(|(_, d)| format!("{}: {}", d.index, d.name)).collect::<Vec<_>>().join(", ");
    if devices.is_empty() {
        return Err(Error::VulkanUnavailable("no Vulkan device found".into()));
    }
    if let Some(w) = wanted {
        let found = match w.parse::<usize>() {
            Ok(i) => devices.iter().position(|(_, d)| d.index == i),
            Err(_) => devices.iter().position(|(_, d)| d.name.to_lowercase().contains(&w.to_lowercase())),
        };
        return found.ok_or_else(|| Error::NoSuchDevice { wanted: w.into(), available: listing() });
    }
    let rank = |d: &DeviceInfo| d.gpu_rank().unwrap_or(if d.kind == vk::PhysicalDeviceType::CPU { 3 } else { 4 });
    Ok((0..devices.len()).min_by_key(|&i| (rank(&devices[i].1), i)).unwrap_or(0))
}

impl Context {
    /// Opens the device the options name, or the best one.
    pub fn new(options: &VulkanOptions) -> Result<Self> {
        let validation = options.validation || std::env::var("CVD_VALIDATION").is_ok_and(|v| v == "1");
        let entry = load_entry()?;
        let instance = create_instance(&entry, validation)?;
        // `open` takes a handle on the loader; this one keeps the library
        // loaded until the instance is destroyed if opening fails.
        match Self::open(entry.clone(), instance.clone(), validation, options) {
            Ok(ctx) => Ok(ctx),
            Err(e) => {
                // SAFETY: nothing else holds the instance; the loader is loaded.
                unsafe { instance.destroy_instance(None) };
                drop(entry);
                Err(e)
            }
        }
    }

    fn open(entry: ash::Entry, instance: ash::Instance, validation: bool, options: &VulkanOptions) -> Result<Self> {
        let debug = if validation {
            let loader = ash::ext::debug_utils::Instance::new(&entry, &instance);
            let info = vk::DebugUtilsMessengerCreateInfoEXT::default()
                .message_severity(
                    vk::DebugUtilsMessageSeverityFlagsEXT::ERROR | vk::DebugUtilsMessageSeverityFlagsEXT::WARNING,
                )
                .message_type(
                    vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                        | vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
                        | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE,
                )
                .pfn_user_callback(Some(debug_callback));
            // SAFETY: valid create info.
            let messenger =
                unsafe { loader.create_debug_utils_messenger(&info, None) }.call("vkCreateDebugUtilsMessengerEXT")?;
            Some((loader, messenger))
        } else {
            None
        };
        let devices = describe_devices(&instance)?;
        let chosen = pick_device(&devices, options.device.as_deref())?;
        let (physical, info) = devices[chosen].clone();
        if info.api_version < vk::API_VERSION_1_2 {
            return Err(Error::MissingFeature { device: info.name, missing: "Vulkan 1.2".into() });
        }

        // SAFETY: valid physical device.
        let families = unsafe { instance.get_physical_device_queue_family_properties(physical) };
        let queue_family = families
            .iter()
            .position(|f| f.queue_flags.contains(vk::QueueFlags::COMPUTE) && f.timestamp_valid_bits > 0)
            .or_else(|| families.iter().position(|f| f.queue_flags.contains(vk::QueueFlags::COMPUTE)))
            .ok_or_else(|| Error::MissingFeature { device: info.name.clone(), missing: "a compute queue".into() })?
            as u32;

        let mut f12 = vk::PhysicalDeviceVulkan12Features::default();
        let mut f2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut f12);
        // SAFETY: valid physical device and feature chain.
        unsafe { instance.get_physical_device_features2(physical, &mut f2) };
        let core = f2.features;
        let checks = [
            ("shaderInt64", core.shader_int64),
            ("shaderBufferInt64Atomics", f12.shader_buffer_int64_atomics),
            ("vulkanMemoryModel", f12.vulkan_memory_model),
            ("vulkanMemoryModelDeviceScope", f12.vulkan_memory_model_device_scope),
        ];
        if let Some((name, _)) = checks.iter().find(|(_, on)| *on == vk::FALSE) {
            return Err(Error::MissingFeature { device: info.name, missing: format!("the feature {name}") });
        }

        let enable_core = vk::PhysicalDeviceFeatures::default().shader_int64(true);
        let mut enable12 = vk::PhysicalDeviceVulkan12Features::default()
            .shader_buffer_int64_atomics(true)
            .vulkan_memory_model(true)
            .vulkan_memory_model_device_scope(true);
        let priorities = [1.0f32];
        let queues =
            [vk::DeviceQueueCreateInfo::default().queue_family_index(queue_family).queue_priorities(&priorities)];
        let device_info = vk::DeviceCreateInfo::default()
            .queue_create_infos(&queues)
            .enabled_features(&enable_core)
            .push_next(&mut enable12);
        // SAFETY: valid create info; the features were checked above.
        let device = unsafe { instance.create_device(physical, &device_info, None) }.call("vkCreateDevice")?;
        // SAFETY: the queue family and index exist.
        let queue = unsafe { device.get_device_queue(queue_family, 0) };
        // SAFETY: valid physical device.
        let memory = unsafe { instance.get_physical_device_memory_properties(physical) };
        // SAFETY: valid physical device.
        let props = unsafe { instance.get_physical_device_properties(physical) };
        let largest_heap = (0..memory.memory_heap_count as usize)
            .map(|h| memory.memory_heaps[h])
            .filter(|h| h.flags.contains(vk::MemoryHeapFlags::DEVICE_LOCAL))
            .map(|h| h.size)
            .max()
            .unwrap_or(1 << 30);
        Ok(Self {
            _entry: entry,
            instance,
            debug,
            device,
            queue,
            queue_lock: std::sync::Mutex::new(()),
            queue_family,
            memory,
            limits: props.limits,
            timestamp_period: props.limits.timestamp_period as f64,
            info,
            usage: Default::default(),
            memory_budget: options.memory_budget.unwrap_or(largest_heap / 5 * 4).into(),
        })
    }

    /// The device's description.
    pub fn info(&self) -> &DeviceInfo {
        &self.info
    }
}

impl Drop for Context {
    fn drop(&mut self) {
        // SAFETY: every child object is destroyed by its owner before this.
        unsafe {
            let _ = self.device.device_wait_idle();
            self.device.destroy_device(None);
            if let Some((loader, messenger)) = self.debug.take() {
                loader.destroy_debug_utils_messenger(messenger, None);
            }
            self.instance.destroy_instance(None);
        }
    }
}
