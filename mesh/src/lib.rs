//! eprop-mesh: the in-memory mesh every reader produces and the solver reads, with what needs
//! nothing but the mesh itself: geometry kernels (`geom`), the validation pass every mesh read
//! goes through (`validate`), face and component walks (`mesh`), and the box and cylinder
//! generators (`generate`). No file formats, no HDF5, no MPI: `eprop-io` reads and writes files
//! and re-exports all of this under its own paths.

pub mod generate;
pub mod geom;
pub mod mesh;
pub mod validate;

pub use mesh::{CellKind, Mesh};
pub use validate::{validate, ReadOptions};
