//! The discretization: the median dual of the mesh (`geometry`: S_ij, V_i, A_i), the CSR
//! operators of both schemes and their kernels (`operator`), the constitutive tensors per
//! node (`material`), and the mesh-quality report of the compact operator (`quality`: which
//! cells make it stiff).

pub mod geometry;
pub mod material;
pub mod operator;
pub mod quality;
