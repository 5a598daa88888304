//! Stopping a run on SIGTERM, SIGINT or SIGHUP without losing a step.
//!
//! `install` routes the signals to a flag (the handler does nothing else) and returns a
//! `StopToken` on it: the command hands the token to its simulation (`Simulation::set_stop`),
//! which reads it once per step, and the processes of a job agree on it in the step's max
//! reduction, so every process stops after the same step, which is written and flushed. A
//! second SIGINT (Ctrl-C twice) ends the process at once.

use eprop::simulate::StopToken;
use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
use std::sync::atomic::{AtomicBool, AtomicUsize};
use std::sync::{Arc, OnceLock};

/// The last signal received (0: none): the handlers are the process's, installed once.
static RECEIVED: OnceLock<Arc<AtomicUsize>> = OnceLock::new();

/// Routes SIGTERM, SIGINT and SIGHUP to the flag (signal-hook: the handler only stores the
/// signal's number) and returns a token on it. A second SIGINT ends the process at once with
/// status 130.
pub fn install() -> StopToken {
    let received = RECEIVED.get_or_init(|| {
        let received = Arc::new(AtomicUsize::new(0));
        let interrupted = Arc::new(AtomicBool::new(false));
        // the order matters: the exit on a second SIGINT checks the flag the first one set
        let _ = signal_hook::flag::register_conditional_shutdown(SIGINT, 128 + SIGINT, interrupted.clone());
        let _ = signal_hook::flag::register(SIGINT, interrupted);
        for sig in [SIGTERM, SIGINT, SIGHUP] {
            let _ = signal_hook::flag::register_usize(sig, received.clone(), sig as usize);
        }
        received
    });
    StopToken::from_flag(received.clone())
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
        let token = install();
        assert_eq!(token.requested(), 0);
        // SAFETY: raising a signal whose handler was installed above.
        unsafe { libc::raise(libc::SIGHUP) };
        assert_eq!(token.requested(), libc::SIGHUP);
        assert_eq!(name(token.requested()), "SIGHUP");
        // a token made before the signal sees it too; a simulation's own token does not
        assert_eq!(install().requested(), libc::SIGHUP);
        assert_eq!(StopToken::new().requested(), 0);
        token.request(0);
    }
}
