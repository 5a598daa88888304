//! Stopping a run on SIGTERM, SIGINT or SIGHUP without losing a step.
//!
//! `install` records the signal in an atomic flag (the handler does nothing else); the
//! simulation reads it once per step (`pending`) and the processes of a job agree on it in the
//! step's max reduction, so every process stops after the same step, which is written and
//! flushed. A second SIGINT (Ctrl-C twice) ends the process at once.

use std::sync::atomic::{AtomicI32, Ordering};

static RECEIVED: AtomicI32 = AtomicI32::new(0);

extern "C" fn on_signal(sig: libc::c_int) {
    let before = RECEIVED.swap(sig, Ordering::SeqCst);
    if before == libc::SIGINT && sig == libc::SIGINT {
        // SAFETY: _exit is async-signal-safe.
        unsafe { libc::_exit(128 + sig) }
    }
}

/// Routes SIGTERM, SIGINT and SIGHUP to the flag.
pub fn install() {
    for sig in [libc::SIGTERM, libc::SIGINT, libc::SIGHUP] {
        // SAFETY: a handler that only touches an atomic (and calls _exit) is async-signal-safe;
        // the sigaction struct is zeroed and filled before use.
        unsafe {
            let mut sa: libc::sigaction = std::mem::zeroed();
            sa.sa_sigaction = on_signal as extern "C" fn(libc::c_int) as usize;
            sa.sa_flags = libc::SA_RESTART;
            libc::sigemptyset(&mut sa.sa_mask);
            libc::sigaction(sig, &sa, std::ptr::null_mut());
        }
    }
}

/// The signal received since `install` (0: none).
pub fn pending() -> i32 {
    RECEIVED.load(Ordering::SeqCst)
}

/// The name of a signal number.
pub fn name(sig: i32) -> &'static str {
    match sig {
        libc::SIGTERM => "SIGTERM",
        libc::SIGINT => "SIGINT",
        libc::SIGHUP => "SIGHUP",
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
        RECEIVED.store(0, Ordering::SeqCst);
    }
}
