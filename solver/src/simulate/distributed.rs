//! The distributed build of a simulation: rank 0 scatters the parts (`distribute::parts`),
//! then every process builds its geometry and operator.

use crate::config::Setup;
use crate::diagnostics::peak_rss;
use crate::distribute::comm::Comm;
use crate::distribute::parts::{self, GlobalSizes, Share};
use crate::simulate::Simulation;
use anyhow::Result;

/// A distributed simulation ready to step.
pub struct Built {
    pub sim: Simulation,
    pub sizes: GlobalSizes,
    /// Peak resident memory of rank 0 once the parts were sent (0 elsewhere).
    pub rank0_scatter_peak: u64,
}

/// Every process of `world` calls: rank 0 makes the whole-mesh setup and sends every process
/// its part (`parts::share`); every process builds its simulation, on communicators of its own.
pub fn build_mpi(world: &dyn Comm, make_setup: impl FnOnce() -> Result<Setup>) -> Result<Built> {
    let rank = world.rank();
    let Share {
        part: mut mine,
        global,
        comm,
        halo,
    } = parts::share(world, make_setup)?;
    let rank0_scatter_peak = if rank == 0 { peak_rss() } else { 0 };
    tracing::info!(
        "rank {rank}: part received ({} owned, {} halo nodes); building geometry and operator",
        mine.plan.numbering.n_owned,
        mine.plan.n_halo()
    );
    let rows = mine.rows.take();
    let mut sim = Simulation::new_with(mine.setup, comm, halo, mine.plan, global)?;
    sim.rows = rows;
    Ok(Built {
        sim,
        sizes: mine.sizes,
        rank0_scatter_peak,
    })
}
