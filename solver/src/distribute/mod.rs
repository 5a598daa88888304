//! Distribution over processes, and every use of MPI: the communicator (`comm`: collectives),
//! the halo exchange and the block scatter (`halo`), per-node fields in local numbering
//! (`field`), each process's part of the scenario (`parts`, sent as postcard bytes of its serde
//! form, `config::wire`; `ptscotch`: PT-Scotch's parallel split of the node graph; `slabs`: a VTKHDF mesh read, graphed, split and moved in slabs), and the launch policy (`launch`: one process or mpirun, MPI's start,
//! errors and exit statuses). Nothing outside this module names MPI: the rest of the crate
//! holds a `comm::Comm`.

pub mod checks;
pub mod comm;
pub mod field;
pub mod halo;
pub mod launch;
pub mod parts;
pub mod ptscotch;
pub mod slabs;
