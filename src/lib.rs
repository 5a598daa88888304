//! eprop: soft-tissue deformation by Poisson energy propagation.
//!
//! A force on an organ becomes a directional energy source; the energy spreads through the
//! volume by a vector Poisson equation, discretised with edge-based median-dual finite
//! volumes and stepped with explicit Euler (or RKL2 super-steps, or implicit TR-BDF2); the
//! propagated potential drives damped nodal dynamics. The model is fixed in MODEL.md;
//! ARCHITECTURE.md maps the code.

pub mod bench;
pub mod comm;
pub mod contact;
mod diagnostics;
mod drive;
pub mod field;
pub mod geometry;
pub mod inspect;
pub mod integrate;
pub mod launch;
pub mod limits;
pub mod material;
pub mod operator;
mod parts;
pub mod plausible;
mod progress;
pub mod propagation;
pub mod run;
pub mod safety;
pub mod scatter;
pub mod scenario;
mod series;
pub mod serve;
pub mod signals;
pub mod solver;
pub mod summary;
pub mod tables;
#[cfg(test)]
mod testing;
pub mod wavefront;
mod wire;

pub use eprop_io as io;
