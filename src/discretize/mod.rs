//! The discretization: the median dual of the mesh (`geometry`: S_ij, V_i, A_i), the CSR
//! operators of both schemes and their kernels (`operator`), and the constitutive tensors
//! per node (`material`).

pub mod geometry;
pub mod material;
pub mod operator;
