//! The progress of a run on stderr, on rank 0, unless `--quiet`: a bar redrawn at most five
//! times a second when stderr is a terminal; otherwise (a batch job's log) a line every
//! `--progress-every` steps or seconds (default every 10 s).

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tracing::field::{Field, Visit};
use tracing::span::{Attributes, Id};
use tracing::{Event, Subscriber};
use tracing_subscriber::layer::{Context, Layer};
use tracing_subscriber::registry::LookupSpan;

/// The target of the setup notes: the library says what a long setup does (auto's trial
/// steps, the multigrid hierarchy) as `tracing` events of this target,
/// `tracing::info!(target: "eprop::setup", ...)`; `Notes` renders them.
pub const SETUP: &str = "eprop::setup";

/// A setup that has run this long prints its notes; a shorter one prints nothing.
pub(crate) const SETUP_QUIET_FOR: f64 = 2.0;

/// The setup notes, on while this lives (`on(Some(start))`: the setup's start; `on(None)`
/// leaves them off) and off once it is dropped, an error's early return included: a span of
/// target `SETUP` entered on this thread, within which `Notes` renders the notes. A run
/// holds it while it sets up, on the process that prints its progress (rank 0, without -q).
pub struct SetupNotes {
    _span: Option<tracing::span::EnteredSpan>,
}

impl SetupNotes {
    pub fn on(start: Option<Instant>) -> SetupNotes {
        SetupNotes {
            _span: start.map(|t0| {
                let since_ns = t0.elapsed().as_nanos().min(u64::MAX as u128) as u64;
                tracing::info_span!(target: SETUP, "setup", since_ns).entered()
            }),
        }
    }
}

/// Where a setup span started (a span extension).
struct Start(Instant);

/// A `tracing` layer that renders the setup notes: a note within a `SetupNotes` span goes to
/// stderr as `  setup 12.4s: <note>` once the setup has run `SETUP_QUIET_FOR` seconds (a
/// batch job's log is otherwise silent until the first step).
pub struct Notes {
    write: Arc<dyn Fn(&str) + Send + Sync>,
}

impl Default for Notes {
    fn default() -> Notes {
        Notes::to(|line| eprintln!("{line}"))
    }
}

impl Notes {
    /// The notes, each line given to `write`.
    pub fn to(write: impl Fn(&str) + Send + Sync + 'static) -> Notes {
        Notes { write: Arc::new(write) }
    }
}

/// A field of an event or span: the message, or a count of nanoseconds.
#[derive(Default)]
struct Fields {
    message: String,
    since_ns: Option<u64>,
}

impl Visit for Fields {
    fn record_u64(&mut self, field: &Field, value: u64) {
        if field.name() == "since_ns" {
            self.since_ns = Some(value);
        }
    }
    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        if field.name() == "message" {
            self.message = format!("{value:?}");
        }
    }
}

impl<S: Subscriber + for<'a> LookupSpan<'a>> Layer<S> for Notes {
    fn on_new_span(&self, attrs: &Attributes<'_>, id: &Id, ctx: Context<'_, S>) {
        if attrs.metadata().target() != SETUP {
            return;
        }
        let mut f = Fields::default();
        attrs.record(&mut f);
        let now = Instant::now();
        let start = now
            .checked_sub(Duration::from_nanos(f.since_ns.unwrap_or(0)))
            .unwrap_or(now);
        if let Some(span) = ctx.span(id) {
            span.extensions_mut().insert(Start(start));
        }
    }

    fn on_event(&self, event: &Event<'_>, ctx: Context<'_, S>) {
        if event.metadata().target() != SETUP {
            return;
        }
        let start = ctx
            .event_scope(event)
            .and_then(|mut scope| scope.find_map(|span| span.extensions().get::<Start>().map(|s| s.0)));
        let Some(t0) = start else {
            return;
        };
        let s = t0.elapsed().as_secs_f64();
        if s >= SETUP_QUIET_FOR {
            let mut f = Fields::default();
            event.record(&mut f);
            (self.write)(&format!("  setup {}: {}", clock(s), f.message));
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
    fn setup_notes_show_within_a_long_setup_only() {
        use std::sync::Mutex;
        use tracing_subscriber::prelude::*;
        let lines = Arc::new(Mutex::new(Vec::<String>::new()));
        let seen = lines.clone();
        let notes = Notes::to(move |l| seen.lock().unwrap().push(l.to_string()));
        let subscriber = tracing_subscriber::registry().with(notes);
        tracing::subscriber::with_default(subscriber, || {
            let note = |k: u32| tracing::info!(target: SETUP, "note {k} of {}", "the setup");
            note(1); // no setup
            {
                let _on = SetupNotes::on(Some(Instant::now()));
                note(2); // a setup shorter than 2 s
                tracing::info!("not a note");
            }
            {
                let _off = SetupNotes::on(None);
                note(3);
            }
            let _on = SetupNotes::on(Instant::now().checked_sub(Duration::from_secs(75)));
            tracing::info!("not a note");
            note(4);
        });
        assert_eq!(*lines.lock().unwrap(), ["  setup 1m15s: note 4 of the setup"]);
    }

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
