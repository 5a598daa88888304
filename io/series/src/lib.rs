//! eprop-series: the output series of a run, a VTKHDF time series in one HDF5 file that
//! ParaView and h5py open (`vtkhdf`), written collectively under MPI, with every HDF5 call's
//! outcome agreed by all writers (`outcome`: also free space and human sizes). The mesh
//! readers and writers, which need neither HDF5 nor MPI, are in `eprop-io`.

pub mod outcome;
pub mod vtkhdf;
