//! Starting a command on one process or on every process of an MPI job, the job's error
//! policy, and the distributed build of a simulation (the parts scattered, then each
//! process's geometry and operator).
//!
//! The policy: an error every process knows (a bad scenario or mesh, found by rank 0 before
//! the parts were sent and sent to all; or one the processes agreed on, `safety::Agreed`: a
//! stop by a signal, a failed write, a non-finite state) is printed once and every process
//! exits with its status; an error on one process prints its message with its rank and ends
//! every process (MPI_Abort), so a batch job never hangs.

use crate::comm::Mpi;
use crate::diagnostics::peak_rss;
use crate::parts::{self, Collective, GlobalSizes, ReportedElsewhere};
use crate::safety::{Agreed, EXIT_ERROR, EXIT_STOPPED};
use crate::scatter::Halo;
use crate::scenario::Setup;
use crate::solver::Simulation;
use anyhow::{bail, Result};
use mpi::topology::{Communicator, SimpleCommunicator};

/// True when started by an MPI launcher.
pub fn under_mpirun() -> bool {
    ["OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK", "MPI_LOCALNRANKS"]
        .iter()
        .any(|v| std::env::var_os(v).is_some())
}

/// True on the process that prints (rank 0, or the only one).
pub fn is_root(world: Option<&SimpleCommunicator>) -> bool {
    world.is_none_or(|w| w.rank() == 0)
}

/// Runs `body` on this process alone (`None`), or, under mpirun, on every process with the
/// world communicator and the job's error policy: under MPI an error never returns here, the
/// process exits (or the job is aborted) as the policy says.
pub fn launch<T>(body: impl FnOnce(Option<SimpleCommunicator>) -> Result<T>) -> Result<T> {
    if !under_mpirun() {
        return body(None);
    }
    let Some(universe) = mpi::initialize() else {
        bail!("MPI could not be initialised");
    };
    let world = universe.world();
    let (rank, size) = (world.rank() as usize, world.size() as usize);
    let result = body(Some(world));
    let err = match result {
        Ok(v) => return Ok(v),
        Err(e) => e,
    };
    let status = match ending(&err, rank, size) {
        Ending::Quiet(status) => status,
        Ending::Once(msg, status) => {
            eprintln!("{msg}");
            status
        }
        Ending::Abort(msg) => {
            eprintln!("{msg}");
            universe.world().abort(1)
        }
    };
    drop(universe);
    std::process::exit(status.into())
}

/// How a process of a job ends after an error.
#[derive(Debug, PartialEq)]
enum Ending {
    /// Rank 0 printed it; exit with this status.
    Quiet(u8),
    /// Printed by this process, then every process exits with this status.
    Once(String, u8),
    /// Printed by this process, which ends the whole job.
    Abort(String),
}

fn ending(e: &anyhow::Error, rank: usize, size: usize) -> Ending {
    if let Some(a) = e.downcast_ref::<Agreed>() {
        // a stop says so itself ("stopped by SIGTERM ...")
        let word = if a.status == EXIT_STOPPED { "" } else { "error: " };
        match rank {
            0 => Ending::Once(format!("{word}{}", a.message), a.status),
            _ => Ending::Quiet(a.status),
        }
    } else if e.is::<ReportedElsewhere>() {
        Ending::Quiet(EXIT_ERROR)
    } else if e.is::<Collective>() {
        match rank {
            0 => Ending::Once(format!("error: {e:#}"), EXIT_ERROR),
            _ => Ending::Quiet(EXIT_ERROR),
        }
    } else if size > 1 {
        Ending::Abort(format!("error (rank {rank} of {size}): {e:#}"))
    } else {
        Ending::Abort(format!("error: {e:#}"))
    }
}

/// A distributed simulation ready to step.
pub struct Built {
    pub sim: Simulation,
    pub sizes: GlobalSizes,
    /// A communicator of the same processes for collective output.
    pub io_comm: SimpleCommunicator,
    /// Peak resident memory of rank 0 once the parts were sent (0 elsewhere).
    pub rank0_scatter_peak: u64,
}

/// Rank 0 makes the whole-mesh setup and sends every process its part (`parts::scatter`);
/// every process builds its simulation.
pub fn build_mpi(world: SimpleCommunicator, make_setup: impl FnOnce() -> Result<Setup>) -> Result<Built> {
    let rank = world.rank() as usize;
    let io_comm = world.duplicate();
    let halo_comm = world.duplicate();
    let (mine, global) = parts::scatter(&world, make_setup)?;
    let rank0_scatter_peak = if rank == 0 { peak_rss() } else { 0 };
    tracing::info!(
        "rank {rank}: part received ({} owned, {} halo nodes); building geometry and operator",
        mine.plan.numbering.n_owned,
        mine.plan.n_halo()
    );
    let halo = Halo::new(mine.plan.pattern.clone(), halo_comm);
    let sim = Simulation::new_with(mine.setup, Box::new(Mpi::new(world)), halo, mine.plan, global)?;
    Ok(Built {
        sim,
        sizes: mine.sizes,
        io_comm,
        rank0_scatter_peak,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use anyhow::anyhow;

    #[test]
    fn an_error_ends_a_job_by_its_kind() {
        let collective = || anyhow::Error::from(Collective("bad.toml: no mesh".into()));
        assert_eq!(
            ending(&collective(), 0, 3),
            Ending::Once("error: bad.toml: no mesh".into(), 1)
        );
        assert_eq!(ending(&collective(), 2, 3), Ending::Quiet(1));
        assert_eq!(ending(&ReportedElsewhere.into(), 1, 3), Ending::Quiet(1));
        let stopped = || Agreed::error(EXIT_STOPPED, "stopped by SIGTERM after step 3");
        assert_eq!(
            ending(&stopped(), 0, 2),
            Ending::Once("stopped by SIGTERM after step 3".into(), 3)
        );
        assert_eq!(ending(&stopped(), 1, 2), Ending::Quiet(3));
        let full = Agreed::error(crate::safety::EXIT_WRITE, "out.h5: disk full");
        assert_eq!(ending(&full, 0, 2), Ending::Once("error: out.h5: disk full".into(), 4));
        assert_eq!(
            ending(&anyhow!("out.h5: write failed"), 1, 3),
            Ending::Abort("error (rank 1 of 3): out.h5: write failed".into())
        );
        assert_eq!(ending(&anyhow!("x"), 0, 1), Ending::Abort("error: x".into()));
    }
}
