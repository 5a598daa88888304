//! The progress bar of a run: on stderr, on rank 0, when a person watches (stderr is a
//! terminal) and the run is not `--quiet`; redrawn at most five times a second.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::time::{Duration, Instant};

const TEMPLATE: &str = "  [{bar:30}] step {pos}/{len} {per_sec} ETA {eta} max|v| {msg}";

pub struct Progress {
    bar: Option<ProgressBar>,
    last: Instant,
}

impl Progress {
    /// A bar from step `from` to step `to`, drawn when `show` and stderr is a terminal.
    pub fn new(show: bool, from: u64, to: u64) -> Progress {
        let show = show && std::io::IsTerminal::is_terminal(&std::io::stderr());
        Progress {
            bar: show.then(|| bar(from, to, ProgressDrawTarget::stderr())),
            last: Instant::now(),
        }
    }

    /// The state after a step.
    pub fn update(&mut self, step: u64, max_speed: f64) {
        if let Some(b) = &self.bar {
            if self.last.elapsed() > Duration::from_millis(200) {
                b.set_position(step);
                b.set_message(format!("{max_speed:.2e}"));
                self.last = Instant::now();
            }
        }
    }

    /// Prints a line on stderr above the bar.
    pub fn println(&self, line: &str) {
        match &self.bar {
            Some(b) => b.println(line),
            None => eprintln!("{line}"),
        }
    }

    /// Removes the bar.
    pub fn finish(self) {
        if let Some(b) = self.bar {
            b.finish_and_clear();
        }
    }
}

fn bar(from: u64, to: u64, target: ProgressDrawTarget) -> ProgressBar {
    let style = ProgressStyle::with_template(TEMPLATE)
        .expect("the progress template is valid")
        .progress_chars("#-");
    let b = ProgressBar::with_draw_target(Some(to), target).with_style(style);
    b.set_position(from);
    b.reset_eta();
    b
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_bar_follows_the_steps() {
        let b = bar(5, 100, ProgressDrawTarget::hidden());
        assert_eq!((b.position(), b.length()), (5, Some(100)));
        let mut p = Progress {
            bar: Some(b.clone()),
            last: Instant::now() - Duration::from_secs(1),
        };
        p.update(17, 1.5e-3);
        assert_eq!(b.position(), 17);
        assert_eq!(b.message(), "1.50e-3");
        p.update(18, 0.0); // too soon to redraw
        assert_eq!(b.position(), 17);
        p.finish();
        assert!(b.is_finished());
        // no terminal under the test harness: nothing drawn, nothing to update
        let mut quiet = Progress::new(true, 0, 10);
        assert!(quiet.bar.is_none() || std::io::IsTerminal::is_terminal(&std::io::stderr()));
        quiet.update(3, 1.0);
        Progress::new(false, 0, 10).finish();
    }
}
