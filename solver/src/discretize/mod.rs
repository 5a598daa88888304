//! The discretization: the median dual of the mesh (`geometry`: S_ij, V_i, A_i), the CSR
//! operators of both schemes and their kernels (`operator`), and the mesh-quality report of
//! the compact operator (`quality`: which cells make it stiff). The tissues it reads are
//! `config::tissue`'s.

pub mod geometry;
pub mod operator;
pub mod quality;
