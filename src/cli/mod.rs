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

/// The command's log on stderr: the notes of a long setup (`output::progress::Notes`, shown
/// while a run holds its `SetupNotes`), and with `verbose` 1, 2 or 3 (`-v`, `-vv`, `-vvv`) the
/// library's events from info, debug or trace on.
pub fn log_to_stderr(verbose: u8) {
    use eprop::output::progress::{Notes, SETUP};
    use tracing::level_filters::LevelFilter;
    use tracing_subscriber::filter::filter_fn;
    use tracing_subscriber::prelude::*;
    let notes = Notes::default().with_filter(filter_fn(|m| m.target() == SETUP).with_max_level_hint(LevelFilter::INFO));
    let level = match verbose {
        0 => None,
        1 => Some(LevelFilter::INFO),
        2 => Some(LevelFilter::DEBUG),
        _ => Some(LevelFilter::TRACE),
    };
    let log = level.map(|level| {
        tracing_subscriber::fmt::layer()
            .with_writer(std::io::stderr)
            .with_target(false)
            .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
            .with_timer(tracing_subscriber::fmt::time::uptime())
            .with_filter(filter_fn(move |m| m.target() != SETUP && *m.level() <= level).with_max_level_hint(level))
    });
    tracing_subscriber::registry().with(notes).with(log).init();
}
