//! How a body reaches its buffers, so that one body serves both backends.
//!
//! On the GPU a body sees whole storage buffers (`[T]`) and indexes them with
//! global indices. On the CPU, rayon gives each task a disjoint window of an
//! output buffer ([`Window`]); the body still uses global indices and the
//! window translates them (a write outside the window panics, which checks
//! that threads write only their own part). Shared counters go through
//! [`AtomicCounters`]: spirv-std atomics on the GPU, std atomics on the CPU.

/// A buffer a body writes, indexed by global element index.
pub trait OutBuf<T: Copy> {
    /// Reads element `i`.
    fn read(&self, i: usize) -> T;
    /// Writes element `i`.
    fn write(&mut self, i: usize, value: T);
}

impl<T: Copy> OutBuf<T> for [T] {
    #[inline]
    fn read(&self, i: usize) -> T {
        self[i]
    }
    #[inline]
    fn write(&mut self, i: usize, value: T) {
        self[i] = value;
    }
}

/// The part `start..start + data.len()` of a larger buffer, addressed with
/// the larger buffer's indices.
pub struct Window<'a, T> {
    /// Global index of `data[0]`.
    pub start: usize,
    /// The elements this window owns.
    pub data: &'a mut [T],
}

impl<T: Copy> OutBuf<T> for Window<'_, T> {
    #[inline]
    fn read(&self, i: usize) -> T {
        self.data[i - self.start]
    }
    #[inline]
    fn write(&mut self, i: usize, value: T) {
        self.data[i - self.start] = value;
    }
}

/// `u32` counters that many threads add to at once.
pub trait AtomicCounters {
    /// Adds `value` to counter `i` and returns its previous value.
    fn fetch_add(&mut self, i: usize, value: u32) -> u32;
}

/// A storage buffer of counters on the GPU.
pub struct DeviceCounters<'a>(pub &'a mut [u32]);

impl AtomicCounters for DeviceCounters<'_> {
    #[inline]
    fn fetch_add(&mut self, i: usize, value: u32) -> u32 {
        #[cfg(target_arch = "spirv")]
        {
            use spirv_std::memory::{Scope, Semantics};
            // SAFETY: an atomic add on a storage buffer element.
            unsafe {
                spirv_std::arch::atomic_i_add::<u32, { Scope::Device as u32 }, { Semantics::NONE.bits() }>(
                    &mut self.0[i],
                    value,
                )
            }
        }
        #[cfg(not(target_arch = "spirv"))]
        {
            // Natively a `&mut` buffer is not shared: a plain add is atomic.
            let old = self.0[i];
            self.0[i] = old.wrapping_add(value);
            old
        }
    }
}

#[cfg(not(target_arch = "spirv"))]
impl AtomicCounters for &[core::sync::atomic::AtomicU32] {
    #[inline]
    fn fetch_add(&mut self, i: usize, value: u32) -> u32 {
        self[i].fetch_add(value, core::sync::atomic::Ordering::Relaxed)
    }
}

/// `i64` sums that many threads add to at once (fixed-point integrals and
/// counters: integer adds commute, so results do not depend on timing).
pub trait AtomicSums {
    /// Adds `value` to sum `i`.
    fn add(&mut self, i: usize, value: i64);
    /// Sets sum `i` to `key` if it is 0 (atomically); whether it holds
    /// `key` now (set here or before): a slot claimed by one key.
    fn claim(&mut self, i: usize, key: i64) -> bool;
}

/// A storage buffer of sums on the GPU.
pub struct DeviceSums<'a>(pub &'a mut [i64]);

impl AtomicSums for DeviceSums<'_> {
    #[inline]
    fn add(&mut self, i: usize, value: i64) {
        #[cfg(target_arch = "spirv")]
        {
            use spirv_std::memory::{Scope, Semantics};
            // SAFETY: an atomic add on a storage buffer element.
            unsafe {
                spirv_std::arch::atomic_i_add::<i64, { Scope::Device as u32 }, { Semantics::NONE.bits() }>(
                    &mut self.0[i],
                    value,
                );
            }
        }
        #[cfg(not(target_arch = "spirv"))]
        {
            self.0[i] = self.0[i].wrapping_add(value);
        }
    }

    #[inline]
    fn claim(&mut self, i: usize, key: i64) -> bool {
        #[cfg(target_arch = "spirv")]
        {
            use spirv_std::memory::{Scope, Semantics};
            // SAFETY: an atomic compare-exchange on a storage buffer element.
            let was = unsafe {
                spirv_std::arch::atomic_compare_exchange::<
                    i64,
                    { Scope::Device as u32 },
                    { Semantics::NONE.bits() },
                    { Semantics::NONE.bits() },
                >(&mut self.0[i], key, 0)
            };
            was == 0 || was == key
        }
        #[cfg(not(target_arch = "spirv"))]
        {
            if self.0[i] == 0 {
                self.0[i] = key;
            }
            self.0[i] == key
        }
    }
}

#[cfg(not(target_arch = "spirv"))]
impl AtomicSums for &[core::sync::atomic::AtomicI64] {
    #[inline]
    fn add(&mut self, i: usize, value: i64) {
        self[i].fetch_add(value, core::sync::atomic::Ordering::Relaxed);
    }

    #[inline]
    fn claim(&mut self, i: usize, key: i64) -> bool {
        use core::sync::atomic::Ordering::Relaxed;
        self[i].compare_exchange(0, key, Relaxed, Relaxed).is_ok() || self[i].load(Relaxed) == key
    }
}

/// A list of `(tet, site)` pairs many threads append to (the pairs a
/// kernel could not finish).
pub trait PairList {
    /// Appends a pair.
    fn push(&mut self, tet: u32, site: u32);
}

/// A pair list in a storage buffer: element 0 counts the pairs, which
/// follow as two `u32` each. Pairs beyond the capacity are counted but not
/// stored (the host sizes the buffer for the worst case, so none is lost).
pub struct DeviceList<'a>(pub &'a mut [u32]);

impl PairList for DeviceList<'_> {
    #[inline]
    fn push(&mut self, tet: u32, site: u32) {
        let slot = 1 + 2 * DeviceCounters(&mut *self.0).fetch_add(0, 1) as usize;
        if slot + 1 < self.0.len() {
            self.0[slot] = tet;
            self.0[slot + 1] = site;
        }
    }
}
