//! What the optimisers take over all sites when each process holds only
//! its own rows of them (a diagram in parts, [`SiteDiagram::comm`]): sums
//! and dot products (exact, [`ExactSum`], so the same bits in any split),
//! extremes, and the values at a row's neighbours held by other processes
//! ([`Ghosts`]). In one process each is the plain local operation, on the
//! same code path: a run in parts takes one process's steps to the bit.

use super::SiteDiagram;
use crate::backends::distributed::{Parcels, Reduce};
use crate::error::{Error, Result};
use crate::geom::exact_sum::ExactSum;
use rayon::prelude::*;

/// Terms per piece of a parallel exact sum.
const PIECE: usize = 1 << 12;

/// The rows of the sites this process holds, among all processes' rows.
#[derive(Clone, Copy)]
pub(crate) struct Across<'a> {
    comm: Option<&'a dyn Reduce>,
    /// This process's first row.
    pub first: u64,
    /// Its rows.
    pub len: usize,
    /// Rows in all.
    pub total: u64,
}

impl<'a> Across<'a> {
    /// The rows of `diagram`'s sites: `len` here (each process calls this
    /// together, in parts).
    pub fn of(diagram: &'a (impl SiteDiagram + ?Sized), len: usize) -> Result<Self> {
        let Some(comm) = diagram.comm() else { return Ok(Self::alone(len)) };
        let counts = comm.gather_u64(len as u64)?;
        let first = counts[..comm.rank()].iter().sum();
        Ok(Self { comm: Some(comm), first, len, total: counts.iter().sum() })
    }

    /// All `len` rows in this one process.
    pub fn alone(len: usize) -> Self {
        Self { comm: None, first: 0, len, total: len as u64 }
    }

    /// Whether the rows are split between processes.
    pub fn in_parts(&self) -> bool {
        self.comm.is_some()
    }

    /// Each of `sums` over every process, in place.
    pub fn totals(&self, sums: &mut [ExactSum]) -> Result<()> {
        let Some(comm) = self.comm else { return Ok(()) };
        for s in sums {
            *s = comm.exact_total(s)?;
        }
        Ok(())
    }

    /// `Σ terms` over every process's rows, exactly rounded.
    pub fn sum(&self, terms: &[f64]) -> Result<f64> {
        let mut s = [exact(terms.len(), |i| terms[i])];
        self.totals(&mut s)?;
        Ok(s[0].value())
    }

    /// `Σ a_i b_i` over every process's rows (each product rounded, the sum
    /// exactly).
    pub fn dot(&self, a: &[f64], b: &[f64]) -> Result<f64> {
        let mut s = [exact(a.len().min(b.len()), |i| a[i] * b[i])];
        self.totals(&mut s)?;
        Ok(s[0].value())
    }

    /// The largest of every process's `x`.
    pub fn max(&self, x: f64) -> Result<f64> {
        let Some(comm) = self.comm else { return Ok(x) };
        let mut v = [x];
        comm.max(&mut v)?;
        Ok(v[0])
    }

    /// The smallest of every process's `x`.
    pub fn min(&self, x: f64) -> Result<f64> {
        Ok(-self.max(-x)?)
    }

    /// Whether any process's `b` holds.
    pub fn any(&self, b: bool) -> Result<bool> {
        Ok(self.max(b as u8 as f64)? > 0.0)
    }
}

/// The exact sum of `term(i)` for `i < n`, in pieces on every core (the
/// same bits as one by one).
fn exact(n: usize, term: impl Fn(usize) -> f64 + Sync) -> ExactSum {
    (0..n.div_ceil(PIECE))
        .into_par_iter()
        .map(|k| {
            let mut s = ExactSum::new();
            s.extend((k * PIECE..((k + 1) * PIECE).min(n)).map(&term));
            s
        })
        .reduce(ExactSum::new, |mut a, b| {
            a.merge(&b);
            a
        })
}

/// The rows other processes hold that this one's rows refer to (their
/// neighbours), and how to fetch values at them: [`Ghosts::of`] numbers
/// each referred row locally — this process's own rows first, `0..len`,
/// then each other row once — and [`Ghosts::fill`] sends every process
/// the values it asked for.
pub(crate) struct Ghosts<'a> {
    across: Across<'a>,
    /// For each process, this one's rows it asked for (local indices), in
    /// the order it numbered them.
    asked: Vec<Vec<u32>>,
    /// Rows from other processes: after the own rows.
    pub count: usize,
}

impl<'a> Ghosts<'a> {
    /// Renumbers `rows` (rows of all processes, by their global index) to
    /// local slots: an own row `r` to `r - first`, another process's to
    /// `len + k`, `k` counting such rows once each, by the process that
    /// holds them, then in the order first referred to.
    pub fn of(across: Across<'a>, rows: &mut [u32]) -> Result<Self> {
        let Some(comm) = across.comm else {
            return Ok(Self { across, asked: Vec::new(), count: 0 });
        };
        let lens = comm.gather_u64(across.len as u64)?;
        let starts: Vec<u64> = std::iter::once(0)
            .chain(lens.iter().scan(0, |at, &n| {
                *at += n;
                Some(*at)
            }))
            .collect();
        let own = across.first..across.first + across.len as u64;
        let mut slot: std::collections::HashMap<u32, u32> = Default::default();
        let mut wanted: Vec<Vec<u32>> = vec![Vec::new(); comm.size()];
        for r in rows.iter_mut() {
            let row = *r as u64;
            if own.contains(&row) {
                *r = (row - across.first) as u32;
                continue;
            }
            let next = (across.len + slot.len()) as u32;
            *r = *slot.entry(*r).or_insert_with(|| {
                let owner = starts.partition_point(|&s| s <= row) - 1;
                wanted[owner.min(comm.size() - 1)].push(row as u32);
                next
            });
        }
        let count = slot.len();
        // The slots were given in order of first reference; the values come
        // back by owner, each owner's in the order asked: renumber to that.
        let mut order: Vec<u32> = Vec::with_capacity(count);
        for w in &wanted {
            order.extend(w.iter().map(|row| slot[row]));
        }
        let mut renumber = vec![0u32; count];
        for (k, &s) in order.iter().enumerate() {
            renumber[s as usize - across.len] = (across.len + k) as u32;
        }
        for r in rows.iter_mut() {
            if *r as usize >= across.len {
                *r = renumber[*r as usize - across.len];
            }
        }
        let to = Parcels::of(wanted.iter().map(|w| bytemuck::cast_slice(w).to_vec()).collect());
        let got = comm.exchange(to)?;
        let asked = (0..comm.size())
            .map(|q| {
                let bytes = got.get(q);
                let rows: Vec<u32> = bytes
                    .chunks(4)
                    .map(|b| bytemuck::pod_read_unaligned::<u32>(b).wrapping_sub(across.first as u32))
                    .collect();
                rows
            })
            .collect::<Vec<_>>();
        if asked.iter().flatten().any(|&r| r as usize >= across.len) {
            return Err(Error::Internal("a row asked of the process that does not hold it".into()));
        }
        Ok(Self { across, asked, count })
    }

    /// `values` (one per own row) extended by the values at the other
    /// processes' rows, in slot order: the same on one process (no
    /// other rows).
    pub fn fill(&self, values: &[f64], out: &mut Vec<f64>) -> Result<()> {
        out.clear();
        out.extend_from_slice(values);
        let Some(comm) = self.across.comm else { return Ok(()) };
        let to = Parcels::of(
            self.asked
                .iter()
                .map(|rows| rows.iter().flat_map(|&r| values[r as usize].to_le_bytes()).collect())
                .collect(),
        );
        let got = comm.exchange(to)?;
        out.extend(got.bytes.as_chunks::<8>().0.iter().map(|b| f64::from_le_bytes(*b)));
        if out.len() != values.len() + self.count {
            return Err(Error::Internal(format!(
                "{} values from other processes, {} asked",
                out.len() - values.len(),
                self.count
            )));
        }
        Ok(())
    }
}
