//! What keeps a run safe: output claims, the writer lock and agreed exit statuses (`safety`),
//! checked counts and the output budget (`limits`), and the record of inverted cells and nodes
//! inside tools with the warning when the mesh folds (`fold`). The command adds the plausibility
//! warnings and the signal handler (the `eprop` binary's `guard`).

pub mod fold;
pub mod limits;
pub mod safety;
