//! What keeps a run safe: output claims, the writer lock and agreed exit statuses (`safety`),
//! checked counts and the output budget (`limits`), plausibility warnings and the non-finite
//! watch (`plausible`), the record of inverted cells and nodes inside tools with the warning
//! when the mesh folds (`fold`), and the signal handler, whose flag a command hands its simulations as
//! a `StopToken` (`signals`).

pub(crate) mod fold;
pub(crate) mod limits;
pub(crate) mod plausible;
pub mod safety;
pub(crate) mod signals;
