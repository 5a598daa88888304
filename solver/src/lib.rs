//! eprop: soft-tissue deformation by Poisson energy propagation.
//!
//! A force on an organ becomes a directional energy source; the energy spreads through the
//! volume by a vector Poisson equation, discretised with edge-based median-dual finite
//! volumes and stepped with explicit Euler (or RKL2 super-steps, or implicit TR-BDF2); the
//! propagated potential drives damped nodal dynamics. The model is fixed in docs/model.md;
//! ARCHITECTURE.md maps the code.

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
