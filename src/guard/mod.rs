//! What the command adds to the library's guards (`eprop::guard`): plausibility warnings and the
//! non-finite watch (`plausible`), and the signal handler, whose flag a command hands its
//! simulations as a `StopToken` (`signals`).

pub(crate) mod plausible;
pub(crate) mod signals;
