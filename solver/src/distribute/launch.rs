//! Starting a command on one process or on every process of an MPI job, and the job's error
//! policy and exit statuses.
//!
//! The policy: an error every process knows (a bad scenario or mesh, found by rank 0 before
//! the parts were sent and sent to all; or one the processes agreed on, `Agreed`: a
//! stop by a signal, a failed write, a non-finite state) is printed once and every process
//! exits with its status; an error on one process prints its message with its rank and ends
//! every process (MPI_Abort), so a batch job never hangs.
//!
//! MPI is started here only: for a job by `launch`, and for a process alone whose run calls a
//! library that needs it (hypre) by `start_alone`.

use crate::distribute::comm::{Comm, Mpi};
use crate::distribute::parts::{Collective, ReportedElsewhere};
use anyhow::{bail, Result};
use std::sync::Mutex;

/// Exit status of an error (bad input, a refusal, non-finite values).
pub const EXIT_ERROR: u8 = 1;
/// Exit status of a run stopped by SIGTERM, SIGINT or SIGHUP after a complete, written step.
pub const EXIT_STOPPED: u8 = 3;
/// Exit status of a run whose output could not be written (disk full, I/O error); the file
/// holds every step before the failure.
pub const EXIT_WRITE: u8 = 4;

/// An error every process of a run knows (the processes agreed on it through a reduction):
/// printed once (by rank 0), every process exits with `status`.
#[derive(Debug, Clone)]
pub struct Agreed {
    pub status: u8,
    pub message: String,
}

impl Agreed {
    pub fn error(status: u8, message: impl Into<String>) -> anyhow::Error {
        Agreed {
            status,
            message: message.into(),
        }
        .into()
    }
}

impl std::fmt::Display for Agreed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for Agreed {}

/// True when started by an MPI launcher.
pub(crate) fn under_mpirun() -> bool {
    ["OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK", "MPI_LOCALNRANKS"]
        .iter()
        .any(|v| std::env::var_os(v).is_some())
}

/// True on the process that prints (rank 0, or the only one).
pub fn is_root(world: Option<&dyn Comm>) -> bool {
    world.is_none_or(|w| w.rank() == 0)
}

/// Runs `body` on rank 0 only (the one writer of a file), the other processes waiting for it:
/// rank 0's error becomes every process's (an `Agreed` error with status 1, printed once by
/// rank 0); rank 0 gets `Some` of its value, the others `None`.
pub fn on_root<T>(world: Option<&dyn Comm>, body: impl FnOnce() -> Result<T>) -> Result<Option<T>> {
    let root = is_root(world);
    let r = if root { Some(body()) } else { None };
    let Some(w) = world else {
        return r.transpose();
    };
    let any = w.max(f64::from(u8::from(matches!(r, Some(Err(_))))));
    match r {
        Some(Err(e)) => Err(Agreed::error(EXIT_ERROR, format!("{e:#}"))),
        _ if any > 0.0 => Err(Agreed::error(EXIT_ERROR, "rank 0 failed")),
        r => r.transpose(),
    }
}

/// MPI started for a process alone (`start_alone`), finalised when its `launch` ends.
static ALONE: Mutex<Option<mpi::environment::Universe>> = Mutex::new(None);

/// Starts MPI in a process that runs alone (not under mpirun), for a library whose calls need
/// it (hypre: `Comm::raw` then gives MPI_COMM_SELF); a no-op once MPI runs. The launch that
/// runs the command finalises it at its end.
pub fn start_alone() -> Result<()> {
    let mut alone = ALONE.lock().unwrap_or_else(|e| e.into_inner());
    if mpi::environment::is_initialized() {
        return Ok(());
    }
    match mpi::initialize() {
        Some(universe) => {
            *alone = Some(universe);
            Ok(())
        }
        None => bail!("MPI could not be started for this process"),
    }
}

/// Runs `body` on this process alone (`None`), or, under mpirun, on every process with the
/// job's communicator and error policy: under MPI an error never returns here, the process
/// exits (or the job is aborted) as the policy says.
pub fn launch<T>(body: impl FnOnce(Option<&dyn Comm>) -> Result<T>) -> Result<T> {
    if !under_mpirun() {
        let result = body(None);
        // MPI started for a library of this run (`start_alone`) ends with it
        drop(ALONE.lock().unwrap_or_else(|e| e.into_inner()).take());
        return result;
    }
    let Some(universe) = mpi::initialize() else {
        bail!("MPI could not be initialised");
    };
    let world = Mpi::of_job(&universe);
    let (rank, size) = (world.rank(), world.size());
    let result = body(Some(&world));
    let err = match result {
        Ok(v) => return Ok(v),
        Err(e) => e,
    };
    let status = match ending(&err, rank, size) {
        Ending::Quiet(status) => status,
        Ending::Once(msg, status) => {
            eprintln!("{msg}");
            status
        }
        Ending::Abort(msg) => {
            eprintln!("{msg}");
            world.abort(1)
        }
    };
    if eprop_series::outcome::stranded() {
        // a file whose write failed is still open (eprop_series::outcome): finalising MPI
        // would close it collectively and wait forever, so every process, once all have
        // printed, ends here with the agreed status
        world.barrier();
        use std::io::Write;
        let _ = std::io::stdout().flush();
        let _ = std::io::stderr().flush();
        // SAFETY: ends the process at once (no destructor, atexit handler or MPI_Finalize)
        unsafe { libc::_exit(status.into()) }
    }
    drop(world);
    drop(universe);
    std::process::exit(status.into())
}

/// How a process of a job ends after an error.
#[derive(Debug, PartialEq)]
enum Ending {
    /// Rank 0 printed it; exit with this status.
    Quiet(u8),
    /// Printed by this process, then every process exits with this status.
    Once(String, u8),
    /// Printed by this process, which ends the whole job.
    Abort(String),
}

fn ending(e: &anyhow::Error, rank: usize, size: usize) -> Ending {
    if let Some(a) = e.downcast_ref::<Agreed>() {
        // a stop says so itself ("stopped by SIGTERM ...")
        let word = if a.status == EXIT_STOPPED { "" } else { "error: " };
        match rank {
            0 => Ending::Once(format!("{word}{}", a.message), a.status),
            _ => Ending::Quiet(a.status),
        }
    } else if e.is::<ReportedElsewhere>() {
        Ending::Quiet(EXIT_ERROR)
    } else if e.is::<Collective>() {
        match rank {
            0 => Ending::Once(format!("error: {e:#}"), EXIT_ERROR),
            _ => Ending::Quiet(EXIT_ERROR),
        }
    } else if size > 1 {
        Ending::Abort(format!("error (rank {rank} of {size}): {e:#}"))
    } else {
        Ending::Abort(format!("error: {e:#}"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use anyhow::anyhow;

    #[test]
    fn an_error_ends_a_job_by_its_kind() {
        let collective = || anyhow::Error::from(Collective("bad.toml: no mesh".into()));
        assert_eq!(
            ending(&collective(), 0, 3),
            Ending::Once("error: bad.toml: no mesh".into(), 1)
        );
        assert_eq!(ending(&collective(), 2, 3), Ending::Quiet(1));
        assert_eq!(ending(&ReportedElsewhere.into(), 1, 3), Ending::Quiet(1));
        let stopped = || Agreed::error(EXIT_STOPPED, "stopped by SIGTERM after step 3");
        assert_eq!(
            ending(&stopped(), 0, 2),
            Ending::Once("stopped by SIGTERM after step 3".into(), 3)
        );
        assert_eq!(ending(&stopped(), 1, 2), Ending::Quiet(3));
        let full = Agreed::error(EXIT_WRITE, "out.h5: disk full");
        assert_eq!(ending(&full, 0, 2), Ending::Once("error: out.h5: disk full".into(), 4));
        assert_eq!(
            ending(&anyhow!("out.h5: write failed"), 1, 3),
            Ending::Abort("error (rank 1 of 3): out.h5: write failed".into())
        );
        assert_eq!(ending(&anyhow!("x"), 0, 1), Ending::Abort("error: x".into()));
    }
}
