//! Distribution over processes, and every use of MPI: the communicator (`comm`: collectives),
//! the halo exchange and the block scatter (`halo`), per-node fields in local numbering
//! (`field`), each process's part of the scenario (`parts`) and its wire form (`wire`), and the
//! launch policy (`launch`: one process or mpirun, errors and exit statuses).

pub mod comm;
pub mod field;
pub mod halo;
pub mod launch;
pub(crate) mod parts;
pub(crate) mod wire;
