//! `summary.json` and the terminal table: what was computed, where, how
//! fast, and how well (`E_vol`, counters).

use crate::read::write_file;
use cvd::backend::Backend;
use cvd::cvt::Iteration;
use cvd::diagram::voronoi::{Cells, Counters};
use cvd::error::Result;
use cvd::geom::mesh::TetMesh;
use cvd::geom::timing::Timings;
use std::fmt;
use std::path::Path;

/// A run in numbers; serialised as `summary.json`, shown as a table by
/// `Display`.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Summary {
    /// The model's name or mesh file.
    pub model: String,
    /// Tets in the mesh.
    pub tets: usize,
    /// Input sites (duplicates included).
    pub sites: usize,
    /// `cpu` or `vulkan`.
    pub backend: String,
    /// The GPU's name, or the CPU and its threads.
    pub device: String,
    /// `tet-cell` or `cell-tet`.
    pub strategy: String,
    /// `flood` or `knn`.
    pub pairing: String,
    /// Sites paired with each tet (1 for flood pairing: its first site).
    pub k: usize,
    /// Neighbours per site.
    pub k_site: usize,
    /// The mesh's volume.
    pub mesh_volume: f64,
    /// The sum of the cells' volumes.
    pub volume_sum: f64,
    /// `|volume_sum - mesh_volume| / mesh_volume`.
    pub e_vol: f64,
    /// The CVT energy `Σ_i ∫ |x - x_i|²`.
    pub energy: f64,
    /// Times, in seconds.
    pub times: Times,
    /// What the kernels and the second pass counted.
    pub counters: Counters,
    /// Pieces merged into the cells' polyhedra (absent when they were not).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pieces: Option<usize>,
    /// Lids the polyhedra needed: holes where a corner of a cell poked into
    /// a tet by a sliver the flood did not reach (see
    /// [`cvd::passes::polyhedra::CellPolyhedron::repaired_holes`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lids: Option<u64>,
    /// The optimiser's record, when CVT iterations moved the sites before
    /// this diagram (absent otherwise).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cvt: Option<CvtRecord>,
    /// The optimal transport that found this diagram's weights (absent
    /// otherwise).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub transport: Option<TransportRecord>,
    /// The periodic box, when the cells are those of one (absent
    /// otherwise).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub periodic: Option<PeriodicRecord>,
    /// A run in parts ([`cvd::backends::distributed`]): rank 0's rounds and every
    /// rank's totals (absent otherwise).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub parts: Option<cvd::backends::distributed::PartReport>,
    /// The particles' quantities (`--voronoi-index`; absent otherwise).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub particles: Option<ParticlesRecord>,
    /// The most memory this process held up to the summary (`VmHWM`;
    /// rank 0's in a run in parts, every rank's in `ranks`; 0 where
    /// unknown).
    pub peak_memory_bytes: u64,
    /// A periodic box in parts over MPI: what each rank held and did
    /// (absent otherwise).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ranks: Option<Vec<RankRecord>>,
}

/// A rank's tets: none held (a periodic box in parts).
fn no_tets(tets: &[u64; 2]) -> bool {
    tets[1] == 0
}

fn is_zero(n: &u64) -> bool {
    *n == 0
}

/// One rank of a periodic box in parts.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct RankRecord {
    /// The rank.
    pub rank: usize,
    /// The input rows it read (and wrote).
    pub rows: u64,
    /// The blocks of the box it took.
    pub blocks: u64,
    /// The sites whose cells it built.
    pub owned: u64,
    /// The points it held for them (its sites and its halo's).
    pub held: u64,
    /// The halo's width.
    pub halo: f64,
    /// Rounds in which a part of it held more sites for the cells whose
    /// list or walk reached past what it held, over its parts.
    pub widened: u64,
    /// A mesh in parts: the cells it built again in those rounds (on the
    /// CPU the cells that reached past only; a device builds its part's
    /// every cell again; 0, not written, when none).
    #[serde(skip_serializing_if = "is_zero")]
    pub rebuilt: u64,
    /// The cells of the site grid's table it held (the window of the whole
    /// job's grid around its points), and the whole grid's.
    pub grid_cells: [u64; 2],
    /// A mesh in parts: the most tets a part of it held (those its cells
    /// may meet), and the mesh's (0 in a periodic box).
    #[serde(skip_serializing_if = "no_tets")]
    pub tets: [u64; 2],
    /// A mesh in parts: the parts it computed its sites in, one after
    /// another (0, not written, in a periodic box).
    #[serde(skip_serializing_if = "is_zero")]
    pub parts: u64,
    /// Bytes it sent to other ranks.
    pub sent_bytes: u64,
    /// Seconds from reading its rows to its rows written.
    pub seconds: f64,
    /// The most memory the process held (`VmHWM`; 0 where unknown).
    pub peak_memory_bytes: u64,
}

/// The particles' quantities over all cells: the thresholds, the mean
/// coordination and the most common Voronoi indices.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct ParticlesRecord {
    /// The thresholds the index was counted with: `edge`,
    /// `relative_edge`, `face`, `relative_face`.
    pub thresholds: [f64; 4],
    /// The mean coordination over non-empty cells.
    pub mean_coordination: f64,
    /// The ten most common indices, `<n3,n4,n5,n6,...>` (trailing zeros
    /// beyond n6 left out), with how many cells have each, most common
    /// first (ties by index).
    pub top_indices: Vec<(String, usize)>,
}

/// What a [`ParticlesRecord`] is made of: the cells with a face counted,
/// by Voronoi index, and their coordination's sum — whole numbers, added
/// over the ranks of a run in parts ([`Self::add`]) to one process's.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct IndexCounts {
    /// Cells by index.
    pub by_index: std::collections::HashMap<[u32; cvd::INDEX_ORDERS], u64>,
    /// The cells counted.
    pub cells: u64,
    /// Their coordination, summed.
    pub coordination: u64,
}

impl IndexCounts {
    /// The counts of `particles`' cells with a counted face.
    pub fn of(particles: &cvd::ParticleCells) -> Self {
        let mut out = Self::default();
        for (i, index) in particles.index.iter().enumerate() {
            if particles.coordination[i] > 0 {
                *out.by_index.entry(*index).or_default() += 1;
                out.cells += 1;
                out.coordination += particles.coordination[i] as u64;
            }
        }
        out
    }

    /// Adds `other`'s counts.
    pub fn add(&mut self, other: &Self) {
        for (index, n) in &other.by_index {
            *self.by_index.entry(*index).or_default() += n;
        }
        self.cells += other.cells;
        self.coordination += other.coordination;
    }

    /// As bytes (`from_bytes` reads them back).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut words = vec![self.cells, self.coordination];
        for (index, &n) in &self.by_index {
            words.extend(index.iter().map(|&k| k as u64));
            words.push(n);
        }
        words.iter().flat_map(|w| w.to_le_bytes()).collect()
    }

    /// The counts `to_bytes` wrote, or `None` for bytes it did not write.
    pub fn from_bytes(bytes: &[u8]) -> Option<Self> {
        let (words, rest) = bytes.as_chunks::<8>();
        let words: Vec<u64> = words.iter().map(|w| u64::from_le_bytes(*w)).collect();
        if !rest.is_empty() || words.len() < 2 || !(words.len() - 2).is_multiple_of(cvd::INDEX_ORDERS + 1) {
            return None;
        }
        let mut out = Self { cells: words[0], coordination: words[1], ..Default::default() };
        for entry in words[2..].chunks(cvd::INDEX_ORDERS + 1) {
            let index = std::array::from_fn(|k| entry[k] as u32);
            *out.by_index.entry(index).or_default() += entry[cvd::INDEX_ORDERS];
        }
        Some(out)
    }
}

impl ParticlesRecord {
    /// The record of `particles` counted with `thresholds`.
    pub fn of(particles: &cvd::ParticleCells, thresholds: &cvd::IndexThresholds) -> Self {
        Self::of_counts(&IndexCounts::of(particles), thresholds)
    }

    /// The record of the cells `counts` counted with `thresholds`.
    pub fn of_counts(counts: &IndexCounts, thresholds: &cvd::IndexThresholds) -> Self {
        let (cells, total) = (counts.cells, counts.coordination);
        let mut top: Vec<([u32; cvd::INDEX_ORDERS], usize)> =
            counts.by_index.iter().map(|(i, &n)| (*i, n as usize)).collect();
        top.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        let name = |index: &[u32; cvd::INDEX_ORDERS]| {
            let last = index.iter().rposition(|&n| n > 0).unwrap_or(0).max(3);
            let parts: Vec<String> = index[..=last].iter().map(u32::to_string).collect();
            format!("<{}>", parts.join(","))
        };
        Self {
            thresholds: [thresholds.edge, thresholds.relative_edge, thresholds.face, thresholds.relative_face],
            mean_coordination: total as f64 / cells.max(1) as f64,
            top_indices: top.iter().take(10).map(|(i, c)| (name(i), *c)).collect(),
        }
    }
}

/// A periodic box and the images its diagram took.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct PeriodicRecord {
    /// The box's lower corner (a triclinic cell's origin).
    pub lo: [f64; 3],
    /// The box's upper corner (a triclinic cell's corner `lo + a + b + c`).
    pub hi: [f64; 3],
    /// The cell's edge vectors a, b, c.
    pub vectors: [[f64; 3]; 3],
    /// Whether it repeats along each (else: walls).
    pub periodic: [bool; 3],
    /// Mirrors of sites in the walls among the images.
    pub mirrors: usize,
    /// Sites on a wall, moved 1e-9 of the cell's height inside.
    pub on_walls: usize,
    /// Sites given outside the box, wrapped into it.
    pub wrapped: usize,
    /// Images of sites that joined them (the final diagram's).
    pub images: usize,
    /// The halo the images were taken within.
    pub halo: f64,
}

impl PeriodicRecord {
    /// The record of `cells`, computed in `domain`.
    pub fn of(domain: &cvd::PeriodicBox, cells: &cvd::PeriodicCells) -> Self {
        Self {
            lo: domain.lo(),
            hi: domain.hi(),
            vectors: domain.vectors(),
            periodic: domain.periodic(),
            mirrors: cells.mirrors,
            on_walls: cells.on_walls,
            wrapped: cells.wrapped,
            images: cells.images,
            halo: cells.halo,
        }
    }
}

/// What an optimal-transport solve did, Newton step by Newton step.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct TransportRecord {
    /// `uniform` (every cell the same mass) or `capacities` (from a file).
    pub targets: String,
    /// The largest relative mass error asked for.
    pub tolerance: f64,
    /// Whether every cell's mass came within it.
    pub converged: bool,
    /// The final `max_i |m_i - t_i| / t_i`.
    pub max_error: f64,
    /// Newton steps taken.
    pub steps: usize,
    /// Diagrams computed (each step's trials, and the first).
    pub diagrams: u32,
    /// Seconds of the whole solve.
    pub total_s: f64,
    /// Per diagram the steps started from (the last: the final one): the
    /// largest relative mass error.
    pub step_max_error: Vec<f64>,
    /// Per step: the damping `α` taken (1: a full Newton step).
    pub step_length: Vec<f64>,
    /// Per step: conjugate-gradient iterations of its linear solve.
    pub cg_iterations: Vec<u32>,
    /// Per step: seconds (its diagrams and its solve).
    pub seconds: Vec<f64>,
}

impl TransportRecord {
    /// The record of `run`, solved to `tolerance` for `targets`.
    pub fn of(targets: &str, tolerance: f64, run: &cvd::cvt::transport::TransportRun) -> Self {
        let steps = &run.steps;
        let taken = &steps[..steps.len().saturating_sub(1)];
        Self {
            targets: targets.to_string(),
            tolerance,
            converged: run.converged,
            max_error: run.max_error(),
            steps: taken.len(),
            diagrams: steps.iter().map(|s| s.diagrams).sum(),
            total_s: steps.iter().map(|s| s.seconds).sum(),
            step_max_error: steps.iter().map(|s| s.max_error).collect(),
            step_length: taken.iter().map(|s| s.step).collect(),
            cg_iterations: taken.iter().map(|s| s.cg_iterations).collect(),
            seconds: taken.iter().map(|s| s.seconds).collect(),
        }
    }
}

/// What a CVT run did, iteration by iteration.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct CvtRecord {
    /// `lloyd` or `lbfgs`.
    pub optimizer: String,
    /// Iterations run (L-BFGS stops early at a minimum).
    pub iterations: usize,
    /// Seconds of all the iterations together.
    pub total_s: f64,
    /// `total_s / iterations`.
    pub per_iteration_s: f64,
    /// Per iteration: the CVT energy of the diagram it started from, as the
    /// progress bar shows it (so `energy[i]` is the energy after `i`
    /// iterations; after the last one it is the summary's `energy`).
    pub energy: Vec<f64>,
    /// Per iteration: sites whose cell was empty in that diagram.
    pub empty_cells: Vec<u64>,
    /// Per iteration: pieces the second pass finished.
    pub second_pass: Vec<u64>,
    /// Per iteration: pieces not even the second pass could finish.
    pub unresolved: Vec<u64>,
    /// Per iteration: seconds on the backend.
    pub seconds: Vec<f64>,
    /// Per iteration: Newton steps of its optimal transport (the
    /// capacity-constrained CVT; absent otherwise).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub newton_steps: Vec<u32>,
}

impl CvtRecord {
    /// The record of `iterations` run by `optimizer`.
    pub fn of(optimizer: &str, iterations: &[Iteration]) -> Self {
        let total_s: f64 = iterations.iter().map(|i| i.seconds).sum();
        Self {
            optimizer: optimizer.to_string(),
            iterations: iterations.len(),
            total_s,
            per_iteration_s: total_s / iterations.len().max(1) as f64,
            energy: iterations.iter().map(|i| i.energy).collect(),
            empty_cells: iterations.iter().map(|i| i.empty_cells).collect(),
            second_pass: iterations.iter().map(|i| i.second_pass).collect(),
            unresolved: iterations.iter().map(|i| i.unresolved).collect(),
            seconds: iterations.iter().map(|i| i.seconds).collect(),
            newton_steps: if iterations.iter().any(|i| i.newton_steps > 0) {
                iterations.iter().map(|i| i.newton_steps).collect()
            } else {
                Vec::new()
            },
        }
    }
}

/// Times of a run, in seconds.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct Times {
    /// Neighbour search: site grid and k-NN of the sites and tets.
    pub knn_s: f64,
    /// Clipping: cells (cell-tet), pieces, second and host passes.
    pub clip_s: f64,
    /// Every phase, transfers included.
    pub total_s: f64,
    /// The driver's compilation of the kernels on their first use in this
    /// process (Vulkan; 0 on the CPU). Not part of `total_s`.
    pub kernel_compile_s: f64,
    /// Each phase as the backend names it, in order (a JSON object).
    #[serde(serialize_with = "in_order")]
    pub phases: Vec<(String, f64)>,
}

/// `(name, value)` pairs as a JSON object that keeps their order.
fn in_order<S: serde::Serializer>(pairs: &[(String, f64)], s: S) -> std::result::Result<S::Ok, S::Error> {
    s.collect_map(pairs.iter().map(|(k, v)| (k, v)))
}

impl Times {
    /// Sorts a backend's phases into k-NN, clipping and total.
    pub fn of(t: &Timings) -> Self {
        Self { knn_s: t.knn(), clip_s: t.clip(), total_s: t.total(), kernel_compile_s: 0.0, phases: t.phases.clone() }
    }
}

impl Summary {
    /// The summary of `cells`, computed for `model` with `n_sites` sites on
    /// `backend`.
    pub fn new(
        model: &str,
        mesh: &TetMesh,
        n_sites: usize,
        strategy: cvd::Strategy,
        backend: &dyn Backend,
        cells: &Cells,
    ) -> Self {
        Self {
            model: model.to_string(),
            tets: mesh.tets.len(),
            sites: n_sites,
            backend: backend.kind().to_string(),
            device: backend.device(),
            strategy: strategy.name().to_string(),
            pairing: cells.pairing.name().to_string(),
            k: cells.k,
            k_site: cells.k_site,
            mesh_volume: cells.mesh_volume,
            volume_sum: cells.total_volume,
            e_vol: cells.e_vol,
            energy: cells.energy_total(),
            times: Times { kernel_compile_s: backend.kernel_compile_seconds(), ..Times::of(&cells.timings) },
            counters: cells.counters,
            pieces: None,
            lids: None,
            cvt: None,
            transport: None,
            periodic: None,
            parts: None,
            particles: None,
            peak_memory_bytes: cvd::job::memory::peak().unwrap_or(0),
            ranks: None,
        }
    }

    /// Writes the summary as pretty-printed JSON.
    pub fn write_json(&self, path: &Path) -> Result<()> {
        write_file(path, |w| {
            serde_json::to_writer_pretty(&mut *w, self).map_err(std::io::Error::other)?;
            writeln!(w)
        })
    }
}

fn ms(s: f64) -> String {
    format!("{:.1} ms", s * 1e3)
}

impl fmt::Display for Summary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let c = &self.counters;
        let phases: Vec<String> = self.times.phases.iter().map(|(p, s)| format!("{p} {}", ms(*s))).collect();
        let rows = [
            ("model", format!("{} ({} tets, volume {:.6})", self.model, self.tets, self.mesh_volume)),
            ("sites", format!("{} ({} duplicates)", self.sites, c.duplicate_sites)),
            ("backend", format!("{} on {}", self.backend, self.device)),
            (
                "strategy",
                if self.strategy == "whole" {
                    format!(
                        "whole: {} cells whole, {} the boundary may cut (clipped by their tets), k_site = {}",
                        c.whole_cells, c.cut_cells, self.k_site
                    )
                } else {
                    format!("{}, {} pairing, k = {}, k_site = {}", self.strategy, self.pairing, self.k, self.k_site)
                },
            ),
            (
                "time",
                format!(
                    "k-NN {}, clip {}, total {} ({})",
                    ms(self.times.knn_s),
                    ms(self.times.clip_s),
                    ms(self.times.total_s),
                    phases.join(", ")
                ),
            ),
            ("E_vol", format!("{:.2e} (volume {:.6} of {:.6})", self.e_vol, self.volume_sum, self.mesh_volume)),
            ("energy", format!("{:.6e}", self.energy)),
            (
                "pairs",
                format!(
                    "{} tried, {} non-empty, {} dropped before clipping; {} clips; {} pieces beyond their list, walked",
                    c.pairs, c.nonempty, c.filtered, c.clips, c.walks
                ),
            ),
            (
                "unfinished",
                format!(
                    "security radius {}, overflows {}, broken {}; second pass finished {}, unresolved {}",
                    c.security_missed, c.overflows, c.broken, c.second_pass, c.unresolved
                ),
            ),
            (
                "empty",
                format!(
                    "{} cells besides duplicates; knn pairing: {} tets missing a site's pieces, completed",
                    c.empty_cells, c.missed_tets
                ),
            ),
        ];
        let mut rows = rows.to_vec();
        if c.faces_redone > 0 {
            rows.push((
                "faces",
                format!("{} sites' faces redone on the CPU (beyond their spill slots)", c.faces_redone),
            ));
        }
        for (key, value) in rows {
            writeln!(f, "  {key:<11}{value}")?;
        }
        if let Some(n) = self.pieces {
            writeln!(f, "  {:<11}{n}", "pieces")?;
        }
        if let Some(n) = self.lids.filter(|&n| n > 0) {
            writeln!(f, "  {:<11}{n} holes in the cells' polyhedra closed by lids", "lids")?;
        }
        if let Some(r) = &self.cvt {
            let empty = r.empty_cells.iter().max().copied().unwrap_or(0);
            writeln!(
                f,
                "  {:<11}{} iterations in {:.3} s ({} each), energy {:.6e} -> {:.6e}, up to {empty} empty cells",
                r.optimizer,
                r.iterations,
                r.total_s,
                ms(r.per_iteration_s),
                r.energy.first().copied().unwrap_or(self.energy),
                self.energy,
            )?;
        }
        if let Some(p) = &self.parts {
            let held: u64 = p.all.iter().map(|r| r.held_sites).sum();
            let again: u64 = p.all.iter().map(|r| r.tets_again).sum();
            let rounds = p.all.iter().map(|r| r.rounds).max().unwrap_or(0);
            let slowest = p.all.iter().map(|r| r.micros).max().unwrap_or(0) as f64 * 1e-3;
            writeln!(
                f,
                "  {:<11}{} parts on {} rank(s): {:.3} sites held per site (halos), {} tets done again, {} rounds, slowest rank {:.1} ms, all-reduce {:.1} ms",
                "parts",
                p.of,
                p.ranks,
                held as f64 / self.sites.max(1) as f64,
                again,
                rounds,
                slowest,
                p.reduce_seconds * 1e3
            )?;
        }
        if let Some(p) = &self.periodic {
            let walls = if p.periodic.contains(&false) {
                format!(
                    ", walls across {} ({} mirrors, {} sites on them moved inside)",
                    (0..3).filter(|&a| !p.periodic[a]).map(|a| ["a", "b", "c"][a]).collect::<Vec<_>>().join(" "),
                    p.mirrors,
                    p.on_walls
                )
            } else {
                String::new()
            };
            writeln!(
                f,
                "  {:<11}box {:?} to {:?}: {} images within {:.4} of it, {} sites wrapped into it{walls}",
                "periodic", p.lo, p.hi, p.images, p.halo, p.wrapped
            )?;
        }
        if let Some(p) = &self.particles {
            let top: Vec<String> = p.top_indices.iter().take(3).map(|(i, c)| format!("{i} x{c}")).collect();
            writeln!(
                f,
                "  {:<11}mean coordination {:.3}; most common Voronoi indices {}",
                "particles",
                p.mean_coordination,
                top.join(", ")
            )?;
        }
        if let Some(t) = &self.transport {
            writeln!(
                f,
                "  {:<11}{} targets: max mass error {:.2e} ({}converged to {:.0e}) in {} Newton steps, {} diagrams, {:.3} s",
                "transport",
                t.targets,
                t.max_error,
                if t.converged { "" } else { "NOT " },
                t.tolerance,
                t.steps,
                t.diagrams,
                t.total_s
            )?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn index_counts_added_over_parts_are_the_whole_counts() {
        let index = |k: u32| [0, 12 - 2 * k, 4 * k, 0, 0, 0, 0, 0];
        let n = 50;
        let particles = cvd::ParticleCells {
            area: vec![1.0; n],
            coordination: (0..n).map(|i| if i % 7 == 0 { 0 } else { 12 + (i % 3) as u32 }).collect(),
            index: (0..n).map(|i| index((i % 3) as u32)).collect(),
            max_face_order: vec![5; n],
        };
        let whole = IndexCounts::of(&particles);
        let mut added = IndexCounts::default();
        for rows in [0..13, 13..13, 13..50] {
            let bytes = IndexCounts::of(&particles.rows(rows)).to_bytes();
            added.add(&IndexCounts::from_bytes(&bytes).unwrap());
        }
        assert_eq!(added, whole);
        let t = cvd::IndexThresholds::default();
        assert_eq!(ParticlesRecord::of_counts(&added, &t), ParticlesRecord::of(&particles, &t));
        assert!(IndexCounts::from_bytes(&[0; 12]).is_none() && IndexCounts::from_bytes(&[0; 24]).is_none());
    }
    use cvd::cvt::transport::{NewtonStep, TransportRun};

    fn summary() -> Summary {
        let cpu = cvd::CpuBackend::new(Some(1)).unwrap();
        let cells = Cells {
            volume: vec![0.25, 0.75],
            energy: vec![1.0 / 3.0, 0.125],
            total_volume: 1.0,
            mesh_volume: 1.0 + 1e-9,
            e_vol: 1e-9 / (1.0 + 1e-9),
            k: 1,
            k_site: 48,
            timings: Timings { phases: vec![("knn".into(), 0.5), ("clip".into(), 0.25), ("faces".into(), 0.125)] },
            ..Default::default()
        };
        Summary::new("cube", &TetMesh::cube(1), 2, cvd::Strategy::CellTet, &cpu, &cells)
    }

    fn json(s: &Summary, name: &str) -> (String, serde_json::Value) {
        let path = std::env::temp_dir().join(format!("cvd-io-write-{}-{name}", std::process::id()));
        s.write_json(&path).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        std::fs::remove_file(&path).unwrap();
        let value = serde_json::from_str(&text).unwrap();
        (text, value)
    }

    const OPTIONAL: [&str; 7] = ["pieces", "lids", "cvt", "transport", "periodic", "parts", "particles"];

    #[test]
    fn the_fields_readers_use_are_there_and_exact() {
        let (text, j) = json(&summary(), "summary.json");
        assert!(text.ends_with("}\n"));
        assert_eq!((j["model"].as_str(), j["tets"].as_u64(), j["sites"].as_u64()), (Some("cube"), Some(6), Some(2)));
        assert_eq!((j["backend"].as_str(), j["device"].as_str()), (Some("cpu"), Some("1 threads")));
        assert_eq!((j["strategy"].as_str(), j["pairing"].as_str()), (Some("cell-tet"), Some("flood")));
        assert_eq!((j["k"].as_u64(), j["k_site"].as_u64()), (Some(1), Some(48)));
        // Floats read back bit for bit.
        assert_eq!(j["energy"].as_f64().map(f64::to_bits), Some((1.0f64 / 3.0 + 0.125).to_bits()));
        assert_eq!(j["mesh_volume"].as_f64(), Some(1.0 + 1e-9));
        assert_eq!(j["volume_sum"].as_f64(), Some(1.0));
        assert_eq!(j["e_vol"].as_f64(), Some(1e-9 / (1.0 + 1e-9)));
        let counters = j["counters"].as_object().unwrap();
        for key in ["pairs", "second_pass", "unresolved", "duplicate_sites", "empty_cells", "faces_redone"] {
            assert_eq!(counters[key].as_u64(), Some(0), "counters.{key}");
        }
        let t = &j["times"];
        assert_eq!(
            (t["knn_s"].as_f64(), t["clip_s"].as_f64(), t["total_s"].as_f64()),
            (Some(0.5), Some(0.25), Some(0.875))
        );
        assert_eq!(t["kernel_compile_s"].as_f64(), Some(0.0));
        // The phases: an object, in the backend's order.
        assert_eq!(t["phases"]["faces"].as_f64(), Some(0.125), "a phase neither k-NN nor clipping");
        let (knn, clip, faces) =
            (text.find("\"knn\"").unwrap(), text.find("\"clip\"").unwrap(), text.find("\"faces\"").unwrap());
        assert!(knn < clip && clip < faces, "phases out of order:\n{text}");
        for key in OPTIONAL {
            assert!(j.get(key).is_none(), "{key} written though not set: {text}");
        }
    }

    #[test]
    fn records_appear_once_set() {
        let mut s = summary();
        s.pieces = Some(12);
        s.lids = Some(0);
        let iterations = [
            Iteration { energy: 3.0, seconds: 0.5, empty_cells: 1, second_pass: 2, unresolved: 0, newton_steps: 0 },
            Iteration { energy: 2.0, seconds: 1.5, empty_cells: 0, second_pass: 1, unresolved: 4, newton_steps: 0 },
        ];
        s.cvt = Some(CvtRecord::of("lbfgs", &iterations));
        s.periodic = Some(PeriodicRecord {
            lo: [0.0; 3],
            hi: [1.0, 2.0, 3.0],
            wrapped: 4,
            images: 50,
            halo: 0.5,
            ..Default::default()
        });
        s.parts = Some(Default::default());
        let particles = cvd::ParticleCells {
            area: vec![1.0; 3],
            coordination: vec![12, 12, 0],
            index: vec![[0, 12, 0, 0, 0, 0, 0, 0], [0, 12, 0, 0, 0, 0, 0, 0], [0; cvd::INDEX_ORDERS]],
            max_face_order: vec![4, 4, 0],
        };
        s.particles = Some(ParticlesRecord::of(&particles, &cvd::IndexThresholds::default()));
        let run = TransportRun {
            steps: vec![
                NewtonStep { max_error: 0.5, step: 1.0, diagrams: 2, cg_iterations: 7, seconds: 0.25 },
                NewtonStep { max_error: 0.25, step: 0.5, diagrams: 3, cg_iterations: 9, seconds: 0.5 },
                NewtonStep { max_error: 1e-7, step: 0.0, diagrams: 0, cg_iterations: 0, seconds: 0.0 },
            ],
            converged: true,
            ..Default::default()
        };
        s.transport = Some(TransportRecord::of("uniform", 1e-6, &run));
        let (text, j) = json(&s, "summary-records.json");
        for key in OPTIONAL {
            assert!(j.get(key).is_some(), "{key} missing: {text}");
        }
        assert_eq!((j["pieces"].as_u64(), j["lids"].as_u64()), (Some(12), Some(0)));
        let c = &j["cvt"];
        assert_eq!((c["optimizer"].as_str(), c["iterations"].as_u64()), (Some("lbfgs"), Some(2)));
        assert_eq!((c["total_s"].as_f64(), c["per_iteration_s"].as_f64()), (Some(2.0), Some(1.0)));
        assert_eq!(c["energy"], serde_json::json!([3.0, 2.0]));
        assert_eq!(c["empty_cells"], serde_json::json!([1, 0]));
        assert_eq!(c["second_pass"], serde_json::json!([2, 1]));
        assert_eq!(c["unresolved"], serde_json::json!([0, 4]));
        assert_eq!(c["seconds"], serde_json::json!([0.5, 1.5]));
        assert!(c.get("newton_steps").is_none(), "no transport inside: no newton_steps");
        let p = &j["periodic"];
        assert_eq!((p["wrapped"].as_u64(), p["images"].as_u64(), p["halo"].as_f64()), (Some(4), Some(50), Some(0.5)));
        assert_eq!(p["hi"], serde_json::json!([1.0, 2.0, 3.0]));
        assert_eq!(j["particles"]["top_indices"], serde_json::json!([["<0,12,0,0>", 2]]), "empty cells not counted");
        assert_eq!(j["particles"]["mean_coordination"].as_f64(), Some(12.0));
        let t = &j["transport"];
        assert_eq!(
            (t["targets"].as_str(), t["converged"].as_bool(), t["tolerance"].as_f64()),
            (Some("uniform"), Some(true), Some(1e-6))
        );
        assert_eq!(
            (t["steps"].as_u64(), t["diagrams"].as_u64(), t["max_error"].as_f64()),
            (Some(2), Some(5), Some(1e-7))
        );
        assert_eq!(t["step_max_error"], serde_json::json!([0.5, 0.25, 1e-7]), "one more than the steps: the final");
        assert_eq!(t["step_length"], serde_json::json!([1.0, 0.5]));
        assert_eq!(t["cg_iterations"], serde_json::json!([7, 9]));
        assert_eq!((t["seconds"].clone(), t["total_s"].as_f64()), (serde_json::json!([0.25, 0.5]), Some(0.75)));
    }

    #[test]
    fn cvt_records_without_iterations_or_with_transport() {
        let none = CvtRecord::of("lloyd", &[]);
        assert_eq!((none.iterations, none.total_s, none.per_iteration_s), (0, 0.0, 0.0), "no NaN in the JSON");
        let it = Iteration { energy: 1.0, newton_steps: 3, ..Default::default() };
        let with = CvtRecord::of("lloyd-transport", &[it, Iteration { newton_steps: 0, ..it }]);
        assert_eq!(with.newton_steps, vec![3, 0], "every iteration's, once any has some");
    }

    #[test]
    fn the_table_shows_optional_rows_only_when_they_say_something() {
        let mut s = summary();
        let table = s.to_string();
        for absent in ["faces", "lids", "pieces", "transport", "periodic"] {
            assert!(!table.contains(&format!("  {absent}")), "{absent}:\n{table}");
        }
        s.lids = Some(0);
        assert!(!s.to_string().contains("lids"), "no lids row for zero lids");
        s.lids = Some(2);
        s.counters.faces_redone = 5;
        let run = TransportRun {
            steps: vec![NewtonStep { max_error: 0.5, ..Default::default() }],
            converged: false,
            ..Default::default()
        };
        s.transport = Some(TransportRecord::of("capacities", 1e-6, &run));
        let table = s.to_string();
        assert!(table.contains("2 holes in the cells' polyhedra closed by lids"), "{table}");
        assert!(table.contains("5 sites' faces redone"), "{table}");
        assert!(table.contains("NOT converged"), "{table}");
    }
}
