//! A request to stop a run after its current step, made from outside the numerics: the
//! command's signal handler (SIGTERM, SIGINT, SIGHUP), or a program that embeds a simulation.
//! The simulation reads its token once per step; the processes of a job agree on it in the
//! step's reduction, so every process stops after the same step.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

/// A shared stop flag: every clone sees the same request. A new token is never requested
/// until `request` is called on it (or on a clone).
#[derive(Clone, Debug, Default)]
pub struct StopToken {
    flag: Arc<AtomicUsize>,
}

impl StopToken {
    /// A token nobody has requested yet.
    pub fn new() -> StopToken {
        StopToken::default()
    }

    /// A token on `flag`, which its owner sets to a nonzero code to request the stop (a signal
    /// handler stores the signal's number in it).
    pub fn from_flag(flag: Arc<AtomicUsize>) -> StopToken {
        StopToken { flag }
    }

    /// Requests the stop with a nonzero `code` (a signal's number, say); 0 withdraws it.
    pub fn request(&self, code: usize) {
        self.flag.store(code, Ordering::SeqCst);
    }

    /// The code of the request (0: none).
    pub fn requested(&self) -> i32 {
        self.flag.load(Ordering::SeqCst) as i32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clones_share_the_request() {
        let t = StopToken::new();
        let c = t.clone();
        assert_eq!(c.requested(), 0);
        t.request(15);
        assert_eq!(c.requested(), 15);
        let flag = Arc::new(AtomicUsize::new(0));
        let f = StopToken::from_flag(flag.clone());
        flag.store(1, Ordering::SeqCst);
        assert_eq!(f.requested(), 1);
    }
}
