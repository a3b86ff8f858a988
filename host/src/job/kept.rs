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
//! A job reads its candidates in its own site indices and quantized units
//! ([`SiteCandidates`]) and returns its lists so ([`LocalKept`]); the
//! diagram keeps them with what maps one job's sites to the next job's
//! input points and the reach in input units ([`KeptLists`],
//! [`Candidates`]).

/// The last frame's kept lists as a job's candidates: rows of the last
/// job's site indices, how those sites are numbered in this job's input
/// (`u32::MAX`: no point of it), and each answered input site's row. The
/// rows are the last frame's, borrowed.
#[derive(Clone, Debug, Default)]
pub struct Candidates<'a> {
    /// Entries per row.
    pub k: usize,
    /// The rows, `k` entries each (last job's site indices; `NO_SITE`:
    /// none).
    pub lists: &'a [u32],
    /// Per row: every point of this job nearer than this (input units) to
    /// its site is among the row's (0: none certain).
    pub reach: Vec<f64>,
    /// The last job's site `v` is this job's input point `to_input[v]`.
    pub to_input: Vec<u32>,
    /// Answered input site `i`'s row (`u32::MAX`: none, search).
    pub row_of: &'a [u32],
}

/// What a job keeps of its sites' lists ([`crate::job::clip::ClipJob::keep`]).
#[derive(Clone, Debug, Default)]
pub struct Keep {
    /// Entries kept per site (at least the job's `k_site`).
    pub k: u32,
    /// Candidates from the last frame, per listed site, if any.
    pub candidates: Option<SiteCandidates>,
    /// Whether the lists' entries are kept (a trajectory's next frame reads
    /// them), or only their distances (a part's certificate: `k` entries a
    /// site are the largest thing a part would hold for it).
    pub entries: bool,
}

/// [`Candidates`] in a job's terms: `k` candidates per listed site (job
/// order; job site indices, [`cvd_kernels::abi::NO_SITE`] holes), and
/// the squared quantized distance below which every site is among them
/// (0: none).
#[derive(Clone, Debug, Default)]
pub struct SiteCandidates {
    /// Entries per site.
    pub k: usize,
    /// The candidates, `k` per listed site.
    pub sites: Vec<u32>,
    /// Per listed site, squared quantized distance.
    pub below2: Vec<u64>,
}

impl SiteCandidates {
    /// Site `u`'s candidates.
    pub fn of(&self, u: usize) -> &[u32] {
        self.sites.get(u * self.k..(u + 1) * self.k).unwrap_or(&[])
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
    /// The lists, `k` entries each (none unless [`Keep::entries`]).
    pub lists: Vec<u32>,
    /// Per list: the squared quantized distance of its last entry.
    pub last2: Vec<u64>,
    /// Per list: the squared quantized distance of its `k_site`-th entry
    /// (the last the cell's list holds).
    pub kth2: Vec<u64>,
    /// Per list: taken from the candidates (no grid searched).
    pub reused: Vec<bool>,
}

/// The lists a job kept ([`LocalKept`]) with what reads them later: the
/// job's sites' input indices, and each list's reach in input units (the
/// distance within which it holds every point: a searched list's from its
/// last entry, less the quantization's rounding, infinite where it holds
/// every point; a list taken from the candidates keeps theirs).
#[derive(Clone, Debug, Default)]
pub struct KeptLists {
    /// Entries per list.
    pub k: usize,
    /// The lists, `k` per listed site (job order, job site indices,
    /// `NO_SITE` past the sites there are).
    pub lists: Vec<u32>,
    /// Per listed site: every point nearer than this is listed.
    pub reach: Vec<f64>,
    /// Per listed site: the distance of the `k_site`-th entry (input
    /// units; infinite past the sites there are).
    pub kth: Vec<f64>,
    /// Each job site's input index.
    pub inputs: Vec<u32>,
    /// Lists that came from the candidates.
    pub reused: usize,
    /// The median reach beyond the `k_site`-th entry of the lists searched
    /// afresh, where they are most of them (else 0).
    pub skin: f64,
    /// A part's cells (input indices, increasing) whose walks had to leave
    /// its window (`Counters::out_of_halo`): the part does them again with
    /// a wider halo.
    pub left: Vec<u32>,
    /// Per listed site: its cell's kind as the kernels' first pass counted
    /// it ([`crate::job::clip::cell_kind`]); empty where the backend does
    /// not say.
    pub kinds: Vec<u8>,
}
