//! What a run reads: its domain (a tet mesh from a file, a surface meshed,
//! a built-in model, or a periodic box), its sites, and the numbers given
//! per site or per vertex (weights, capacities, a density).

use crate::args::RunArgs;
use cvd::mesher::models;
use cvd::{geom::points, PeriodicBox, TetMesh};
use std::path::{Path, PathBuf};

/// Where the cells live.
pub enum Domain {
    /// A tet mesh: the cells are clipped to it.
    Mesh(TetMesh),
    /// A periodic box: the cells of the space it tiles, cut into it.
    Box(PeriodicBox),
}

/// A run's inputs.
pub struct Inputs {
    /// The model's name, or the mesh or surface file's.
    pub name: String,
    /// The domain.
    pub domain: Domain,
    /// The sites as given (a file's coordinates to the last digit).
    pub sites: Vec<[f64; 3]>,
    /// Power weights from `--weights`, one per site.
    pub weights: Option<Vec<f64>>,
    /// A density per mesh vertex (`--density`, `--density-file`).
    pub density: Option<Vec<f64>>,
    /// Sites given outside a periodic box (wrapped into it).
    pub wrapped: usize,
}

impl Inputs {
    /// Reads (or makes) everything the arguments name, checked.
    pub fn read(args: &RunArgs) -> cvd::Result<Self> {
        if args.periodic() {
            let domain = periodic_box(args)?;
            // Whole cells frame the box with 6 tets; its images may be as
            // many as its sites.
            let job = |n: usize| check_memory(args, 2 * n as u64, 6);
            let sites: Vec<[f64; 3]> = match &args.sites_file {
                Some(path) => cvd_io::read_sites(path)?,
                None => {
                    let n = args.sites.unwrap_or(5000);
                    job(n)?;
                    let unit = points::uniform(n, args.seed);
                    unit.iter().map(|&p| domain.cartesian(p)).collect()
                }
            };
            job(sites.len())?;
            let weights = weights(args, sites.len())?;
            // Said of the sites as given (the iterations move wrapped ones).
            let wrapped = sites.iter().filter(|&&p| domain.wrap(p) != p).count();
            let name = "periodic box".to_string();
            return Ok(Self { name, domain: Domain::Box(domain), sites, weights, density: None, wrapped });
        }
        let (name, mesh) = load_model(args)?;
        let job = |n: usize| check_memory(args, n as u64, mesh.tets.len() as u64);
        let sites: Vec<[f64; 3]> = match &args.sites_file {
            Some(path) => cvd_io::read_sites(path)?,
            None => {
                let n = match args.sites {
                    Some(n) => n,
                    None => models::default_sites(&args.model).unwrap_or(5000),
                };
                job(n)?;
                points::in_mesh(&mesh, n, args.seed)
            }
        };
        job(sites.len())?;
        let weights = weights(args, sites.len())?;
        let density = density(args, &mesh)?;
        Ok(Self { name, domain: Domain::Mesh(mesh), sites, weights, density, wrapped: 0 })
    }

    /// The folder `--out` names, or `out/<name>`: the model's name, the
    /// mesh file's name without extension, or `periodic`.
    pub fn out_dir(&self, args: &RunArgs) -> PathBuf {
        let name = match self.domain {
            Domain::Mesh(_) => self.name.as_str(),
            Domain::Box(_) => PERIODIC_DIR,
        };
        out_dir(args, name)
    }
}

/// The folder `--out` names, or `out/<name>` (without a file's extension).
pub(crate) fn out_dir(args: &RunArgs, name: &str) -> PathBuf {
    if let Some(dir) = &args.out {
        return dir.clone();
    }
    let stem = Path::new(name).file_stem().map(|s| s.to_string_lossy().into_owned());
    Path::new("out").join(stem.filter(|s| !s.is_empty()).unwrap_or_else(|| "model".into()))
}

/// The output folder's name for a periodic box (in `out/`).
pub(crate) const PERIODIC_DIR: &str = "periodic";

/// Refuses a run whose job of `sites` sites and `tets` tets would not fit
/// in memory (`cvd::job::memory`), before its sites are made: against
/// `--memory-budget` on the CPU, else the memory the machine has.
pub(crate) fn check_memory(args: &RunArgs, sites: u64, tets: u64) -> cvd::Result<()> {
    use cvd::job::clip::{DEFAULT_K_SITE, DEFAULT_K_SITE_CPU_FLOOD};
    let cpu = args.backend.backend != cvd::BackendChoice::Vulkan;
    let k_site = args.k_site.unwrap_or(if cpu { DEFAULT_K_SITE_CPU_FLOOD } else { DEFAULT_K_SITE });
    let size = cvd::job::memory::JobSize { sites, tets, k_site: k_site as u64, faces: !args.no_neighbors };
    cvd::job::memory::check(&format!("a job of {sites} sites and {tets} tets"), size.bytes(), args.cpu_memory_budget())
}

/// The model's mesh: an explicit file, a file of that name in the models
/// folder, or a built-in model; inverted tets turned.
pub(crate) fn load_model(args: &RunArgs) -> cvd::Result<(String, TetMesh)> {
    let (name, mut mesh) = find_model(args)?;
    let flipped = mesh.orient_positively();
    if flipped > 0 {
        eprintln!("{name}: {flipped} inverted tets, reoriented");
    }
    Ok((name, mesh))
}

/// Reads, checks and meshes a closed surface, saying what was fixed and how
/// good the mesh is.
fn mesh_surface_file(path: &Path, resolution: Option<u32>, tets: Option<usize>) -> cvd::Result<(String, TetMesh)> {
    let name = path.display().to_string();
    let (surface, r) = cvd_io::read_surface(path)?.into_closed(&name)?;
    let mut fixed = Vec::new();
    for (n, what) in [
        (r.dropped, "triangles with a repeated vertex dropped"),
        (r.reoriented, "triangles turned to agree with their neighbours"),
        (r.flipped_shells, "shells turned outward"),
        (r.zero_area, "triangles of zero area"),
    ] {
        if n > 0 {
            fixed.push(format!("{n} {what}"));
        }
    }
    if r.open_edges > 0 {
        fixed.push(format!(
            "{} open edges in {} cracks up to {:.2e} across, let through (the sign across them is the winding number's)",
            r.open_edges, r.cracks, r.widest_crack
        ));
    }
    let holes = if r.holes > 0 { format!(" ({} holes)", r.holes) } else { String::new() };
    println!(
        "{name}: {} triangles, {} shells{holes}, volume {:.6e}{}",
        r.triangles,
        r.shells,
        r.volume,
        if fixed.is_empty() { String::new() } else { format!("; {}", fixed.join(", ")) }
    );
    let resolution = match (resolution, tets) {
        (Some(r), _) => r,
        (None, Some(n)) => cvd::mesher::resolution_for_tets(&surface, n)?,
        (None, None) => cvd::mesher::DEFAULT_SURFACE_RESOLUTION,
    };
    let mesh = cvd::mesher::mesh_surface(&surface, resolution)?;
    let q = cvd::mesher::quality::Quality::of(&mesh);
    println!(
        "meshed at resolution {resolution}: {} tets, dihedral angles {:.1}..{:.1} degrees, volume {:+.3} % of the surface's",
        mesh.tets.len(),
        q.min_dihedral,
        q.max_dihedral,
        100.0 * (mesh.volume() - r.volume) / r.volume
    );
    Ok((name, mesh))
}

/// The model's mesh as found, before any repair.
fn find_model(args: &RunArgs) -> cvd::Result<(String, TetMesh)> {
    if let Some(path) = &args.mesh {
        return Ok((path.display().to_string(), cvd_io::read_mesh(path)?));
    }
    if let Some(path) = &args.surface {
        return mesh_surface_file(path, args.resolution, args.tets);
    }
    let dir = args.models_dir.clone().or_else(|| std::env::var_os("CVD_MODELS").map(PathBuf::from));
    if let Some(dir) = dir {
        let name = &args.model;
        let mut candidates = vec![dir.join(format!("{name}.mesh")), dir.join(format!("{name}.tet"))];
        if let Ok(entries) = std::fs::read_dir(&dir) {
            let mut more: Vec<PathBuf> = entries
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| {
                    let file = p.file_name().and_then(|f| f.to_str()).unwrap_or("");
                    file.starts_with(&format!("{name}_")) && file.ends_with(".mesh")
                })
                .collect();
            // joint_31k before joint_100k: numbers compare as numbers.
            more.sort_by_key(|p| natural_key(&p.to_string_lossy()));
            candidates.extend(more);
        }
        if let Some(path) = candidates.into_iter().find(|p| p.is_file()) {
            return Ok((path.display().to_string(), cvd_io::read_mesh(&path)?));
        }
        let mut surfaces =
            cvd_io::formats::extensions(cvd_io::formats::SURFACES).map(|e| dir.join(format!("{name}.{e}")));
        if let Some(path) = surfaces.find(|p| p.is_file()) {
            return mesh_surface_file(&path, args.resolution, args.tets);
        }
    }
    let name = args.model.as_str();
    if !models::NAMES.contains(&name) {
        return Err(cvd::Error::InvalidInput(format!(
            "unknown model '{name}': built-in models: {}; or give --mesh PATH, or --models-dir DIR holding {name}.mesh",
            models::NAMES.join(", ")
        )));
    }
    let mesh = models::builtin(name, args.resolution)?;
    let resolution = args.resolution.map_or_else(|| models::default_resolution(name), Ok)?;
    println!("{name} (built-in, resolution {resolution}): {}", cvd::mesher::quality::Quality::of(&mesh));
    Ok((name.to_string(), mesh))
}

/// A sort key in which runs of digits compare by value.
fn natural_key(s: &str) -> Vec<(String, u64)> {
    let mut key = Vec::new();
    let mut text = String::new();
    let mut chars = s.chars().peekable();
    while let Some(c) = chars.next() {
        if c.is_ascii_digit() {
            let mut n = c.to_digit(10).unwrap_or(0) as u64;
            while let Some(d) = chars.peek().and_then(|d| d.to_digit(10)) {
                n = n.saturating_mul(10).saturating_add(d as u64);
                chars.next();
            }
            key.push((std::mem::take(&mut text), n));
        } else {
            text.push(c);
        }
    }
    key.push((text, 0));
    key
}

/// The density per mesh vertex the arguments ask for, if any.
pub(crate) fn density(args: &RunArgs, mesh: &TetMesh) -> cvd::Result<Option<Vec<f64>>> {
    if let Some(text) = &args.density {
        return Ok(Some(cvd::geom::density::Expr::parse(text)?.at_vertices(mesh, text)?));
    }
    let Some(path) = &args.density_file else { return Ok(None) };
    let values = cvd_io::read_values(path)?;
    if values.len() != mesh.vertices.len() {
        return Err(cvd::Error::InvalidInput(format!(
            "{}: {} density values for {} mesh vertices",
            path.display(),
            values.len(),
            mesh.vertices.len()
        )));
    }
    Ok(Some(values))
}

/// The power weights the arguments give, if any: one per site.
fn weights(args: &RunArgs, n_sites: usize) -> cvd::Result<Option<Vec<f64>>> {
    if let Some(path) = &args.radii {
        let radii = per_site(path, "radii", n_sites)?;
        return cvd::diagram::particles::radii_weights(&radii)
            .map(Some)
            .map_err(|e| cvd::Error::InvalidInput(format!("{}: {e}", path.display())));
    }
    let Some(path) = &args.weights else { return Ok(None) };
    if args.iterations > 0 && !args.transports() {
        return Err(cvd::Error::InvalidInput(
            "--weights with --iterations: CVT iterations keep power weights only with --transport \
             (the capacity-constrained CVT)"
                .into(),
        ));
    }
    per_site(path, "weights", n_sites).map(Some)
}

/// One value per site from `path`, the count checked.
pub fn per_site(path: &Path, what: &str, n_sites: usize) -> cvd::Result<Vec<f64>> {
    let values = cvd_io::read_values(path)?;
    if values.len() != n_sites {
        return Err(cvd::Error::InvalidInput(format!(
            "{}: {} {what} for {n_sites} sites",
            path.display(),
            values.len()
        )));
    }
    Ok(values)
}

/// The periodic box of `--periodic` / `--box`.
pub(crate) fn periodic_box(args: &RunArgs) -> cvd::Result<PeriodicBox> {
    let refuse = |what: &str| Err(cvd::Error::InvalidInput(format!("--periodic: {what}")));
    let given = [
        (args.mesh.is_some(), "--mesh"),
        (args.surface.is_some(), "--surface"),
        (args.density.is_some() || args.density_file.is_some(), "a density"),
        (args.pieces, "--pieces"),
    ];
    if let Some((_, what)) = given.iter().find(|g| g.0) {
        return refuse(&format!("{what} is not available in a periodic box yet"));
    }
    let periodic = periodic_axes(&args.periodic_axes)?;
    let domain = match (&args.periodic_box, &args.tilt, &args.lattice) {
        (_, _, Some(v)) if v.len() == 9 => {
            let origin = match &args.origin {
                Some(o) if o.len() == 3 => [o[0], o[1], o[2]],
                Some(o) => return refuse(&format!("--origin takes three numbers, X,Y,Z, not {}", o.len())),
                None => [0.0; 3],
            };
            PeriodicBox::triclinic(origin, [[v[0], v[1], v[2]], [v[3], v[4], v[5]], [v[6], v[7], v[8]]])
        }
        (_, _, Some(v)) => {
            refuse(&format!("--lattice takes nine numbers, AX,AY,AZ,BX,BY,BZ,CX,CY,CZ, not {}", v.len()))
        }
        (Some(c), _, _) if c.len() != 6 => {
            refuse(&format!("--box takes six numbers, X0,Y0,Z0,X1,Y1,Z1, not {}", c.len()))
        }
        (Some(_), Some(t), _) if t.len() != 3 => {
            refuse(&format!("--tilt takes three numbers, XY,XZ,YZ, not {}", t.len()))
        }
        (Some(c), Some(t), _) => PeriodicBox::lammps([c[0], c[1], c[2]], [c[3], c[4], c[5]], [t[0], t[1], t[2]]),
        (Some(c), None, _) => PeriodicBox::new([c[0], c[1], c[2]], [c[3], c[4], c[5]]),
        (None, _, _) if args.model == "cube" => Ok(PeriodicBox::unit()),
        (None, _, _) => refuse(&format!(
            "give the box (--box X0,Y0,Z0,X1,Y1,Z1, or --lattice), or --model cube for the unit cube, not --model {}",
            args.model
        )),
    }?;
    Ok(domain.with_periodic(periodic))
}

/// The axes `--periodic-axes` names: letters of `xyz` or `abc`, each at
/// most once.
fn periodic_axes(text: &str) -> cvd::Result<[bool; 3]> {
    let mut axes = [false; 3];
    for c in text.chars() {
        let a = match c.to_ascii_lowercase() {
            'x' | 'a' => 0,
            'y' | 'b' => 1,
            'z' | 'c' => 2,
            _ => {
                return Err(cvd::Error::InvalidInput(format!(
                    "--periodic-axes {text:?}: expected letters of xyz (or abc), not {c:?}"
                )))
            }
        };
        if axes[a] {
            return Err(cvd::Error::InvalidInput(format!("--periodic-axes {text:?}: {c:?} twice")));
        }
        axes[a] = true;
    }
    Ok(axes)
}

#[cfg(test)]
mod tests {
    use super::{natural_key, periodic_axes};

    #[test]
    fn periodic_axes_are_letters_of_xyz_or_abc() {
        assert_eq!(periodic_axes("xyz").unwrap(), [true; 3]);
        assert_eq!(periodic_axes("xy").unwrap(), [true, true, false]);
        assert_eq!(periodic_axes("CA").unwrap(), [true, false, true]);
        assert_eq!(periodic_axes("").unwrap(), [false; 3]);
        assert!(periodic_axes("xx").unwrap_err().to_string().contains("twice"));
        assert!(periodic_axes("xw").unwrap_err().to_string().contains("'w'"));
    }

    #[test]
    fn numbers_in_names_compare_as_numbers() {
        let mut names = ["joint_100k.mesh", "joint_31k.mesh", "joint_8k.mesh", "joint.mesh"];
        names.sort_by_key(|n| natural_key(n));
        assert_eq!(names, ["joint.mesh", "joint_8k.mesh", "joint_31k.mesh", "joint_100k.mesh"]);
    }
}
