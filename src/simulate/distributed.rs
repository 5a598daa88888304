//! The distributed build of a simulation: rank 0 scatters the parts, then every process
//! builds its geometry and operator.

use crate::config::Setup;
use crate::diagnostics::peak_rss;
use crate::distribute::comm::Mpi;
use crate::distribute::halo::Halo;
use crate::distribute::parts::{self, GlobalSizes};
use crate::simulate::Simulation;
use anyhow::Result;
use mpi::topology::{Communicator, SimpleCommunicator};

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
