//! The sections of the suite: what each measures, on which inputs.

use super::report::{cpu_name, Axis, Chart, Report, Row};
use super::{Backends, Config, Model};
use cvd::backends::vulkan::VulkanBackend;
use cvd::error::{Error, Result};
use cvd::geom::timing::timed;
use cvd::{geom::points, Backend, Cells, ClippedVoronoi, Pairing, Strategy, TetMesh};
use std::str::FromStr;

/// A part of the suite.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Section {
    /// The paper's Table 1: every model, both strategies, both pairings.
    Table1,
    /// Fig. 7: time against the number of sites (1k to 31k), fixed mesh.
    Fig7,
    /// Fig. 8: time against the mesh's resolution (10k to 100k tets),
    /// 15k sites.
    Fig8,
    /// Fig. 12: time and accuracy against k (10 to 120), knn pairing.
    Fig12,
    /// Fig. 13: tet-cell against cell-tet over Lloyd iterations, 1k and
    /// 30k sites.
    Fig13,
    /// 100k, 1M and 10M sites in a mesh of about as many tets.
    Scale,
}

impl Section {
    /// Every section, in the order they run.
    pub const ALL: [Section; 6] =
        [Section::Table1, Section::Fig7, Section::Fig8, Section::Fig12, Section::Fig13, Section::Scale];

    /// Its name on the command line and in file names.
    pub fn name(self) -> &'static str {
        match self {
            Section::Table1 => "table1",
            Section::Fig7 => "fig7",
            Section::Fig8 => "fig8",
            Section::Fig12 => "fig12",
            Section::Fig13 => "fig13",
            Section::Scale => "scale",
        }
    }

    fn title(self) -> &'static str {
        match self {
            Section::Table1 => "Table 1: the models, both strategies and pairings",
            Section::Fig7 => "Fig. 7: time against the number of sites",
            Section::Fig8 => "Fig. 8: time against the mesh resolution, 15k sites",
            Section::Fig12 => "Fig. 12: time and accuracy against k (knn pairing), 15k sites",
            Section::Fig13 => "Fig. 13: tet-cell against cell-tet over Lloyd iterations (k = 50)",
            Section::Scale => "Scale: sites in a mesh of about as many tets (tet-cell, flood)",
        }
    }
}

impl FromStr for Section {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        Section::ALL.into_iter().find(|x| x.name() == s).ok_or_else(|| {
            let names: Vec<&str> = Section::ALL.iter().map(|x| x.name()).collect();
            Error::InvalidInput(format!("unknown section '{s}'; expected one of {}", names.join(", ")))
        })
    }
}

/// The three ways of the paper's Table 1.
const METHODS: [(Strategy, Pairing); 3] =
    [(Strategy::TetCell, Pairing::Flood), (Strategy::TetCell, Pairing::Knn), (Strategy::CellTet, Pairing::Knn)];

/// The ways measured on `backend`: whole cells (on the CPU backend, which
/// runs them), then the paper's three.
fn methods(backend: &dyn Backend) -> Vec<(Strategy, Pairing)> {
    let whole = (backend.kind() == cvd::BackendKind::Cpu).then_some((Strategy::Whole, Pairing::Flood));
    whole.into_iter().chain(METHODS).collect()
}

/// Sites uniform inside the mesh, the same for every backend and method.
const SEED: u64 = 2020;

/// Runs the sections of `config`, printing each row as it is measured, and
/// writes the report into `config.out`.
pub fn run(config: &Config) -> Result<Report> {
    std::fs::create_dir_all(&config.out)
        .map_err(|e| Error::Write { path: config.out.display().to_string(), source: e })?;
    let backends = Backends::open(config)?;
    let mut s = Suite {
        config,
        backends: &backends,
        report: Report {
            cpu: cpu_name(),
            threads: backends.cpu.threads(),
            vulkan_device: backends.vulkan.as_ref().map(|v| v.device().name.clone()),
            vulkan_compile_s: backends.compile_s,
            ..Default::default()
        },
    };
    if let Some(why) = &backends.no_vulkan {
        s.note(format!("Vulkan rows skipped: {why}"));
    }
    println!("CPU: {}, {} threads", s.report.cpu, s.report.threads);
    if let (Some(d), Some(c)) = (&s.report.vulkan_device, s.report.vulkan_compile_s) {
        println!("Vulkan device: {d} (kernel compilation on first use, paid once: {c:.2} s)");
    }
    for &section in &config.sections {
        println!("\n== {}", section.title());
        match section {
            Section::Table1 => s.table1()?,
            Section::Fig7 => s.fig7()?,
            Section::Fig8 => s.fig8()?,
            Section::Fig12 => s.fig12()?,
            Section::Fig13 => s.fig13()?,
            Section::Scale => s.scale()?,
        }
    }
    let titles: Vec<_> = config.sections.iter().map(|x| (x.name(), x.title())).collect();
    s.report.write(&config.out, &titles)?;
    println!("\nwrote {}", config.out.join("paper.md").display());
    Ok(s.report)
}

/// What one measurement computes: section, model name, mesh, sites.
#[derive(Clone, Copy)]
struct Case<'m>(&'static str, &'m str, &'m TetMesh, &'m [[f64; 3]]);

struct Suite<'a> {
    config: &'a Config,
    backends: &'a Backends,
    report: Report,
}

/// The built-in torus, coarse, for the quick suite.
const QUICK_RESOLUTION: u32 = 8;

impl<'a> Suite<'a> {
    fn note(&mut self, note: String) {
        println!("note: {note}");
        self.report.notes.push(note);
    }

    fn builtin(&self, name: &str) -> Result<Model> {
        Model::builtin(name, self.config.quick.then_some(QUICK_RESOLUTION))
    }

    /// Folder models by name with their sites, those present; else the
    /// built-in `fallback` models (noted).
    fn folder_models(&mut self, wanted: &[(&str, usize)], fallback: &[&str]) -> Result<Vec<Model>> {
        if !self.config.quick {
            let found: Vec<Model> =
                wanted.iter().filter_map(|&(name, n)| Model::from_folder(self.config, name, n)).collect();
            if found.len() < wanted.len() {
                let missing: Vec<&str> =
                    wanted.iter().map(|w| w.0).filter(|w| !found.iter().any(|m| m.name == *w)).collect();
                self.note(format!("not in {}: {}", self.config.models_dir.display(), missing.join(", ")));
            }
            if !found.is_empty() {
                return Ok(found);
            }
        }
        fallback.iter().map(|name| self.builtin(name)).collect()
    }

    /// Measures one diagram on `backend`: the fastest of `repeat` runs.
    fn measure(
        &self,
        case: Case,
        backend: (&dyn Backend, Option<&VulkanBackend>),
        method: (Strategy, Pairing),
        k: Option<usize>,
    ) -> Result<(Row, Cells)> {
        let Case(section, model, mesh, sites) = case;
        let cv = ClippedVoronoi::new(mesh, sites).strategy(method.0).pairing(method.1).k(k).backend(backend.0);
        let mut best: Option<(Row, Cells)> = None;
        // Each Lloyd iteration of Fig. 13 is a diagram of its own: one run.
        let runs = if section == "fig13" { 1 } else { self.config.repeat.max(1) };
        for _ in 0..runs {
            if let Some(v) = backend.1 {
                v.reset_peak_memory();
            }
            let (cells, wall) = timed(|| cv.compute());
            let cells = cells?;
            let mut row = Row::new(section, model, mesh.tets.len(), backend.0, &cells);
            row.wall_ms = wall * 1e3;
            row.peak_device_mib = backend.1.map(|v| v.peak_memory() as f64 / (1u64 << 20) as f64);
            if best.as_ref().is_none_or(|b| row.total_ms < b.0.total_ms) {
                best = Some((row, cells));
            }
        }
        Ok(best.expect("at least one run"))
    }

    /// Prints and keeps a row.
    fn keep(&mut self, row: Row) -> Row {
        self.print(&row);
        self.report.rows.push(row.clone());
        row
    }

    fn print(&self, r: &Row) {
        let it = r.iteration.map_or(String::new(), |i| format!(" iteration {i}"));
        println!(
            "{:<12} |T| {:>8} |X| {:>8} {:<7} {:<14} k {:>3}{it}: knn {:>9.2} ms, clip {:>9.2} ms, total {:>9.2} ms, E_vol {:.1e}, second pass {}, missed tets {}",
            r.model,
            r.tets,
            r.sites,
            r.backend,
            r.method(),
            r.k,
            r.knn_ms,
            r.clip_ms,
            r.total_ms,
            r.e_vol,
            r.counters.second_pass,
            r.counters.missed_tets
        );
    }

    fn each_backend(&self) -> Vec<(&'a dyn Backend, Option<&'a VulkanBackend>)> {
        let backends: &'a Backends = self.backends;
        let mut out: Vec<(&'a dyn Backend, Option<&'a VulkanBackend>)> = vec![(&backends.cpu, None)];
        if let Some(v) = &backends.vulkan {
            out.push((v, Some(v)));
        }
        out
    }

    fn charts(&mut self, charts: impl IntoIterator<Item = Chart>, rows: &[Row]) -> Result<()> {
        let rows: Vec<&Row> = rows.iter().collect();
        for chart in charts {
            let path = chart.write(&self.config.out, &rows)?;
            self.report.files.push(path);
        }
        Ok(())
    }

    fn table1(&mut self) -> Result<()> {
        let mut models: Vec<Model> = Vec::new();
        for name in ["cube", "torus", "joint"] {
            let mut m = self.builtin(name)?;
            if self.config.quick {
                m.sites = 500;
            }
            models.push(m);
        }
        if !self.config.quick {
            let folder = [("torus_8k", 5000), ("bunny_10k", 10_000), ("fandisk_26k", 15_000), ("joint_31k", 35_000)];
            models.extend(self.folder_models(&folder, &[])?);
        }
        let cfg = self.config;
        for m in models.iter().filter(|m| cfg.wants(&m.name)) {
            let sites = points::in_mesh(&m.mesh, m.sites, SEED);
            for b in self.each_backend() {
                for method in methods(b.0) {
                    let row = self.measure(Case("table1", &m.name, &m.mesh, &sites), b, method, None)?.0;
                    self.keep(row);
                }
            }
        }
        Ok(())
    }

    fn fig7(&mut self) -> Result<()> {
        let folder = [("torus_8k", 0), ("bunny_10k", 0), ("fandisk_26k", 0), ("joint_31k", 0)];
        let models = self.folder_models(&folder, &["torus", "joint"])?;
        let counts: &[usize] =
            if self.config.quick { &[200, 400] } else { &[1000, 2000, 5000, 10_000, 15_000, 20_000, 25_000, 31_000] };
        let cfg = self.config;
        for m in models.iter().filter(|m| cfg.wants(&m.name)) {
            let mut rows = Vec::new();
            for &n in counts {
                let sites = points::in_mesh(&m.mesh, n, SEED);
                for b in self.each_backend() {
                    for method in methods(b.0) {
                        let row = self.measure(Case("fig7", &m.name, &m.mesh, &sites), b, method, None)?.0;
                        rows.push(self.keep(row));
                    }
                }
            }
            let chart =
                Chart::new(format!("fig7_{}.png", m.name), ("sites", |r| r.sites as f64), ("ms", |r| r.total_ms));
            self.charts([chart], &rows)?;
        }
        Ok(())
    }

    fn fig8(&mut self) -> Result<()> {
        let (targets, n): (&[usize], usize) = if self.config.quick {
            (&[1000, 2000], 300)
        } else {
            (&[10_000, 20_000, 40_000, 60_000, 80_000, 100_000], 15_000)
        };
        let cfg = self.config;
        for name in ["torus", "joint"].into_iter().filter(|n| cfg.wants(n)) {
            let base = Model::builtin(name, None)?;
            let base_resolution = cvd::mesher::models::default_resolution(name)?;
            let mut rows = Vec::new();
            for &target in targets {
                // Tets grow as the cube of the resolution.
                let r = base_resolution as f64 * (target as f64 / base.mesh.tets.len() as f64).cbrt();
                let m = Model::builtin(name, Some(r.round().max(1.0) as u32))?;
                let sites = points::in_mesh(&m.mesh, n, SEED);
                for b in self.each_backend() {
                    for method in methods(b.0) {
                        let row = self.measure(Case("fig8", name, &m.mesh, &sites), b, method, None)?.0;
                        rows.push(self.keep(row));
                    }
                }
            }
            let chart = Chart::new(format!("fig8_{name}.png"), ("tets", |r| r.tets as f64), ("ms", |r| r.total_ms));
            self.charts([chart], &rows)?;
        }
        Ok(())
    }

    fn fig12(&mut self) -> Result<()> {
        let models = self.folder_models(&[("torus_8k", 0), ("bunny_10k", 0)], &["torus", "sphere"])?;
        let (ks, n): (Vec<usize>, usize) =
            if self.config.quick { (vec![10, 20], 300) } else { ((1..=12).map(|i| 10 * i).collect(), 15_000) };
        let cfg = self.config;
        for m in models.iter().filter(|m| cfg.wants(&m.name)) {
            let sites = points::in_mesh(&m.mesh, n, SEED);
            let mut rows = Vec::new();
            for &k in &ks {
                for b in self.each_backend() {
                    for method in [METHODS[1], METHODS[2]] {
                        let row = self.measure(Case("fig12", &m.name, &m.mesh, &sites), b, method, Some(k))?.0;
                        rows.push(self.keep(row));
                    }
                }
            }
            let name = &m.name;
            let k: Axis = ("k", |r| r.k as f64);
            let missed: Axis = ("tets completed by the certificate", |r| r.counters.missed_tets as f64);
            let charts = [
                Chart::new(format!("fig12_{name}_time.png"), k, ("ms", |r| r.total_ms)),
                Chart::new(format!("fig12_{name}_missed.png"), k, missed),
                Chart::new(format!("fig12_{name}_evol.png"), k, ("e_vol", |r| r.e_vol)).log_y(),
            ];
            self.charts(charts, &rows)?;
        }
        Ok(())
    }

    fn fig13(&mut self) -> Result<()> {
        if !self.config.wants("joint") {
            return Ok(());
        }
        let m = self.builtin("joint")?;
        let counts: &[usize] = if self.config.quick { &[200] } else { &[1000, 30_000] };
        if !self.config.quick {
            self.note("Fig. 13 uses the built-in joint (the paper's Homer is not available)".into());
        }
        for &n in counts {
            let mut rows = Vec::new();
            for b in self.each_backend() {
                for method in methods(b.0) {
                    let mut sites = points::in_mesh(&m.mesh, n, SEED);
                    for it in 0..self.config.iterations {
                        let k = (method.1 == Pairing::Knn).then_some(50);
                        let (mut row, cells) = self.measure(Case("fig13", &m.name, &m.mesh, &sites), b, method, k)?;
                        row.iteration = Some(it);
                        rows.push(self.keep(row));
                        // Lloyd's step: every site to its cell's centroid.
                        sites = cells.centroid.clone();
                    }
                }
            }
            let it: Axis = ("iteration", |r| r.iteration.unwrap_or(0) as f64);
            let charts = [
                Chart::new(format!("fig13_{n}_time.png"), it, ("ms", |r| r.total_ms)),
                Chart::new(format!("fig13_{n}_clips.png"), it, ("clips", |r| r.counters.clips as f64)),
            ];
            self.charts(charts, &rows)?;
        }
        Ok(())
    }

    fn scale(&mut self) -> Result<()> {
        if !self.config.wants("cube") {
            return Ok(());
        }
        let sizes: Vec<usize> = if self.config.quick {
            vec![5000]
        } else {
            [100_000, 1_000_000, 10_000_000].into_iter().filter(|&n| n <= self.config.scale_max).collect()
        };
        let mut rows = Vec::new();
        for n in sizes {
            // The cube's resolution r has 6 r³ tets.
            let r = (n as f64 / 6.0).cbrt().round().max(1.0) as u32;
            let m = Model::builtin("cube", Some(r))?;
            let sites = points::in_mesh(&m.mesh, n, SEED);
            for b in self.each_backend() {
                match self.measure(Case("scale", "cube", &m.mesh, &sites), b, METHODS[0], None) {
                    Ok((row, _)) => rows.push(self.keep(row)),
                    // A job the device cannot hold is reported, not fatal.
                    Err(e @ Error::InvalidInput(_)) => self.note(format!("scale, {n} sites on {}: {e}", b.0.name())),
                    Err(e) => return Err(e),
                }
            }
        }
        let per_s: Axis = ("sites per second", |r| r.sites_per_s());
        let chart = Chart::new("scale_sites_per_s.png".into(), ("sites", |r| r.sites as f64), per_s).log_y();
        self.charts([chart], &rows)
    }
}
