//! The library's error type.

use ash::vk;

/// Everything that can go wrong, each naming what was expected.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// No Vulkan loader, instance or device could be had.
    #[error("Vulkan is not available: {0}")]
    VulkanUnavailable(String),
    /// A Vulkan call failed.
    #[error("Vulkan call {call} failed: {result}")]
    Vulkan {
        /// The function that failed.
        call: &'static str,
        /// Its result code.
        result: vk::Result,
    },
    /// The chosen device lacks something the kernels need.
    #[error("Vulkan device '{device}' lacks {missing}")]
    MissingFeature {
        /// Device name.
        device: String,
        /// What is missing (feature or extension name).
        missing: String,
    },
    /// `--device` matched no device.
    #[error("no Vulkan device matches '{wanted}'; devices: {available}")]
    NoSuchDevice {
        /// What was asked for.
        wanted: String,
        /// The devices that exist, by index and name.
        available: String,
    },
    /// The input cannot be processed as given.
    #[error("invalid input: {0}")]
    InvalidInput(String),
    /// A file could not be parsed.
    #[error("{path}:{line}: {message}")]
    Parse {
        /// The file.
        path: String,
        /// 1-based line number.
        line: usize,
        /// What was expected.
        message: String,
    },
    /// A file could not be read, with the path it concerns.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The underlying error.
        source: std::io::Error,
    },
    /// A job (or a file to read) larger than the memory it may take:
    /// refused before anything is allocated (`job::memory`).
    #[error(
        "{what} needs about {} of memory, more than {of}: {}; \
         use fewer sites, a machine with more memory, or a distributed run",
        human(*needed),
        human(*limit)
    )]
    TooLarge {
        /// What would not fit.
        what: String,
        /// Bytes it needs (estimated).
        needed: u64,
        /// Bytes it may take.
        limit: u64,
        /// What sets the limit.
        of: String,
    },
    /// A check of the library's own results failed.
    #[error("internal error: {0}")]
    Internal(String),
    /// An output file or folder could not be written.
    #[error("cannot write {path}: {source}")]
    Write {
        /// The file or folder.
        path: String,
        /// The underlying error.
        source: std::io::Error,
    },
}

impl Error {
    /// Whether the error lies in what the caller gave (arguments, input
    /// files, a device name) rather than in the machine or the library.
    pub fn is_input_error(&self) -> bool {
        matches!(
            self,
            Error::InvalidInput(_)
                | Error::Parse { .. }
                | Error::Io { .. }
                | Error::NoSuchDevice { .. }
                | Error::TooLarge { .. }
        )
    }
}

/// Bytes as people read them: `1.5 GB`.
pub fn human(bytes: u64) -> String {
    const UNITS: [&str; 6] = ["bytes", "kB", "MB", "GB", "TB", "PB"];
    let mut x = bytes as f64;
    let mut u = 0;
    while x >= 1000.0 && u + 1 < UNITS.len() {
        x /= 1000.0;
        u += 1;
    }
    if u == 0 {
        format!("{bytes} bytes")
    } else {
        format!("{x:.1} {}", UNITS[u])
    }
}

/// Shorthand for results of this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Adds the name of the failing Vulkan call to a `vk::Result`.
pub(crate) trait VkContext<T> {
    fn call(self, call: &'static str) -> Result<T>;
}

impl<T> VkContext<T> for std::result::Result<T, vk::Result> {
    fn call(self, call: &'static str) -> Result<T> {
        self.map_err(|result| Error::Vulkan { call, result })
    }
}
