//! The sites as the kernels take them: checked, duplicates merged, in
//! Morton order, told apart in the kernels' split coordinates — with a
//! map from each input site to its place, in memory proportional to 4
//! bytes per site beyond the inputs (no hash maps of coordinates).

use crate::error::{Error, Result};
use cvd_kernels::abi::SplitPoint;
use std::hash::{BuildHasher, Hash};

/// Refuses no sites, a non-finite coordinate, and weights that are not one
/// finite number per site, naming the site.
pub(crate) fn check_sites(sites: &[[f64; 3]], weights: Option<&[f64]>) -> Result<()> {
    if sites.is_empty() {
        return Err(Error::InvalidInput("there are no sites".into()));
    }
    if let Some(i) = sites.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
        return Err(Error::InvalidInput(format!("site {i} has a non-finite coordinate: {:?}", sites[i])));
    }
    if let Some(w) = weights {
        if w.len() != sites.len() {
            return Err(Error::InvalidInput(format!("{} weights for {} sites", w.len(), sites.len())));
        }
        if let Some(i) = w.iter().position(|w| !w.is_finite()) {
            return Err(Error::InvalidInput(format!("the weight of site {i} is {}; it must be finite", w[i])));
        }
    }
    Ok(())
}

/// Each input site's place among the kernels' sites, or none for a
/// duplicate (whose cell its twin holds): 4 bytes per site.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SiteMap(Vec<u32>);

const NONE: u32 = u32::MAX;

impl SiteMap {
    /// Input sites.
    pub fn len(&self) -> usize {
        self.0.len()
    }

    /// Whether there are no input sites.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// Input site `i`'s place, or `None` for a duplicate.
    pub fn get(&self, i: usize) -> Option<usize> {
        match self.0[i] {
            NONE => None,
            u => Some(u as usize),
        }
    }

    /// Each of `n` places' input site (`u32::MAX` for a place no input
    /// site has): the map turned around.
    pub fn inputs(&self, n: usize) -> Vec<u32> {
        let mut inputs = vec![NONE; n];
        for (i, &u) in self.0.iter().enumerate() {
            if u != NONE {
                inputs[u as usize] = i as u32;
            }
        }
        inputs
    }

    /// Every input site's place, in input order.
    pub fn iter(&self) -> impl DoubleEndedIterator<Item = Option<usize>> + ExactSizeIterator + '_ {
        self.0.iter().map(|&u| if u == NONE { None } else { Some(u as usize) })
    }
}

/// A set of indices keyed by what `key` says of them, in open addressing:
/// 8 bytes per index at most (the keys stay where they are).
struct IndexTable {
    slots: Vec<u32>,
    hasher: std::collections::hash_map::RandomState,
}

impl IndexTable {
    fn with_capacity(n: usize) -> Self {
        Self { slots: vec![NONE; (2 * n).next_power_of_two().max(2)], hasher: Default::default() }
    }

    /// The slot holding an index whose key equals `key(i)`, or the empty
    /// slot where `i` would go.
    fn find<K: Hash + Eq>(&self, i: usize, key: impl Fn(usize) -> K) -> usize {
        let k = key(i);
        let mask = self.slots.len() - 1;
        let mut s = self.hasher.hash_one(&k) as usize & mask;
        loop {
            match self.slots[s] {
                NONE => return s,
                j if key(j as usize) == k => return s,
                _ => s = (s + 1) & mask,
            }
        }
    }
}

/// The sites the kernels take: one per distinct position — of duplicates
/// the largest weight, the lowest index on a tie (without weights: the
/// lowest index) — in Morton order; those of input index below `first`
/// before the others (a periodic box's sites before their images), each
/// group in Morton order. Returns the input index of each, in that order,
/// and each input site's place ([`SiteMap`]).
pub(crate) fn unique_in_morton_order(sites: &[[f64; 3]], weights: Option<&[f64]>, first: usize) -> (Vec<u32>, SiteMap) {
    let weight = |i: usize| weights.map_or(0.0, |w| w[i]);
    let key = |i: usize| sites[i].map(|c| if c == 0.0 { 0 } else { c.to_bits() });
    let mut table = IndexTable::with_capacity(sites.len());
    for i in 0..sites.len() {
        let s = table.find(i, key);
        match table.slots[s] {
            NONE => table.slots[s] = i as u32,
            o if weight(i) > weight(o as usize) => table.slots[s] = i as u32,
            _ => {}
        }
    }
    let owners: Vec<u32> = (0..sites.len() as u32).filter(|&i| table.slots[table.find(i as usize, key)] == i).collect();
    drop(table);
    let order = crate::geom::points::morton_order_by(owners.len(), |u| sites[owners[u] as usize]);
    let mut inputs: Vec<u32> = order.iter().map(|&u| owners[u as usize]).collect();
    if first < sites.len() {
        // Stable: each group keeps its Morton order.
        inputs.sort_by_key(|&i| i as usize >= first);
    }
    let mut map = vec![NONE; sites.len()];
    for (place, &i) in inputs.iter().enumerate() {
        map[i as usize] = place as u32;
    }
    (inputs, SiteMap(map))
}

/// A job whose caller lays its sites out (a periodic box's whole cells,
/// in one process or in parts): the sites in the order given, the frame
/// from bounds given, cells for the sites at some places of that order
/// only. The quantization, the sums' fixed point and each cell's first box
/// then follow from the bounds and not from the sites held, and a site's
/// neighbours keep their order among themselves, ties included: a part
/// that holds every site near its own, laid out in the same order, builds
/// its cells to the same bits as the whole job.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Layout<'a> {
    /// The input index of each place, every input once.
    pub order: &'a [u32],
    /// The frame's corners, in the input's coordinates; every site lies
    /// between them.
    pub lo: [f64; 3],
    /// See `lo`.
    pub hi: [f64; 3],
    /// The sites (and images) of the whole job: the size of its grid,
    /// which a part searches too.
    pub grid_sites: usize,
    /// The places (in `order`) of the sites that get cells: from the
    /// first, up to the second.
    pub answer: (usize, usize),
    /// The whole job's smallest and largest weight of a site that owns a
    /// cell (a part's sites hold only some weights); `None`: the job's own.
    pub weights: Option<[f64; 2]>,
    /// The whole job's grid of largest weights (its sites' local weight
    /// bounds read it: [`crate::job::weight_bounds`]), when a part's sites
    /// do not make it; `None`: the job's own.
    pub weight_grid: Option<&'a crate::job::weight_bounds::WeightGrid>,
    /// Which cells of the whole job's grid the job's table holds.
    pub window: Window,
    /// Of a held window ([`Window::Held`]), the cells whose sites the part
    /// does not hold (one bit per cell of the window, set: not held;
    /// [`crate::job::knn::KnnJob::unheld`]); `None`: all of them.
    pub unheld: Option<&'a [u32]>,
    /// A periodic box's sites and images: no cell is cut (else a mesh's
    /// sites, whole cells cut by its boundary).
    pub periodic: bool,
    /// Of the answered places, the only ones whose cells are built
    /// (increasing; [`crate::job::clip::ClipJob::only`], the CPU
    /// backend's); `None`: all of them.
    pub only: Option<&'a [u32]>,
    /// Each row of the adjacency holds its cell's own half of each face
    /// only (the caller adds the other side's, as a diagram in parts
    /// does); else both halves.
    pub halves: bool,
}

/// The cells of the whole job's grid a laid-out job's table holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Window {
    /// Every cell (the whole job).
    Whole,
    /// A part of the job, holding only the sites near its own: its grid's
    /// table is the window of the whole job's grid around its sites
    /// ([`crate::job::knn::KnnJob::windowed`]), and a walk that would
    /// leave the window gives up (counted in `Counters::out_of_halo`).
    Around,
    /// A part holding every site of these cells: its table is theirs, and
    /// a walk that would leave them gives up, likewise.
    Held(crate::job::held::HeldCells),
}

/// [`unique_in_morton_order`] for a [`Layout`]: the sites in its order,
/// each group of duplicates kept at the place of the one that owns their
/// cell (the largest weight, the earliest place on a tie). Also the places
/// of the answered sites among those kept.
pub(crate) fn unique_in_order(
    sites: &[[f64; 3]],
    weights: Option<&[f64]>,
    layout: &Layout,
) -> Result<(Vec<u32>, SiteMap, std::ops::Range<usize>)> {
    let order = layout.order;
    let (first, end) = layout.answer;
    if order.len() != sites.len() || first > end || end > order.len() {
        return Err(Error::Internal(format!(
            "a layout of {} places (answering {:?}) for {} sites",
            order.len(),
            layout.answer,
            sites.len()
        )));
    }
    let weight = |i: usize| weights.map_or(0.0, |w| w[i]);
    let key = |i: usize| sites[i].map(|c| if c == 0.0 { 0 } else { c.to_bits() });
    let mut table = IndexTable::with_capacity(sites.len());
    let mut seen = vec![false; sites.len()];
    for &i in order {
        let i = i as usize;
        if i >= sites.len() || std::mem::replace(&mut seen[i], true) {
            return Err(Error::Internal(format!("a layout places input {i} of {} twice or beyond", sites.len())));
        }
        let s = table.find(i, key);
        match table.slots[s] {
            NONE => table.slots[s] = i as u32,
            o if weight(i) > weight(o as usize) => table.slots[s] = i as u32,
            _ => {}
        }
    }
    let owns = |i: u32| table.slots[table.find(i as usize, key)] == i;
    let before = |place: usize| order[..place].iter().filter(|&&i| owns(i)).count();
    let answer = before(first)..before(end);
    let inputs: Vec<u32> = order.iter().copied().filter(|&i| owns(i)).collect();
    drop(table);
    let mut map = vec![NONE; sites.len()];
    for (place, &i) in inputs.iter().enumerate() {
        map[i as usize] = place as u32;
    }
    Ok((inputs, SiteMap(map), answer))
}

/// Refuses distinct sites the kernels could not tell apart: those whose
/// normalised coordinates, split into `hi + lo` (`split`, the kernels'
/// sites in order, of the input sites `inputs`), are equal. Names them by
/// their input indices.
pub(crate) fn check_separable(split: &[SplitPoint], sites: &[[f64; 3]], inputs: &[u32]) -> Result<()> {
    let key = |u: usize| {
        let p = &split[u];
        [p.hi[0], p.hi[1], p.hi[2], p.lo[0], p.lo[1], p.lo[2]].map(|c| (c + 0.0).to_bits())
    };
    let mut table = IndexTable::with_capacity(inputs.len());
    for u in 0..inputs.len() {
        let s = table.find(u, key);
        if table.slots[s] != NONE {
            let other = table.slots[s] as usize;
            let (a, b) = (inputs[other].min(inputs[u]) as usize, inputs[other].max(inputs[u]) as usize);
            return Err(Error::InvalidInput(format!(
                "sites {a} {:?} and {b} {:?} are distinct but too close to be told apart in the domain's frame \
                 (about 1e-14 of its size); move or merge them",
                sites[a], sites[b]
            )));
        }
        table.slots[s] = u as u32;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn duplicates_keep_the_heaviest_then_the_first() {
        let sites = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [-0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, 0.5, 0.5]];
        let (inputs, map) = unique_in_morton_order(&sites, None, sites.len());
        assert_eq!(inputs.len(), 3);
        assert_eq!(map.iter().filter(|m| m.is_none()).count(), 2);
        // -0.0 and 0.0 are one position; the lower index owns it.
        assert!(map.get(0).is_some() && map.get(2).is_none());
        assert!(map.get(1).is_some() && map.get(3).is_none());
        for (i, m) in map.iter().enumerate() {
            if let Some(u) = m {
                assert_eq!(inputs[u] as usize, i);
            }
        }
        let weights = [0.0, 1.0, 2.0, 1.0, 0.0];
        let (_, map) = unique_in_morton_order(&sites, Some(&weights), sites.len());
        assert!(map.get(2).is_some() && map.get(0).is_none(), "the heavier twin owns the cell");
        assert!(map.get(1).is_some() && map.get(3).is_none(), "equal weights: the first");
    }

    #[test]
    fn many_sites_map_one_to_one_in_morton_order() {
        let sites = crate::geom::points::uniform(20_000, 7);
        let mut with_twins = sites.clone();
        with_twins.extend_from_slice(&sites[..500]);
        let (inputs, map) = unique_in_morton_order(&with_twins, None, with_twins.len());
        assert_eq!(inputs.len(), sites.len());
        assert_eq!(map.len(), with_twins.len());
        assert!((sites.len()..with_twins.len()).all(|i| map.get(i).is_none()));
        let order = crate::geom::points::morton_order(&sites);
        assert_eq!(inputs, order, "the owners in the Morton order of the distinct sites");
    }

    #[test]
    fn the_first_sites_come_first_each_group_in_morton_order() {
        let sites = crate::geom::points::uniform(3_000, 8);
        let first = 1_000;
        let (inputs, map) = unique_in_morton_order(&sites, None, first);
        let all = crate::geom::points::morton_order(&sites);
        let (head, tail): (Vec<u32>, Vec<u32>) = all.iter().partition(|&&i| (i as usize) < first);
        assert_eq!(inputs, [head, tail].concat());
        for (place, &i) in inputs.iter().enumerate() {
            assert_eq!(map.get(i as usize), Some(place));
        }
    }
}
