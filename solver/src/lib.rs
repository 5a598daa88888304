//! eprop: soft-tissue deformation by Poisson energy propagation.
//!
//! A force on an organ becomes a directional energy source; the energy spreads through the
//! volume by a vector Poisson equation, discretised with edge-based median-dual finite
//! volumes and stepped with explicit Euler (or RKL2 super-steps, or implicit TR-BDF2); the
//! propagated potential drives damped nodal dynamics. The model is fixed in docs/model.md;
//! ARCHITECTURE.md maps the code.
//!
//! The front of the library is re-exported here: a scenario is read ([`Scenario`]), resolved
//! against its mesh ([`Setup`]) and built into a [`Simulation`] on one process ([`Serial`]) or
//! on the processes of a [`Comm`] ([`build_mpi`], under [`launch`]); the simulation steps
//! (`Simulation::advance`) with its integrator (a [`Stepper`] over the [`Propagation`]), stops
//! when its [`StopToken`] asks, and writes its steps to a [`Series`] and its [`Summary`].
//! Errors that every process agrees on carry an exit status ([`Agreed`]). A live client feeds
//! `Simulation::apply_live_samples` through the wire format of [`protocol`].
//!
//! The stage modules stay public for the `eprop` command, the tests and the examples, which
//! reach further in (the operator kernels, the integrators, the halo); their items are the
//! library's inner layers, not its front.
//!
//! ```no_run
//! # fn main() -> anyhow::Result<()> {
//! let scenario = eprop::Scenario::load(std::path::Path::new("scenarios/cylinder.toml"))?;
//! let mut sim = eprop::Simulation::new(eprop::Setup::new(scenario)?)?;
//! while !sim.done() {
//!     sim.advance()?;
//! }
//! println!("{} steps, t = {}", sim.step(), sim.time());
//! # Ok(())
//! # }
//! ```

pub mod config;
pub mod diagnostics;
pub mod discretize;
pub mod distribute;
pub mod guard;
pub mod linalg;
pub mod output;
pub mod propagate;
pub mod protocol;
pub mod simulate;
#[cfg(test)]
mod testing;

pub use eprop_io as io;

pub use config::{Scenario, Setup};
pub use distribute::comm::{Comm, Serial};
pub use distribute::field::NodeField;
pub use distribute::launch::{launch, Agreed};
pub use output::series::Series;
pub use output::summary::Summary;
pub use propagate::integrate::{StepPlan, StepStats, Stepper};
pub use propagate::Propagation;
pub use simulate::distributed::build_mpi;
pub use simulate::{mesh_info, MeshInfo, Simulation, StopToken};
