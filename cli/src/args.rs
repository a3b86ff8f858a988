//! The command line's arguments (clap), and what they say beyond their
//! values.

use clap::{Args, Parser, Subcommand};
use cvd::backends::vulkan::VulkanOptions;
use cvd::backends::{BackendChoice, BackendOptions};
use cvd::cvt::Optimizer;
use cvd::{KnnMethod, Pairing, Strategy};
use std::path::PathBuf;

#[derive(Parser)]
#[command(name = "cvd", version, about = "Clipped Voronoi diagrams on Vulkan GPUs and CPU cores")]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand)]
pub enum Command {
    /// List the Vulkan devices (the index or a part of the name picks one with --device).
    Devices {
        /// As JSON: index, name, type and whether it is a real GPU (what
        /// `--backend auto` would use).
        #[arg(long)]
        json: bool,
    },
    /// The clipped Voronoi diagram of random sites in a model.
    Run(Box<RunArgs>),
    /// k nearest neighbours of random sites; checks the backend against the CPU.
    Knn(KnnArgs),
    /// Write the kernels as SPIR-V modules, one per entry point, and their
    /// manifest.json (docs/EMBEDDING.md).
    Spirv {
        /// Output folder.
        #[arg(long, default_value = "spirv")]
        out: PathBuf,
    },
}

#[derive(Args)]
pub struct RunArgs {
    /// Model: built-in `joint`, `torus`, `sphere` or `cube` (meshed on the
    /// fly), or NAME.mesh / NAME_*.mesh / NAME.tet in the models folder.
    #[arg(long, default_value = "joint")]
    pub model: String,
    /// Folder of model files (default: $CVD_MODELS); its files win over built-in models.
    #[arg(long)]
    pub models_dir: Option<PathBuf>,
    // The formats from cvd-io's table.
    #[arg(long, help = format!("A tet mesh file instead of --model: {}", cvd_io::formats::mesh_help()))]
    pub mesh: Option<PathBuf>,
    #[arg(long, conflicts_with = "mesh", help = format!(
        "A closed triangle surface whose volume is meshed into tets (isosurface stuffing, --resolution lattice \
         cubes along its longest side; default 40) instead of --model: {}",
        cvd_io::formats::surface_help()
    ))]
    pub surface: Option<PathBuf>,
    /// With --surface: about this many tets (sets the resolution; instead
    /// of --resolution).
    #[arg(long, conflicts_with = "resolution")]
    pub tets: Option<usize>,
    /// Built-in model resolution: lattice cells along the longest side
    /// (cube: sub-cubes per side; default: joint 37, others 16).
    #[arg(long)]
    pub resolution: Option<u32>,
    /// Number of sites, uniform inside the mesh (default: joint 35000, as
    /// in the paper's Table 1; others 5000).
    #[arg(long)]
    pub sites: Option<usize>,
    #[arg(long, help = format!("Sites from a file: {}", cvd_io::formats::sites_help()))]
    pub sites_file: Option<PathBuf>,
    /// Random seed of the sites.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Whole cells (each cell built once; only those the boundary may cut
    /// go through the tets), or the paper's tet-cell or cell-tet. Default:
    /// whole on the CPU backend; tet-cell under a density, on Vulkan and in
    /// parts.
    #[arg(long, value_enum)]
    pub strategy: Option<Strategy>,
    /// Pairing of tets and sites: flood (exact; default for tet-cell) or knn
    /// (paper Eq. 6; default for cell-tet).
    #[arg(long, value_enum)]
    pub pairing: Option<Pairing>,
    /// Sites paired with each tet (default: the paper's Eq. 6).
    #[arg(long, short)]
    pub k: Option<usize>,
    /// Lloyd iterations before the final diagram (0: the diagram of the
    /// sites as given). On Vulkan the loop runs on the device.
    #[arg(long, default_value_t = 0)]
    pub iterations: usize,
    /// A density ρ(x, y, z) > 0 weighting volumes, centroids and energies,
    /// e.g. "1+10*x" (world coordinates; + - * / ^, exp sqrt abs sin cos),
    /// evaluated at the mesh vertices and linear inside each tet.
    #[arg(long, conflicts_with = "density_file")]
    pub density: Option<String>,
    /// A density per mesh vertex from a file: one number per line, in the
    /// mesh's vertex order (`#` comments allowed).
    #[arg(long)]
    pub density_file: Option<PathBuf>,
    /// Power (Laguerre) cells: a weight per site from a file, one number
    /// per line in the sites' order (`#` comments allowed), in squared
    /// units of length; site i's cell is where |x - x_i|² - w_i is least.
    /// Cells may be empty (counted). With --transport: where its Newton
    /// steps start.
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// Optimal transport: find the power weights that give every cell the
    /// same mass (the mesh's volume, or mass under a density, over the
    /// sites), by damped Newton steps; writes weights.txt. With
    /// --iterations: the capacity-constrained CVT (transport, then sites
    /// to their cells' centroids, each iteration).
    #[arg(long)]
    pub transport: bool,
    /// Optimal transport to a capacity per site from a file (one positive
    /// number per line in the sites' order, normalised to the mesh's mass);
    /// implies --transport.
    #[arg(long, value_name = "PATH")]
    pub capacities: Option<PathBuf>,
    /// Optimal transport to volumes drawn from a law, one per site, as
    /// polycrystal generators do: `lognormal:MU,SIGMA` (ln of a volume
    /// normal with mean MU and deviation SIGMA), drawn with --seed and
    /// scaled to the mesh's volume; implies --transport. The grains'
    /// polyhedra are in cells.vtu (cell data `site`: the grain).
    #[arg(long, value_name = "LAW", conflicts_with = "capacities")]
    pub volumes: Option<cvd::cvt::transport::VolumeLaw>,
    /// Optimal transport stops when every cell's mass is within this of
    /// its target, relative to it.
    #[arg(long, default_value_t = 1e-6)]
    pub tolerance: f64,
    /// Optimal transport's Newton steps at most (per solve).
    #[arg(long, default_value_t = 50)]
    pub newton_steps: usize,
    /// How the iterations minimise the CVT energy.
    #[arg(long, value_enum, default_value_t = Optimizer::Lloyd)]
    pub optimizer: Optimizer,
    /// Neighbours per site for its cell [default: 48 for flood pairing on
    /// the CPU (a piece its list does not settle walks the site grid), 90
    /// otherwise].
    #[arg(long)]
    pub k_site: Option<usize>,
    /// A periodic box: each site's cell in the space the box tiles, cut
    /// into the box (sites outside it are wrapped in); the box from --box,
    /// or the unit cube with --model cube. neighbors.csv gains each
    /// neighbour's image shift.
    #[arg(long)]
    pub periodic: bool,
    /// The periodic box's corners (implies --periodic).
    #[arg(long = "box", value_name = "X0,Y0,Z0,X1,Y1,Z1", value_delimiter = ',', allow_hyphen_values = true)]
    pub periodic_box: Option<Vec<f64>>,
    /// A triclinic box by LAMMPS's tilts (lengths) of the box --box gives:
    /// a = (X1-X0, 0, 0), b = (XY, Y1-Y0, 0), c = (XZ, YZ, Z1-Z0) from its
    /// lower corner.
    #[arg(long, value_name = "XY,XZ,YZ", value_delimiter = ',', allow_hyphen_values = true, requires = "periodic_box")]
    pub tilt: Option<Vec<f64>>,
    /// A triclinic box by its three edge vectors a, b, c (a right-handed
    /// frame), from --origin (implies --periodic).
    #[arg(
        long,
        value_name = "AX,AY,AZ,BX,BY,BZ,CX,CY,CZ",
        value_delimiter = ',',
        allow_hyphen_values = true,
        conflicts_with = "periodic_box"
    )]
    pub lattice: Option<Vec<f64>>,
    /// The corner the --lattice vectors start from.
    #[arg(long, value_name = "X,Y,Z", value_delimiter = ',', allow_hyphen_values = true, requires = "lattice")]
    pub origin: Option<Vec<f64>>,
    /// The axes along which the box repeats, of x y z (a b c for a
    /// triclinic box); along the others its faces are walls that cut the
    /// cells (`xy`: a slab with walls at its z faces).
    #[arg(long, value_name = "AXES", default_value = "xyz")]
    pub periodic_axes: String,
    /// A particle trajectory (LAMMPS text dump, extended XYZ): the cells
    /// of each frame in its own cell (periodic axes and radii from the
    /// file), written to frames/cells.<frame>.csv with summary.json.
    #[arg(long, value_name = "PATH", conflicts_with_all = ["mesh", "surface", "sites_file", "periodic_box", "lattice"])]
    pub particles: Option<PathBuf>,
    /// The frames of --particles: A:B:STEP (from A to before B, every
    /// STEP; each part optional, as Python's slices), or one frame N.
    #[arg(long, value_name = "A:B:STEP", requires = "particles")]
    pub frames: Option<FrameRange>,
    /// Builds every frame of --particles afresh. By default a frame starts
    /// from the last one's neighbour lists where the particles' largest
    /// displacement still certifies them (the same cells; CPU backend).
    #[arg(long, requires = "particles")]
    pub rebuild_frames: bool,
    /// Radical (power) cells from a radius per particle, one number per
    /// line in the sites' order: weights r², as voro++'s radical
    /// tessellation.
    #[arg(long, value_name = "PATH", conflicts_with = "weights")]
    pub radii: Option<PathBuf>,
    /// The particles' quantities in cells.csv: each cell's faces counted
    /// above the thresholds (coordination), the Voronoi index (faces with
    /// 3, 4, ..., 10 or more edges: columns n3..n10) and the largest face
    /// order, as OVITO's Voronoi analysis; summary.json gains the most
    /// common indices. Computes the cells' polyhedra (whole cells).
    #[arg(long)]
    pub voronoi_index: bool,
    /// Edges shorter than this length are not counted in the Voronoi index.
    #[arg(long, default_value_t = 0.0, value_name = "LENGTH")]
    pub edge_threshold: f64,
    /// Edges shorter than this times the cell's V^(1/3) are not counted.
    #[arg(long, default_value_t = 0.0, value_name = "FRACTION")]
    pub relative_edge_threshold: f64,
    /// Faces of this area or less are not counted.
    #[arg(long, default_value_t = 0.0, value_name = "AREA")]
    pub face_threshold: f64,
    /// Faces of this fraction of the cell's surface or less are not
    /// counted.
    #[arg(long, default_value_t = 0.0, value_name = "FRACTION")]
    pub relative_face_threshold: f64,
    /// Output folder [default: out/<model or mesh file name>/].
    #[arg(long, long_help = crate::outputs::help())]
    pub out: Option<PathBuf>,
    /// Also write cells.csv (site, volume, centroid, energy) to PATH.
    #[arg(long, value_name = "PATH")]
    pub output: Option<PathBuf>,
    /// Also write summary.json to PATH.
    #[arg(long, value_name = "PATH")]
    pub json: Option<PathBuf>,
    /// Skip the cells' geometry: cells.vtu, walls.ply and the pictures.
    /// The geometry takes one more run on the CPU, which keeps every piece
    /// (each site's cell inside each tet) in memory to merge them.
    #[arg(long, alias = "no-pieces")]
    pub no_geometry: bool,
    /// Also write pieces.vtu: every piece (each site's cell inside each tet)
    /// as a VTK polyhedron (ASCII, several per tet: large).
    #[arg(long, conflicts_with = "no_geometry")]
    pub pieces: bool,
    /// Skip picture.png and cells.png (the cells cut by the plane through the
    /// middle of the mesh, and those below it in 3D).
    #[arg(long)]
    pub no_picture: bool,
    /// Skip neighbors.csv: the faces the cells share and their areas, and
    /// each cell's area on the domain's boundary (summed with the diagram).
    #[arg(long)]
    pub no_neighbors: bool,
    /// Compute the diagram once more before the timed run (caches, memory,
    /// the driver's kernel compilation), as benchmarks do.
    #[arg(long)]
    pub warm_up: bool,
    /// Compute in N parts, one after another: the same results to the bit,
    /// one part's lists and grids in memory at a time. Without `mpirun`:
    /// the diagram in N parts (whole cells: runs of the sites; tet-cell:
    /// runs of the tets, with the sites of a halo around them). Under
    /// `mpirun -np P` (a build with the `mpi` feature), a mesh's sites in
    /// parts: each rank's share in N parts, P x N in all (by default 4 a
    /// rank, fewer where a part would own fewer than 16 384 sites; a part's
    /// job then holds less than the rows the rank writes). docs/PARALLEL.md.
    #[arg(long, value_name = "N")]
    pub parts: Option<usize>,
    /// In parts: the first round's halo, LISTED,BEYOND grid cells (about 5
    /// sites each) around a part's tets: the sites of the first get
    /// neighbour lists, those of both are held. Narrower halos hold fewer
    /// sites and leave more tets to later rounds; the results are the same.
    #[arg(long, value_name = "LISTED,BEYOND", value_parser = two_counts)]
    pub halo: Option<[u32; 2]>,
    /// Under `mpirun`, a mesh's sites in parts: the folder where each rank
    /// keeps the faces of the rows it will write until it writes them (a
    /// file of its own, unlinked as soon as it is made), not in memory.
    /// Default: the output folder.
    #[arg(long, value_name = "DIR")]
    pub scratch: Option<std::path::PathBuf>,
    #[command(flatten)]
    pub backend: BackendArgs,
}

/// `A,B`: two whole numbers.
fn two_counts(s: &str) -> Result<[u32; 2], String> {
    let v: Vec<&str> = s.split(',').collect();
    match v[..] {
        [a, b] => match (a.trim().parse(), b.trim().parse()) {
            (Ok(a), Ok(b)) => Ok([a, b]),
            _ => Err(format!("'{s}': expected two whole numbers of cells, such as 2,3")),
        },
        _ => Err(format!("'{s}': expected two numbers of cells separated by a comma, such as 2,3")),
    }
}

#[derive(Args, Clone)]
pub struct BackendArgs {
    /// Where the kernels run.
    #[arg(long, value_enum, default_value_t = BackendChoice::Auto)]
    pub backend: BackendChoice,
    /// CPU backend threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Vulkan device: an index from `cvd devices` or part of its name (named
    /// devices are used by `--backend auto` too, GPU or not).
    #[arg(long)]
    pub device: Option<String>,
    /// Enable the Vulkan validation layer.
    #[arg(long)]
    pub validation: bool,
    /// Most memory a job may hold, in MiB. On a Vulkan device (default:
    /// 80 % of its memory) larger jobs run in chunks; on the CPU (default:
    /// the memory the machine has available) a larger job is refused
    /// before it starts, with both numbers.
    #[arg(long, value_name = "MIB")]
    pub memory_budget: Option<u64>,
}

impl BackendArgs {
    pub fn options(&self) -> BackendOptions {
        BackendOptions {
            choice: self.backend,
            threads: self.threads,
            vulkan: VulkanOptions {
                device: self.device.clone(),
                validation: self.validation,
                memory_budget: self.memory_budget.map(|mib| mib << 20),
            },
        }
    }
}

#[derive(Args)]
pub struct KnnArgs {
    /// Number of sites, uniform in the unit cube.
    #[arg(long, default_value_t = 35_000)]
    pub sites: usize,
    /// Neighbours per site.
    #[arg(long, short, default_value_t = 90)]
    pub k: usize,
    /// Search method.
    #[arg(long, value_enum, default_value_t = KnnMethod::Grid)]
    pub method: KnnMethod,
    /// Random seed of the sites.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    #[command(flatten)]
    pub backend: BackendArgs,
}

impl RunArgs {
    /// `--memory-budget` in bytes where it limits the host's memory: off
    /// the Vulkan backend (on a device it splits jobs instead).
    pub fn cpu_memory_budget(&self) -> Option<u64> {
        let cpu = self.backend.backend != cvd::BackendChoice::Vulkan;
        self.backend.memory_budget.filter(|_| cpu).map(|mib| mib << 20)
    }

    /// Whether the arguments ask for optimal transport.
    pub fn transports(&self) -> bool {
        self.transport || self.capacities.is_some() || self.volumes.is_some()
    }

    /// The Voronoi index's thresholds, checked.
    pub fn index_thresholds(&self) -> cvd::Result<cvd::IndexThresholds> {
        let t = cvd::IndexThresholds {
            edge: self.edge_threshold,
            relative_edge: self.relative_edge_threshold,
            face: self.face_threshold,
            relative_face: self.relative_face_threshold,
        };
        t.check()?;
        Ok(t)
    }

    /// Whether the domain is a periodic box.
    pub fn periodic(&self) -> bool {
        self.periodic || self.periodic_box.is_some() || self.lattice.is_some()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::{CommandFactory, ValueEnum};

    /// The names the engine gives its enums (in files and tables) are the
    /// ones the command line takes.
    #[test]
    fn value_names_are_the_engines_names() {
        fn same<T: ValueEnum>(name: impl Fn(&T) -> &'static str) {
            for v in T::value_variants() {
                let clap = v.to_possible_value().map(|p| p.get_name().to_string());
                assert_eq!(clap.as_deref(), Some(name(v)));
            }
        }
        same::<Strategy>(|s| s.name());
        same::<Pairing>(|p| p.name());
        same::<KnnMethod>(|m| m.name());
        same::<Optimizer>(|o| o.name());
        same::<BackendChoice>(|b| b.name());
        assert_eq!(BackendChoice::value_variants(), BackendChoice::ALL);
        for b in BackendChoice::ALL {
            assert_eq!(BackendChoice::from_name(b.name()), Some(b));
        }
        assert_eq!(BackendChoice::from_name("gpu"), None);
    }

    #[test]
    fn the_arguments_are_consistent() {
        Cli::command().debug_assert();
    }

    #[test]
    fn halo_takes_two_counts() {
        assert_eq!(two_counts("2, 3"), Ok([2, 3]));
        assert!(two_counts("2").unwrap_err().contains("separated by a comma"));
        assert!(two_counts("a,3").unwrap_err().contains("whole numbers"));
    }
}

/// The frames `--frames A:B:STEP` asks for: from `A` (default 0) to before
/// `B` (default: the end), every `STEP` (default 1); `N` alone is that
/// frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameRange {
    pub start: usize,
    pub end: Option<usize>,
    pub step: usize,
}

impl std::str::FromStr for FrameRange {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let number = |t: &str, what: &str| -> Result<Option<usize>, String> {
            let t = t.trim();
            if t.is_empty() {
                return Ok(None);
            }
            t.parse::<usize>().map(Some).map_err(|_| format!("{what} {t:?} is not a frame number (0, 1, 2, ...)"))
        };
        let parts: Vec<&str> = s.split(':').collect();
        let range = match parts.as_slice() {
            [one] => {
                let n = number(one, "the frame")?.ok_or("expected A:B:STEP, A:B or a frame number")?;
                FrameRange { start: n, end: Some(n + 1), step: 1 }
            }
            [a, b] => FrameRange { start: number(a, "the start")?.unwrap_or(0), end: number(b, "the end")?, step: 1 },
            [a, b, c] => FrameRange {
                start: number(a, "the start")?.unwrap_or(0),
                end: number(b, "the end")?,
                step: number(c, "the step")?.unwrap_or(1),
            },
            _ => return Err(format!("{s:?}: expected A:B:STEP")),
        };
        if range.step == 0 {
            return Err("the step must be at least 1".into());
        }
        Ok(range)
    }
}

impl FrameRange {
    /// Whether frame `index` is one asked for.
    pub fn wants(&self, index: usize) -> bool {
        index >= self.start && self.end.is_none_or(|e| index < e) && (index - self.start).is_multiple_of(self.step)
    }

    /// Whether no frame from `index` on is asked for.
    pub fn past(&self, index: usize) -> bool {
        self.end.is_some_and(|e| index >= e)
    }

    /// How many frames it asks for, if it knows.
    pub fn count(&self) -> Option<usize> {
        self.end.map(|e| e.saturating_sub(self.start).div_ceil(self.step))
    }
}

#[cfg(test)]
mod frame_range_tests {
    use super::FrameRange;

    #[test]
    fn frame_ranges_read_as_slices() {
        let r = |s: &str| s.parse::<FrameRange>();
        assert_eq!(r("2:10:3"), Ok(FrameRange { start: 2, end: Some(10), step: 3 }));
        assert_eq!(r(":"), Ok(FrameRange { start: 0, end: None, step: 1 }));
        assert_eq!(r("5"), Ok(FrameRange { start: 5, end: Some(6), step: 1 }));
        assert_eq!(r("::2"), Ok(FrameRange { start: 0, end: None, step: 2 }));
        assert!(r("1:2:0").unwrap_err().contains("step"));
        assert!(r("a:2").unwrap_err().contains("\"a\""));
        assert!(r("1:2:3:4").is_err());
        let range = r("2:10:3").unwrap();
        let wanted: Vec<usize> = (0..12).filter(|&i| range.wants(i)).collect();
        assert_eq!(wanted, [2, 5, 8]);
        assert_eq!(range.count(), Some(3));
        assert!(range.past(10) && !range.past(9));
    }
}
