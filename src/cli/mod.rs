//! The commands: `run` (a scenario to a series), `serve` (a run fed by a client),
//! `info`/`check`/`partition`/`export-operator` (`inspect`), `bench`, `fit` (parameters fitted
//! to a measured curve).

pub mod bench;
pub(crate) mod drive;
pub mod export;
pub mod fit;
pub mod inspect;
pub mod run;
pub mod serve;
