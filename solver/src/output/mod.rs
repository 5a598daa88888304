//! What a run writes and prints: the output series (`series`), the run's `Summary`
//! (`summary`), and the progress bar and the notes of a long setup (`progress`).

pub mod progress;
pub mod series;
pub mod summary;
