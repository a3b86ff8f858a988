//! The optimiser's result, shared by one process (`cvd run`) and a
//! periodic box in parts (under `mpirun`): the sites it moved, the weights
//! it found and their records; and optimal transport as both run it.

use crate::args::RunArgs;
use crate::progress::with_iterations;
use cvd::cvt::transport::{Transport, VolumeLaw};
use cvd::cvt::SiteDiagram;
use cvd_io::{CvtRecord, TransportRecord};

/// Exit status of a run whose optimal transport did not reach its
/// tolerance (its outputs written all the same).
pub const NOT_CONVERGED: u8 = 3;

/// What the optimiser gives the final diagram.
pub(crate) struct Optimised {
    /// The sites: as given, or moved by the iterations.
    pub sites: Vec<[f64; 3]>,
    /// The iterations' record.
    pub cvt: Option<CvtRecord>,
    /// The weights: `--weights`, or those optimal transport found.
    pub weights: Option<Vec<f64>>,
    /// Optimal transport's record.
    pub transport: Option<TransportRecord>,
}

/// The optimal transport the arguments ask for on `diagram`, from the
/// weights `start` (if any): the weights that give every cell its target
/// mass, with the solve's record; with `--iterations`, the
/// capacity-constrained CVT first (its moved sites and record). Prints
/// each Newton step of a single solve. `capacities`: the sites' (or, in
/// parts, this rank's rows').
pub(crate) fn transport<D: SiteDiagram>(
    args: &RunArgs,
    diagram: D,
    start: Option<&[f64]>,
    capacities: Option<Vec<f64>>,
) -> cvd::Result<Optimised> {
    if args.optimizer != cvd::cvt::Optimizer::Lloyd {
        return Err(cvd::Error::InvalidInput(
            "--transport with --optimizer lbfgs: the capacity-constrained CVT moves sites by Lloyd steps".into(),
        ));
    }
    let sites = diagram.starting_sites().to_vec();
    let speaks = diagram.comm().is_none_or(|c| c.rank() == 0);
    let mut ot = Transport::new(diagram).tolerance(args.tolerance).max_steps(args.newton_steps);
    if let Some(c) = &capacities {
        ot = ot.capacities(c);
    }
    if let Some(w) = start {
        ot = ot.start(w);
    }
    let targets = match (&args.capacities, args.volumes) {
        (Some(_), _) => "capacities".to_string(),
        (None, Some(VolumeLaw::LogNormal { mu, sigma })) => format!("lognormal:{mu},{sigma}"),
        (None, None) => "uniform".to_string(),
    };
    let (sites, cvt, run) = if args.iterations > 0 {
        let what = "capacity-constrained CVT";
        let (cvt, run) = with_iterations(what, args.iterations, |show| ot.cvt(args.iterations, show))?;
        let record = CvtRecord::of("lloyd-transport", &cvt.iterations);
        (cvt.sites, Some(record), run)
    } else {
        let mut step = 0;
        let run = ot.solve(&mut |s| {
            if s.step > 0.0 {
                step += 1;
                println!("transport: Newton step {step}: {s}");
            }
            true
        })?;
        (sites, None, run)
    };
    let record = TransportRecord::of(&targets, args.tolerance, &run);
    if !run.converged && speaks {
        eprintln!(
            "transport: the masses came within {:.2e} of their targets, not {:.0e}: {}",
            record.max_error, args.tolerance, run.stopped
        );
    }
    Ok(Optimised { sites, cvt, weights: Some(run.weights), transport: Some(record) })
}
