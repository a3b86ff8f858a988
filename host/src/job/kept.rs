//! Neighbour lists kept from one frame of a trajectory for the next.
//!
//! A whole cell is built from its site's `k_site` nearest sites, nearest
//! first ([`cvd_kernels::cell`]). A frame can keep each site's `k` nearest
//! (`k >= k_site`, a skin of spare neighbours) and the distance `r` within
//! which every site is among them. In the next frame, with each site moved
//! by at most `d` and site `i` by `d_i`, every site now within
//! `r - d_i - d` of site `i` was within `r` of it before: the kept list,
//! its sites taken where they are now, still holds them. Sorted again
//! (by the k-NN's own exact distances, [`cvd_kernels::knn::candidate_query`]),
//! its first `k_site` entries are the site's new k-NN list, entry for
//! entry, as soon as the `k_site`-th lies nearer than that: then no grid
//! is searched for it. Where not, the site's list is searched anew.
//!
//! The host side speaks of input points and their units ([`Candidates`],
//! [`KeptLists`]); the job, of its sites and quantized units
//! ([`SiteCandidates`], [`LocalKept`]).

/// Each answered site's candidate neighbours for a job (input indices,
/// in any order) and the distance within which every point of the job is
/// among them (input units; 0: none, search the grid).
#[derive(Clone, Debug, Default)]
pub struct Candidates {
    /// Site `i`'s candidates: `points[offsets[i]..offsets[i + 1]]`.
    pub offsets: Vec<usize>,
    /// Input point indices.
    pub points: Vec<u32>,
    /// Per site: every input point nearer than this is a candidate.
    pub reach: Vec<f64>,
}

impl Candidates {
    /// Site `i`'s candidates.
    pub fn of(&self, i: usize) -> &[u32] {
        &self.points[self.offsets[i]..self.offsets[i + 1]]
    }

    /// Sites with candidates.
    pub fn len(&self) -> usize {
        self.reach.len()
    }

    /// Whether no site has any.
    pub fn is_empty(&self) -> bool {
        self.reach.is_empty()
    }
}

/// What a job keeps of its sites' lists ([`crate::job::clip::ClipJob::keep`]).
#[derive(Clone, Debug, Default)]
pub struct Keep {
    /// Entries kept per site (at least the job's `k_site`).
    pub k: u32,
    /// Candidates from the last frame, per listed site, if any.
    pub candidates: Option<SiteCandidates>,
}

/// [`Candidates`] in a job's terms: per listed site (job order), its
/// candidates as job site indices, and the squared quantized distance
/// below which every site is among them (0: none).
#[derive(Clone, Debug, Default)]
pub struct SiteCandidates {
    /// Site `u`'s candidates: `sites[offsets[u]..offsets[u + 1]]`.
    pub offsets: Vec<u32>,
    /// Job site indices.
    pub sites: Vec<u32>,
    /// Per site, squared quantized distance.
    pub below2: Vec<u64>,
}

impl SiteCandidates {
    /// Site `u`'s candidates.
    pub fn of(&self, u: usize) -> &[u32] {
        match (self.offsets.get(u), self.offsets.get(u + 1)) {
            (Some(&a), Some(&b)) => &self.sites[a as usize..b as usize],
            _ => &[],
        }
    }
}

/// The lists a job kept, in its terms: `k` per listed site (job order),
/// nearest first ([`cvd_kernels::abi::NO_SITE`] past the sites there
/// are), with each list's last squared distance (`u64::MAX`: fewer sites
/// than `k`, every one listed) and whether it came from the candidates.
#[derive(Clone, Debug, Default)]
pub struct LocalKept {
    /// Entries per list.
    pub k: u32,
    /// The lists, `k` entries each.
    pub lists: Vec<u32>,
    /// Per list: the squared quantized distance of its last entry.
    pub last2: Vec<u64>,
    /// Per list: taken from the candidates (no grid searched).
    pub reused: Vec<bool>,
}

/// Each answered site's kept list in input terms: `k` input point indices
/// per site, nearest first (`u32::MAX` past the points there are), the
/// distance within which every point is listed (input units; infinite
/// when every point is), and how many lists came from the last frame's.
#[derive(Clone, Debug, Default)]
pub struct KeptLists {
    /// Entries per site.
    pub k: usize,
    /// The lists, `k` entries per answered site, in input order.
    pub points: Vec<u32>,
    /// Per answered site: every point nearer than this is listed.
    pub reach: Vec<f64>,
    /// Lists that came from the candidates.
    pub reused: usize,
}

impl KeptLists {
    /// Site `i`'s list (entries `u32::MAX` past the points there are).
    pub fn of(&self, i: usize) -> &[u32] {
        &self.points[i * self.k..(i + 1) * self.k]
    }
}
