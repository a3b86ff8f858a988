//! A job's memory, estimated before anything is allocated, against what
//! the machine has: a job too large is refused with both numbers
//! ([`Error::TooLarge`]), never ended by a failed allocation.
//!
//! The estimate is the CPU backend's, as measured (docs/BENCHMARKS.md
//! "Memory at 1M and 10M sites": 318 MB at 1M sites and 1M tets with
//! 48-entry lists of 20 bits): per site, its neighbour list (`k_site`
//! entries of as many bits as a site index needs, in whole words) and 200
//! bytes (the caller's sites, the kernels' sites, the quantized sites, the
//! sums, the grid, the maps); per tet, 40 bytes; with faces, the kernels'
//! face sums (`k_site + 9` of 8 bytes per site) and the adjacency (about
//! 16 faces of 48 bytes). It errs high.

pub use crate::error::human;
use crate::error::{Error, Result};

/// What a job is made of, for its estimate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct JobSize {
    /// Sites (with a periodic box's images).
    pub sites: u64,
    /// Tets.
    pub tets: u64,
    /// Neighbours per site's list.
    pub k_site: u64,
    /// Whether the cells' faces are summed.
    pub faces: bool,
}

impl JobSize {
    /// Bytes the CPU backend holds for the job, at most about.
    pub fn bytes(&self) -> u64 {
        let bits = 64 - self.sites.max(1).leading_zeros() as u64;
        let list = (self.k_site * bits).div_ceil(32) * 4;
        let faces = if self.faces { (self.k_site + 9) * 8 + 16 * 48 } else { 0 };
        let per_site = 200 + list + faces;
        self.sites.saturating_mul(per_site).saturating_add(self.tets.saturating_mul(40))
    }
}

/// The memory this machine has available now (Linux: `MemAvailable` in
/// `/proc/meminfo`), if it can tell.
pub fn available() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib.saturating_mul(1024))
}

/// The most memory this process has held so far (Linux: `VmHWM` in
/// `/proc/self/status`), if it can tell.
pub fn peak() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = text.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib.saturating_mul(1024))
}

/// Refuses `needed` bytes for `what` over `budget` (a limit the caller
/// set, e.g. `--memory-budget`), or else over the memory the machine has
/// available ([`available`]; unknown: not refused).
pub fn check(what: &str, needed: u64, budget: Option<u64>) -> Result<()> {
    let (limit, of) = match budget {
        Some(b) => (b, "the memory budget (--memory-budget)"),
        None => match available() {
            Some(a) => (a, "the memory this machine has available"),
            None => return Ok(()),
        },
    };
    if needed > limit {
        return Err(Error::TooLarge { what: what.to_string(), needed, limit, of: of.to_string() });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_estimate_covers_what_was_measured() {
        // 1M sites, 1M tets, 48-entry lists, no faces: 318 MB measured.
        let at_1m = JobSize { sites: 1_000_000, tets: 1_000_000, k_site: 48, faces: false }.bytes();
        assert!((318_000_000..400_000_000).contains(&at_1m), "{at_1m}");
        // 10M: 3.36 GB measured (24-bit lists).
        let at_10m = JobSize { sites: 10_000_000, tets: 10_000_000, k_site: 48, faces: false }.bytes();
        assert!((3_360_000_000..4_200_000_000).contains(&at_10m), "{at_10m}");
        let faces = JobSize { faces: true, ..JobSize { sites: 1_000_000, tets: 0, k_site: 48, faces: false } };
        assert!(faces.bytes() > 1_000_000 * (57 * 8), "the face sums");
        // Absurd sizes saturate, never wrap.
        assert_eq!(JobSize { sites: u64::MAX, tets: u64::MAX, k_site: 90, faces: true }.bytes(), u64::MAX);
    }

    #[test]
    fn over_the_budget_is_refused_with_both_numbers() {
        let e = check("the job", 2 << 30, Some(1 << 30)).unwrap_err();
        assert!(e.is_input_error());
        let m = e.to_string();
        assert!(
            m.contains("the job") && m.contains("2.1 GB") && m.contains("1.1 GB") && m.contains("--memory-budget"),
            "{m}"
        );
        assert!(check("the job", 1 << 20, Some(1 << 30)).is_ok());
        if let Some(a) = available() {
            assert!(a > 0);
            assert!(check("everything", u64::MAX, None).is_err());
        }
        assert_eq!(human(999), "999 bytes");
        assert_eq!(human(240_000_000_000), "240.0 GB");
    }
}
