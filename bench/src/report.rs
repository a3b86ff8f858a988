//! The suite's measurements and how they are written: one JSON file with
//! every row, one Markdown file with a table per section, PNG charts.

use cvd::diagram::voronoi::{Cells, Counters};
use cvd::error::{Error, Result};
use cvd::job::clip::{Pairing, Strategy};
use cvd_io::{write_chart_png, Axes, Series};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// One measurement.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Row {
    /// The section (`table1`, `fig7`, ...).
    pub section: &'static str,
    /// Model name.
    pub model: String,
    /// Tets in the mesh.
    pub tets: usize,
    /// Sites.
    pub sites: usize,
    /// `cpu` or `vulkan`.
    pub backend: &'static str,
    /// The device (CPU: threads; Vulkan: the driver's name).
    pub device: String,
    /// CPU threads of the process.
    pub threads: usize,
    /// Tet-cell or cell-tet.
    pub strategy: Strategy,
    /// Knn or flood pairing.
    pub pairing: Pairing,
    /// Sites paired with each tet (flood: 1).
    pub k: usize,
    /// Neighbours per site for its cell.
    pub k_site: usize,
    /// Lloyd iteration (Fig. 13).
    pub iteration: Option<usize>,
    /// Both k-NN searches, grids included.
    pub knn_ms: f64,
    /// Clipping, accumulation, cells (cell-tet), second pass, host pass.
    pub clip_ms: f64,
    /// `knn_ms + clip_ms`: inputs resident to results resident.
    pub total_ms: f64,
    /// Copies to the device (Vulkan).
    pub upload_ms: f64,
    /// Copies back (Vulkan).
    pub download_ms: f64,
    /// Wall clock of the whole call, validation and host work included.
    pub wall_ms: f64,
    /// `|Σ volumes - mesh volume| / mesh volume`.
    pub e_vol: f64,
    /// CVT energy of the diagram.
    pub energy: f64,
    /// Most device-local memory held at once (Vulkan), MiB.
    pub peak_device_mib: Option<f64>,
    /// Parts the job was split into to stay under the memory budget.
    pub chunks: u64,
    /// The counters.
    pub counters: Counters,
}

impl Row {
    /// The row of one computation's `cells` taking `wall` seconds.
    pub fn new(section: &'static str, model: &str, tets: usize, backend: &dyn cvd::Backend, cells: &Cells) -> Self {
        let t = &cells.timings;
        let (knn, clip) = (t.knn(), t.clip());
        Self {
            section,
            model: model.to_string(),
            tets,
            sites: cells.volume.len(),
            backend: backend.kind().name(),
            device: backend.device(),
            threads: rayon::current_num_threads(),
            strategy: cells.strategy,
            pairing: cells.pairing,
            k: cells.k,
            k_site: cells.k_site,
            iteration: None,
            knn_ms: knn * 1e3,
            clip_ms: clip * 1e3,
            total_ms: (knn + clip) * 1e3,
            upload_ms: t.get("upload") * 1e3,
            download_ms: t.get("download") * 1e3,
            wall_ms: 0.0,
            e_vol: cells.e_vol,
            energy: cells.energy_total(),
            peak_device_mib: None,
            chunks: cells.chunks,
            counters: cells.counters,
        }
    }

    /// `whole`, `tet-cell flood`, `cell-tet knn`, ...
    pub fn method(&self) -> String {
        let s = match self.strategy {
            Strategy::Whole => return "whole".into(),
            Strategy::TetCell => "tet-cell",
            Strategy::CellTet => "cell-tet",
        };
        let p = match self.pairing {
            Pairing::Flood => "flood",
            Pairing::Knn => "knn",
        };
        format!("{s} {p}")
    }

    /// The line a chart draws this row on.
    fn series(&self) -> String {
        format!("{} {}", self.backend, self.method())
    }

    /// Sites per second, inputs resident to results resident.
    pub fn sites_per_s(&self) -> f64 {
        self.sites as f64 / (self.total_ms * 1e-3)
    }
}

/// Everything a run measured, with the machine it ran on.
#[derive(Debug, Default, serde::Serialize)]
pub struct Report {
    /// The CPU's model name.
    pub cpu: String,
    /// CPU threads used.
    pub threads: usize,
    /// The Vulkan device, if one was used.
    pub vulkan_device: Option<String>,
    /// Seconds the Vulkan driver took to compile the kernels, paid once
    /// before anything was timed.
    pub vulkan_compile_s: Option<f64>,
    /// Notes: models or sections skipped and why.
    pub notes: Vec<String>,
    /// Every measurement.
    pub rows: Vec<Row>,
    /// Files written.
    pub files: Vec<PathBuf>,
}

/// A column of a section's table.
type Column = (&'static str, fn(&Row) -> String);

fn ms(v: f64) -> String {
    if v == 0.0 {
        "-".into()
    } else if v >= 100.0 {
        format!("{v:.0}")
    } else if v >= 10.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.2}")
    }
}

fn columns(section: &str) -> Vec<Column> {
    let mut c: Vec<Column> = vec![
        ("model", |r| r.model.clone()),
        ("\\|T\\|", |r| r.tets.to_string()),
        ("\\|X\\|", |r| r.sites.to_string()),
        ("backend", |r| r.backend.to_string()),
        ("method", |r| r.method()),
        ("k", |r| if r.pairing == Pairing::Flood { "-".into() } else { r.k.to_string() }),
        ("k_site", |r| r.k_site.to_string()),
    ];
    if section == "fig13" {
        c.push(("iteration", |r| r.iteration.map_or("-".into(), |i| i.to_string())));
    }
    c.extend::<[Column; 3]>([
        ("knn ms", |r| ms(r.knn_ms)),
        ("clip ms", |r| ms(r.clip_ms)),
        ("total ms", |r| ms(r.total_ms)),
    ]);
    match section {
        "table1" | "scale" => {
            c.extend::<[Column; 2]>([("upload ms", |r| ms(r.upload_ms)), ("download ms", |r| ms(r.download_ms))])
        }
        "fig13" => c.extend::<[Column; 2]>([
            ("clips", |r| r.counters.clips.to_string()),
            ("energy", |r| format!("{:.5e}", r.energy)),
        ]),
        _ => {}
    }
    if section == "scale" {
        c.extend::<[Column; 3]>([
            ("sites/s", |r| format!("{:.3e}", r.sites_per_s())),
            ("peak device MiB", |r| r.peak_device_mib.map_or("-".into(), |m| format!("{m:.0}"))),
            ("chunks", |r| r.chunks.to_string()),
        ]);
    }
    c.extend::<[Column; 4]>([
        ("E_vol", |r| format!("{:.1e}", r.e_vol)),
        ("walked", |r| r.counters.walks.to_string()),
        ("second pass", |r| r.counters.second_pass.to_string()),
        ("missed tets", |r| r.counters.missed_tets.to_string()),
    ]);
    c
}

/// The Markdown table of `rows`.
pub fn markdown_table(section: &str, rows: &[&Row]) -> String {
    let cols = columns(section);
    let mut s = String::new();
    let _ = writeln!(s, "| {} |", cols.iter().map(|c| c.0).collect::<Vec<_>>().join(" | "));
    let _ = writeln!(s, "|{}", cols.iter().map(|c| if c.0 == "model" { "---|" } else { "---:|" }).collect::<String>());
    for r in rows {
        let _ = writeln!(s, "| {} |", cols.iter().map(|c| (c.1)(r)).collect::<Vec<_>>().join(" | "));
    }
    s
}

/// A chart: `y` against `x` of the rows, one line per backend and method.
pub struct Chart {
    /// File name in the output folder.
    pub file: String,
    /// Axis labels and scale.
    pub x_name: &'static str,
    /// See `x_name`.
    pub y_name: &'static str,
    /// Logarithmic vertical axis.
    pub log_y: bool,
    /// The horizontal value of a row.
    pub x: fn(&Row) -> f64,
    /// The vertical value of a row.
    pub y: fn(&Row) -> f64,
}

const COLOURS: [[u8; 3]; 8] = [
    [200, 40, 40],
    [40, 80, 200],
    [30, 150, 60],
    [220, 130, 20],
    [130, 50, 170],
    [20, 160, 170],
    [120, 120, 120],
    [180, 60, 130],
];

/// An axis: its label and the value of a row on it.
pub type Axis = (&'static str, fn(&Row) -> f64);

impl Chart {
    /// A chart of `y` against `x`, both linear.
    pub fn new(file: String, x: Axis, y: Axis) -> Self {
        Self { file, x_name: x.0, y_name: y.0, log_y: false, x: x.1, y: y.1 }
    }

    /// The same with a logarithmic vertical axis.
    pub fn log_y(self) -> Self {
        Self { log_y: true, ..self }
    }

    /// Draws the chart of `rows` into `dir`.
    pub fn write(&self, dir: &Path, rows: &[&Row]) -> Result<PathBuf> {
        let mut lines: BTreeMap<String, (Vec<f64>, Vec<f64>)> = BTreeMap::new();
        for r in rows {
            let line = lines.entry(r.series()).or_default();
            line.0.push((self.x)(r));
            line.1.push((self.y)(r));
        }
        let series: Vec<Series> = lines
            .iter()
            .zip(COLOURS.iter().cycle())
            .map(|((name, (x, y)), rgb)| Series { name, values: y, x, rgb: *rgb })
            .collect();
        let path = dir.join(&self.file);
        let axes = Axes { x_name: self.x_name, y_name: self.y_name, log_y: self.log_y };
        write_chart_png(&path, &axes, &series)?;
        Ok(path)
    }
}

impl Report {
    /// Writes `paper.json` and `paper.md` (a table per section, charts
    /// linked) into `dir`, with the files written before.
    pub fn write(&mut self, dir: &Path, sections: &[(&'static str, &'static str)]) -> Result<()> {
        let io = |path: &Path, e: std::io::Error| Error::Write { path: path.display().to_string(), source: e };
        let mut md = String::from("# Benchmark suite (`cargo xtask bench paper`)\n\n");
        let _ = writeln!(md, "CPU: {}, {} threads.", self.cpu, self.threads);
        match (&self.vulkan_device, self.vulkan_compile_s) {
            (Some(d), Some(c)) => {
                let _ = writeln!(md, "Vulkan device: {d} (kernel compilation on first use, paid once: {c:.2} s).");
            }
            _ => md.push_str("Vulkan: not used.\n"),
        }
        for n in &self.notes {
            let _ = writeln!(md, "\n- {n}");
        }
        for (name, title) in sections {
            let rows: Vec<&Row> = self.rows.iter().filter(|r| r.section == *name).collect();
            if rows.is_empty() {
                continue;
            }
            let _ = write!(md, "\n## {title}\n\n{}", markdown_table(name, &rows));
            let prefix = format!("{name}_");
            for f in self.files.iter().filter_map(|f| f.file_name()?.to_str()).filter(|f| f.starts_with(&prefix)) {
                let _ = write!(md, "\n![{f}]({f})\n");
            }
        }
        let md_path = dir.join("paper.md");
        std::fs::write(&md_path, md).map_err(|e| io(&md_path, e))?;
        let json_path = dir.join("paper.json");
        self.files.push(md_path);
        self.files.push(json_path.clone());
        let json = serde_json::to_string_pretty(&self).map_err(|e| Error::InvalidInput(e.to_string()))?;
        std::fs::write(&json_path, json).map_err(|e| io(&json_path, e))?;
        Ok(())
    }
}

/// The CPU's model name (Linux: `/proc/cpuinfo`).
pub fn cpu_name() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| s.lines().find(|l| l.starts_with("model name"))?.split(':').nth(1).map(|v| v.trim().to_string()))
        .unwrap_or_else(|| std::env::consts::ARCH.to_string())
}
