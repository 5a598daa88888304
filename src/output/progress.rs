//! The progress of a run on stderr, on rank 0, unless `--quiet`: a bar redrawn at most five
//! times a second when stderr is a terminal; otherwise (a batch job's log) a line every
//! `--progress-every` steps or seconds (default every 10 s).

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// A setup that has run this long prints notes of what it does (`setup_note`); a shorter one
/// prints nothing.
pub const SETUP_QUIET_FOR: f64 = 2.0;

static SETUP: Mutex<Option<Instant>> = Mutex::new(None);

fn setup_notes(start: Option<Instant>) {
    *SETUP.lock().unwrap_or_else(|e| e.into_inner()) = start;
}

/// The setup notes, on while this lives (`on(Some(start))`: the setup's start; `on(None)`
/// leaves them off) and off once it is dropped, an error's early return included. A run
/// holds it while it sets up, on the process that prints its progress (rank 0, without -q).
pub struct SetupNotes;

impl SetupNotes {
    pub fn on(start: Option<Instant>) -> SetupNotes {
        setup_notes(start);
        SetupNotes
    }
}

impl Drop for SetupNotes {
    fn drop(&mut self) {
        setup_notes(None);
    }
}

/// A note on stderr about a long setup (a batch job's log is otherwise silent until the first
/// step): `  setup 12.4s: <note>`, when the notes are on and the setup has run for
/// `SETUP_QUIET_FOR` seconds.
pub fn setup_note(note: impl FnOnce() -> String) {
    let start = *SETUP.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(t0) = start {
        let s = t0.elapsed().as_secs_f64();
        if s >= SETUP_QUIET_FOR {
            eprintln!("  setup {}: {}", clock(s), note());
        }
    }
}

const TEMPLATE: &str = "  [{bar:30}] step {pos}/{len} {per_sec} ETA {eta} max|v| {msg}";

/// How often a run without a terminal prints a progress line (`--progress-every`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Every {
    Steps(u64),
    Seconds(f64),
    Never,
}

impl Default for Every {
    fn default() -> Every {
        Every::Seconds(10.0)
    }
}

impl std::str::FromStr for Every {
    type Err = String;
    /// `N` steps, `Ts` seconds, `Tm` minutes, or `0` / `off` (never).
    fn from_str(s: &str) -> Result<Every, String> {
        let t = s.trim();
        let fix = "fix: give a number of steps (100), seconds (30s), minutes (5m) or 0 (no lines)";
        if t == "0" || t == "off" {
            return Ok(Every::Never);
        }
        let secs = |v: &str, unit: f64| match v.parse::<f64>() {
            Ok(x) if x.is_finite() && x > 0.0 && x * unit <= 1e9 => Ok(Every::Seconds(x * unit)),
            _ => Err(format!("`{s}`: not a positive time; {fix}")),
        };
        if let Some(v) = t.strip_suffix('s') {
            return secs(v, 1.0);
        }
        if let Some(v) = t.strip_suffix('m') {
            return secs(v, 60.0);
        }
        match t.parse::<u64>() {
            Ok(n) => Ok(Every::Steps(n)),
            Err(_) => Err(format!("`{s}`: not a count of steps or a time; {fix}")),
        }
    }
}

/// The lines of a run without a terminal.
struct Lines {
    every: Every,
    from: u64,
    to: u64,
    start: Instant,
    last: Instant,
}

impl Lines {
    /// Whether the state after `step` gets a line at `now`.
    fn due(&mut self, step: u64, now: Instant) -> bool {
        let due = match self.every {
            Every::Steps(n) => step.is_multiple_of(n.max(1)),
            Every::Seconds(t) => now.duration_since(self.last).as_secs_f64() >= t,
            Every::Never => false,
        };
        if due {
            self.last = now;
        }
        due
    }

    fn line(&self, step: u64, max_speed: f64, now: Instant) -> String {
        let secs = now.duration_since(self.start).as_secs_f64();
        let done = step.saturating_sub(self.from);
        let rate = if secs > 0.0 { done as f64 / secs } else { 0.0 };
        let pct = if self.to > 0 {
            100.0 * step as f64 / self.to as f64
        } else {
            100.0
        };
        let eta = if rate > 0.0 {
            clock(self.to.saturating_sub(step) as f64 / rate)
        } else {
            "?".into()
        };
        // three significant digits
        let rate = match rate {
            r if r >= 100.0 => format!("{r:.0}"),
            r if r >= 1.0 => format!("{r:.2}"),
            r => format!("{r:.3e}"),
        };
        format!(
            "progress: step {step}/{} ({pct:.1} %), {} elapsed, {rate} steps/s, ETA {eta}, max|v| {max_speed:.2e}",
            self.to,
            clock(secs)
        )
    }
}

/// Seconds as 1h02m, 4m05s or 7.3s.
fn clock(s: f64) -> String {
    if !s.is_finite() {
        return "?".into();
    }
    let whole = s.round() as u64;
    if whole >= 3600 {
        format!("{}h{:02}m", whole / 3600, whole % 3600 / 60)
    } else if whole >= 60 {
        format!("{}m{:02}s", whole / 60, whole % 60)
    } else {
        format!("{s:.1}s")
    }
}

pub struct Progress {
    bar: Option<ProgressBar>,
    lines: Option<Lines>,
    last: Instant,
}

impl Progress {
    /// Progress from step `from` to step `to` when `show`: a bar when stderr is a terminal,
    /// else a line as often as `every` says.
    pub fn new(show: bool, from: u64, to: u64, every: Every) -> Progress {
        let tty = std::io::IsTerminal::is_terminal(&std::io::stderr());
        let now = Instant::now();
        Progress {
            bar: (show && tty).then(|| bar(from, to, ProgressDrawTarget::stderr())),
            lines: (show && !tty && every != Every::Never).then_some(Lines {
                every,
                from,
                to,
                start: now,
                last: now,
            }),
            last: now,
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
        if let Some(l) = &mut self.lines {
            let now = Instant::now();
            if l.due(step, now) {
                eprintln!("{}", l.line(step, max_speed, now));
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
            lines: None,
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
        let mut quiet = Progress::new(true, 0, 10, Every::Never);
        assert!(quiet.bar.is_none() || std::io::IsTerminal::is_terminal(&std::io::stderr()));
        assert!(quiet.lines.is_none());
        quiet.update(3, 1.0);
        Progress::new(false, 0, 10, Every::Steps(1)).finish();
    }

    #[test]
    fn lines_come_every_n_steps_or_t_seconds() {
        assert_eq!("250".parse(), Ok(Every::Steps(250)));
        assert_eq!("30s".parse(), Ok(Every::Seconds(30.0)));
        assert_eq!("0.5m".parse(), Ok(Every::Seconds(30.0)));
        assert_eq!("0".parse(), Ok(Every::Never));
        assert_eq!("off".parse(), Ok(Every::Never));
        assert_eq!(Every::default(), Every::Seconds(10.0));
        for bad in ["-3", "s", "0s", "nans", "1e99m", "ten"] {
            let e = bad.parse::<Every>().unwrap_err();
            assert!(e.contains(bad) && e.contains("fix:"), "{e}");
        }
        let t0 = Instant::now();
        let mut l = Lines {
            every: Every::Steps(3),
            from: 2,
            to: 12,
            start: t0,
            last: t0,
        };
        let due: Vec<u64> = (3..=12).filter(|&k| l.due(k, t0)).collect();
        assert_eq!(due, [3, 6, 9, 12]);
        // 4 steps in 2 s: 2 steps/s, 6 to go
        let line = l.line(6, 1.5e-3, t0 + Duration::from_secs(2));
        assert_eq!(
            line,
            "progress: step 6/12 (50.0 %), 2.0s elapsed, 2.00 steps/s, ETA 3.0s, max|v| 1.50e-3"
        );
        l.every = Every::Seconds(10.0);
        assert!(!l.due(7, t0 + Duration::from_secs(9)));
        assert!(l.due(8, t0 + Duration::from_secs(10)));
        assert!(!l.due(9, t0 + Duration::from_secs(19)));
        assert!(l.due(10, t0 + Duration::from_secs(21)));
        assert_eq!(clock(3725.0), "1h02m");
        assert_eq!(clock(245.0), "4m05s");
        assert_eq!(clock(f64::NAN), "?");
    }
}
