//! The sites' neighbour lists as the clipping kernels read them.
//!
//! Each bound site has a list of `k_site` site indices, nearest first,
//! [`NO_SITE`] where fewer sites exist. A list is stored in `bits`-bit
//! entries packed into whole 32-bit words ([`stride`] words per list, so
//! that whoever writes a list owns its words): `bits` = 32 is the plain
//! layout (entry `s` of list `l` at word `l * k + s`); fewer bits, enough
//! for the largest index ([`width`]), keep the same lists in less memory —
//! 20 bits at a million sites, where the lists are most of a job's memory.
//! An entry of all ones is [`NO_SITE`]. Packed lists end with one spare
//! word ([`spare`]): an entry is read with the word after its own.
//!
//! A list that begins with its own site (a site is never its own
//! neighbour) is unknown ([`Lists::unknown`]): a part of a distributed job
//! holds the sites near its tets only, and the host could not certify that
//! site's list from them. What needs it is left for a wider halo.

use crate::abi::{ClipParams, NO_SITE};
use crate::buffers::OutBuf;

/// Marks a site whose list is not bound (see [`Lists::slot`]).
pub const NO_LIST: usize = usize::MAX;

/// The fewest bits that hold every index below `n_sites` with one value to
/// spare for [`NO_SITE`] (at least 1, at most 32).
#[inline]
pub fn width(n_sites: u32) -> u32 {
    let bits = 32 - n_sites.leading_zeros();
    if bits == 0 {
        1
    } else {
        bits
    }
}

/// Words per list of `k` entries of `bits` bits.
#[inline]
pub fn stride(k: u32, bits: u32) -> usize {
    (k as usize * bits as usize).div_ceil(32)
}

/// Words after the last list of packed lists (`bits` < 32): a spare one,
/// read with the last entries (see [`Lists::get`]) and never written.
#[inline]
pub fn spare(bits: u32) -> usize {
    (bits < 32) as usize
}

/// The lists of the sites `base..end`, `k` entries of `bits` bits each,
/// in `words` (see the module's documentation).
#[derive(Clone, Copy)]
pub struct Lists<'a> {
    words: &'a [u32],
    k: u32,
    bits: u32,
    stride: u32,
    base: u32,
    end: u32,
}

impl<'a> Lists<'a> {
    /// The lists of sites `base..end` in `words` (none when `words` is
    /// shorter than they need, e.g. empty).
    #[inline]
    pub fn new(words: &'a [u32], k: u32, bits: u32, base: u32, end: u32) -> Self {
        let stride = stride(k, bits) as u32;
        let held = end > base && (end - base) as usize * stride as usize + spare(bits) <= words.len();
        Self { words, k, bits, stride, base, end: if held { end } else { base } }
    }

    /// The lists a clipping job binds: `k_site` entries of `list_bits` bits
    /// for sites `nbr_base..nbr_end`.
    #[inline]
    pub fn of(p: &ClipParams, words: &'a [u32]) -> Self {
        Self::new(words, p.k_site, p.list_bits, p.nbr_base, p.nbr_end)
    }

    /// Entries per list.
    #[inline]
    pub fn k(&self) -> usize {
        self.k as usize
    }

    /// Where site `j`'s list is ([`Self::get`]), or [`NO_LIST`] when it
    /// is not held.
    #[inline]
    pub fn slot(&self, j: usize) -> usize {
        if j < self.base as usize || j >= self.end as usize {
            NO_LIST
        } else {
            j - self.base as usize
        }
    }

    /// Whether the list at `slot`, site `j`'s, is marked unknown (its first
    /// entry is `j`; see the module's documentation).
    #[inline]
    pub fn unknown(&self, slot: usize, j: u32) -> bool {
        self.k > 0 && self.get(slot, 0) == j
    }

    /// Entry `s` of the list at `slot` (from [`Self::slot`]).
    #[inline]
    pub fn get(&self, slot: usize, s: usize) -> u32 {
        let at = slot * self.stride as usize;
        if self.bits == 32 {
            return self.words[at + s];
        }
        let bit = s * self.bits as usize;
        let w = at + bit / 32;
        // The entry's word and the next, whether it reaches into it or not
        // (the lists end with a spare word): no branch on the bit position.
        let pair = self.words[w] as u64 | (self.words[w + 1] as u64) << 32;
        let mask = (1u32 << self.bits) - 1;
        let v = (pair >> (bit % 32)) as u32 & mask;
        if v == mask {
            NO_SITE
        } else {
            v
        }
    }
}

/// Writes `list` (its `k` entries, [`NO_SITE`] allowed) as the list at
/// `slot` of lists of `bits`-bit entries in `out`: the list's
/// [`stride`] words, and only those.
#[inline]
pub fn pack<O: OutBuf<u32> + ?Sized>(list: &[u32], k: u32, bits: u32, slot: usize, out: &mut O) {
    let words = stride(k, bits);
    let at = slot * words;
    if bits == 32 {
        let mut s = 0;
        while s < k as usize {
            out.write(at + s, list[s]);
            s += 1;
        }
        return;
    }
    let mask = (1u32 << bits) - 1;
    let mut w = 0;
    while w < words {
        out.write(at + w, 0);
        w += 1;
    }
    let mut s = 0;
    while s < k as usize {
        let v = if list[s] == NO_SITE { mask } else { list[s] & mask };
        let bit = s * bits as usize;
        let w = at + bit / 32;
        let shift = (bit % 32) as u32;
        out.write(w, out.read(w) | (v << shift));
        if shift + bits > 32 {
            out.write(w + 1, out.read(w + 1) | (v >> (32 - shift)));
        }
        s += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::vec;
    use std::vec::Vec;

    #[test]
    fn widths_leave_all_ones_free() {
        assert_eq!(width(0), 1);
        assert_eq!(width(1), 1);
        assert_eq!(width(2), 2);
        for n in [3u32, 4, 5, 1000, (1 << 20) - 1, 1 << 20, 1_000_000, 10_000_000, u32::MAX - 1] {
            let b = width(n);
            let mask = if b == 32 { u32::MAX } else { (1 << b) - 1 };
            // Every index below n is below the mask; one bit fewer would not do.
            assert!(n - 1 < mask, "{n}: {b} bits");
            assert!(b == 1 || n > (1u32 << (b - 1)) - 1, "{n}: {b} bits is more than needed");
        }
    }

    #[test]
    fn packed_lists_read_back_as_written() {
        let mut seed = 12345u64;
        let mut next = || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (seed >> 33) as u32
        };
        for (n, k) in [(1u32, 1u32), (2, 1), (5, 4), (1000, 48), (1_000_000, 48), (3_000_001, 45), (70_000, 90)] {
            for bits in [width(n), 32] {
                let lists: Vec<Vec<u32>> = (0..7)
                    .map(|_| (0..k).map(|_| if next() % 9 == 0 { NO_SITE } else { next() % n }).collect())
                    .collect();
                let mut words = vec![u32::MAX; 7 * stride(k, bits) + spare(bits)];
                // Written in any order: each list owns its words.
                for &l in &[3usize, 0, 6, 1, 5, 2, 4] {
                    pack(&lists[l], k, bits, l, &mut words[..]);
                }
                let view = Lists::new(&words, k, bits, 10, 17);
                for (l, list) in lists.iter().enumerate() {
                    let slot = view.slot(10 + l);
                    assert_eq!(slot, l);
                    for (s, &want) in list.iter().enumerate() {
                        assert_eq!(view.get(slot, s), want, "n {n} k {k} bits {bits} list {l} entry {s}");
                    }
                }
                assert_eq!(view.slot(9), NO_LIST);
                assert_eq!(view.slot(17), NO_LIST);
                let short = &words[..words.len() - 1];
                assert_eq!(Lists::new(short, k, bits, 10, 17).slot(10), NO_LIST, "too few words: none held");
            }
        }
    }
}
