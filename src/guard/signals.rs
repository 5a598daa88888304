//! Stopping a run on SIGTERM, SIGINT or SIGHUP without losing a step.
//!
//! `install` records the signal in an atomic flag (the handler does nothing else); the
//! simulation reads it once per step (`pending`) and the processes of a job agree on it in the
//! step's max reduction, so every process stops after the same step, which is written and
//! flushed. A second SIGINT (Ctrl-C twice) ends the process at once.

use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, OnceLock};

/// The last signal received (0: none).
struct Flags {
    received: Arc<AtomicUsize>,
}

static FLAGS: OnceLock<Flags> = OnceLock::new();

/// Routes SIGTERM, SIGINT and SIGHUP to the flag (signal-hook: the handler only stores the
/// signal's number). A second SIGINT ends the process at once with status 130.
pub fn install() {
    FLAGS.get_or_init(|| {
        let received = Arc::new(AtomicUsize::new(0));
        let interrupted = Arc::new(AtomicBool::new(false));
        // the order matters: the exit on a second SIGINT checks the flag the first one set
        let _ = signal_hook::flag::register_conditional_shutdown(SIGINT, 128 + SIGINT, interrupted.clone());
        let _ = signal_hook::flag::register(SIGINT, interrupted);
        for sig in [SIGTERM, SIGINT, SIGHUP] {
            let _ = signal_hook::flag::register_usize(sig, received.clone(), sig as usize);
        }
        Flags { received }
    });
}

/// The signal received since `install` (0: none).
pub fn pending() -> i32 {
    FLAGS.get().map_or(0, |f| f.received.load(Ordering::SeqCst) as i32)
}

/// The name of a signal number.
pub fn name(sig: i32) -> &'static str {
    match sig {
        SIGTERM => "SIGTERM",
        SIGINT => "SIGINT",
        SIGHUP => "SIGHUP",
        _ => "a signal",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_signal_is_recorded_not_fatal() {
        install();
        assert_eq!(pending(), 0);
        // SAFETY: raising a signal whose handler was installed above.
        unsafe { libc::raise(libc::SIGHUP) };
        assert_eq!(pending(), libc::SIGHUP);
        assert_eq!(name(pending()), "SIGHUP");
        FLAGS.get().unwrap().received.store(0, Ordering::SeqCst);
    }
}
