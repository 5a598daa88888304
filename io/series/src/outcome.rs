//! The outcome of an output call, agreed by every process that writes one file.
//!
//! Under MPI most HDF5 calls on a file are collective: every process must make the same
//! calls in the same order. A process whose call failed must not return while the others go
//! on to the next collective call (they would wait for it forever), and must not close the
//! file while they write. So every call's outcome is agreed (`Team::settle`: one all-gather
//! of a small code) before the next one is made; when any process failed, every process
//! returns the same `WriteFailed`.
//!
//! After a failed write the processes' HDF5 states differ (the one whose write failed still
//! holds the unwritten metadata), so closing the file, which is collective, would wait forever:
//! one process flushing (`H5AC_flush -> MPI_Barrier`), another truncating
//! (`H5FD_truncate -> MPI_Bcast`). So a file whose write failed under MPI is never closed:
//! the team keeps a reference to it, and the process ends without the HDF5 and MPI
//! finalisation (`stranded`, `distribute::launch`), after the data of every step before
//! the failure was flushed.
//!
//! One process does the same: closing would write the metadata of the steps written since
//! the last commit, which on a full disk lands in part and leaves a file its next open
//! cannot truncate. Left open, the file on the disk is the one of the last commit (the rows
//! written since lie beyond the space it describes), and `--restart` continues from it.

use std::cell::Cell;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

static STRANDED: AtomicBool = AtomicBool::new(false);

/// True when a write to a file failed: it is left open, and the process must end without
/// finalising HDF5 and MPI (which would close it, and under MPI hang).
pub fn stranded() -> bool {
    STRANDED.load(Ordering::SeqCst)
}

/// Why a write failed, as far as the system says (the `errno` class).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Cause {
    Other = 1,
    Io,
    Permission,
    ReadOnly,
    TooLarge,
    Quota,
    NoSpace,
}

impl Cause {
    fn from_code(c: i32) -> Cause {
        match c {
            7 => Cause::NoSpace,
            6 => Cause::Quota,
            5 => Cause::TooLarge,
            4 => Cause::ReadOnly,
            3 => Cause::Permission,
            2 => Cause::Io,
            _ => Cause::Other,
        }
    }

    /// What the system said, with its errno name.
    pub fn text(self) -> &'static str {
        match self {
            Cause::NoSpace => "no space left on device (ENOSPC)",
            Cause::Quota => "disk quota exceeded (EDQUOT)",
            Cause::TooLarge => "file too large for its file system (EFBIG)",
            Cause::ReadOnly => "read-only file system (EROFS)",
            Cause::Permission => "permission denied (EACCES)",
            Cause::Io => "input/output error (EIO)",
            Cause::Other => "the HDF5 library reported an error",
        }
    }

    /// What to do about it.
    pub fn fix(self) -> &'static str {
        match self {
            Cause::NoSpace | Cause::Quota => "free space on that disk (or move the file to a larger one)",
            Cause::TooLarge => {
                "write to a file system that holds large files, or write less (`[output] every`, `fields`)"
            }
            Cause::ReadOnly | Cause::Permission => "make the directory writable or choose another output file",
            Cause::Io => "check the disk (system log)",
            Cause::Other => "run with -v for the library's message",
        }
    }

    /// The class of an error text: errno names and numbers as HDF5's drivers print them, and
    /// the system's messages. Returns None when the text names none.
    pub fn of_text(text: &str) -> Option<Cause> {
        let has = |s: &str| text.contains(s);
        Some(
            if has("No space left on device") || has("errno = 28,") || has("MPI_ERR_NO_SPACE") {
                Cause::NoSpace
            } else if has("Disk quota exceeded") || has("errno = 122,") || has("MPI_ERR_QUOTA") {
                Cause::Quota
            } else if has("File too large") || has("errno = 27,") {
                Cause::TooLarge
            } else if has("Read-only file system") || has("errno = 30,") || has("MPI_ERR_READ_ONLY") {
                Cause::ReadOnly
            } else if has("Permission denied") || has("errno = 13,") || has("MPI_ERR_ACCESS") {
                Cause::Permission
            } else if has("Input/output error") || has("errno = 5,") {
                Cause::Io
            } else {
                return None;
            },
        )
    }
}

/// Bytes free for an unprivileged user on the file system holding `dir` (statvfs), None when
/// the system does not say.
pub fn free_bytes(dir: &Path) -> Option<u64> {
    fs4::available_space(dir).ok()
}

/// The directory a file is in (`.` for a bare name).
pub fn dir_of(path: &Path) -> PathBuf {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// The class of a failed HDF5 call: from its error stack, else (MPI-IO often hides errno)
/// from the free space of the file's directory.
pub fn classify(e: &hdf5::Error, path: &Path) -> (Cause, String) {
    let text = match e.stack() {
        Some(s) => s
            .iter()
            .map(|f| f.description().to_string())
            .collect::<Vec<_>>()
            .join("; "),
        None => e.to_string(),
    };
    let cause = Cause::of_text(&text).unwrap_or_else(|| match free_bytes(&dir_of(path)) {
        Some(free) if free < 1 << 20 => Cause::NoSpace,
        _ => Cause::Other,
    });
    (cause, text)
}

/// Writing the output failed; every process of the writer returned this same error at the
/// same call (under MPI), so every process may close the file and end alike.
#[derive(Debug, Clone)]
pub struct WriteFailed {
    pub path: PathBuf,
    /// The call that failed ("creating /VTKHDF/Points", "writing step 12", ...).
    pub what: String,
    pub cause: Cause,
    /// The processes whose call failed (empty on one process).
    pub ranks: Vec<usize>,
    /// Bytes free on the file's disk when the failure was seen (where known).
    pub free: Option<u64>,
    /// This process's own message when its call failed without an errno class.
    pub detail: Option<String>,
}

impl std::fmt::Display for WriteFailed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {} failed", self.path.display(), self.what)?;
        match self.ranks.as_slice() {
            [] => {}
            [r] => write!(f, " on rank {r}")?,
            rs => write!(
                f,
                " on ranks {}",
                rs.iter().map(|r| r.to_string()).collect::<Vec<_>>().join(", ")
            )?,
        }
        write!(f, ": {}", self.cause.text())?;
        if let (Cause::NoSpace | Cause::Quota, Some(b)) = (self.cause, self.free) {
            write!(
                f,
                " ({} free in {})",
                human_bytes(b as f64),
                dir_of(&self.path).display()
            )?;
        }
        if let (Cause::Other, Some(d)) = (self.cause, &self.detail) {
            write!(f, " ({d})")?;
        }
        Ok(())
    }
}

impl std::error::Error for WriteFailed {}

/// `12.3 MiB`, `4.0 KiB`, `17 B`.
pub fn human_bytes(b: f64) -> String {
    const UNITS: [&str; 6] = ["KiB", "MiB", "GiB", "TiB", "PiB", "EiB"];
    if b < 1024.0 {
        return format!("{b:.0} B");
    }
    let mut v = b / 1024.0;
    for u in UNITS {
        if v < 1024.0 {
            return format!("{v:.1} {u}");
        }
        v /= 1024.0;
    }
    format!("{:.1} ZiB", v)
}

/// The processes writing one file and their agreement on every call's outcome.
pub struct Team {
    pub path: PathBuf,
    comm: Option<mpi::topology::SimpleCommunicator>,
    /// The file's HDF5 id, once open: under MPI a failure keeps it open for good.
    file: Cell<Option<hdf5_sys::h5i::hid_t>>,
}

/// A call's outcome as one code: 0 done, else the cause's code.
fn code<T>(r: &Result<T, (Cause, String)>) -> i32 {
    match r {
        Ok(_) => 0,
        Err((c, _)) => *c as i32,
    }
}

impl Team {
    /// The writers of `path`: this process alone, or every process of `comm` (which every
    /// one of them must call with).
    pub fn new(path: &Path, comm: Option<&mpi::topology::SimpleCommunicator>) -> Team {
        use mpi::topology::Communicator;
        Team {
            path: path.to_path_buf(),
            comm: comm.map(|c| c.duplicate()),
            file: Cell::new(None),
        }
    }

    /// The file these processes write: under MPI, a failed call leaves it open (see the
    /// module's text).
    pub fn hold(&self, file: &hdf5::File) {
        self.file.set(Some(file.id()));
    }

    /// After a failure: one more reference to the file, so that dropping every handle never
    /// closes it, and the process marked to end without finalisation.
    fn strand(&self) {
        if let Some(id) = self.file.take() {
            // SAFETY: `id` is the open file's id (held since it was opened)
            unsafe {
                hdf5_sys::h5i::H5Iinc_ref(id);
            }
            STRANDED.store(true, Ordering::SeqCst);
        }
    }

    pub fn is_parallel(&self) -> bool {
        self.comm.is_some()
    }

    /// The outcome code of every process (this one's alone without MPI).
    fn gather(&self, mine: i32) -> Vec<i32> {
        use mpi::topology::Communicator;
        use mpi::traits::CommunicatorCollectives;
        match &self.comm {
            None => vec![mine],
            Some(c) => {
                let mut all = vec![0i32; c.size() as usize];
                c.all_gather_into(&mine, &mut all[..]);
                all
            }
        }
    }

    /// Agrees on the outcome of one call made by every process: its value when it succeeded
    /// everywhere, else the same `WriteFailed` on every process. `what` names the call.
    pub fn settle<T>(&self, what: impl FnOnce() -> String, r: hdf5::Result<T>) -> anyhow::Result<T> {
        let r = r.map_err(|e| {
            let (cause, text) = classify(&e, &self.path);
            tracing::info!("{}: HDF5: {text}", self.path.display());
            (cause, text)
        });
        self.agree(what, r)
    }

    /// `settle` for a call that failed with a message of eprop's own (no errno).
    pub fn settle_msg<T>(&self, what: impl FnOnce() -> String, r: Result<T, String>) -> anyhow::Result<T> {
        self.agree(what, r.map_err(|m| (Cause::Other, m)))
    }

    fn agree<T>(&self, what: impl FnOnce() -> String, r: Result<T, (Cause, String)>) -> anyhow::Result<T> {
        let all = self.gather(code(&r));
        self.decide(what, r, &all)
    }

    /// The agreed outcome from every process's code.
    fn decide<T>(
        &self,
        what: impl FnOnce() -> String,
        r: Result<T, (Cause, String)>,
        all: &[i32],
    ) -> anyhow::Result<T> {
        if all.iter().all(|&c| c == 0) {
            return r.map_err(|_| unreachable!());
        }
        self.strand();
        let cause = Cause::from_code(*all.iter().max().unwrap_or(&1));
        let detail = r
            .err()
            .map(|(_, text)| text.split("; ").next().unwrap_or("").chars().take(200).collect());
        let ranks = if self.comm.is_some() {
            (0..all.len()).filter(|&i| all[i] != 0).collect()
        } else {
            vec![]
        };
        Err(WriteFailed {
            path: self.path.clone(),
            what: what(),
            cause,
            ranks,
            free: free_bytes(&dir_of(&self.path)),
            detail,
        }
        .into())
    }

    /// `settle` for opening or creating the file: a process that opened it while another
    /// failed cannot close it alone (closing is collective), so it leaves it open and returns
    /// an error that is not agreed (the job's policy then aborts every process).
    pub fn settle_open<T>(&self, what: impl FnOnce() -> String, r: hdf5::Result<T>) -> anyhow::Result<T> {
        let r = r.map_err(|e| {
            let (cause, text) = classify(&e, &self.path);
            tracing::info!("{}: HDF5: {text}", self.path.display());
            (cause, text)
        });
        let all = self.gather(code(&r));
        let failed: Vec<usize> = (0..all.len()).filter(|&i| all[i] != 0).collect();
        if failed.is_empty() || failed.len() == all.len() {
            return self.decide(what, r, &all);
        }
        if let Ok(v) = r {
            std::mem::forget(v);
        }
        Err(anyhow::anyhow!(
            "{}: {} failed on rank(s) {failed:?} only; the job ends (MPI_Abort) because the processes that opened the file cannot close it alone",
            self.path.display(),
            what()
        ))
    }

    /// `settle` for a read whose failure means "not there" when it fails on every process:
    /// None then; an error when it failed on some processes only.
    pub fn settle_opt<T>(&self, what: impl FnOnce() -> String, r: hdf5::Result<T>) -> anyhow::Result<Option<T>> {
        let all = self.gather(i32::from(r.is_err()));
        if all.iter().all(|&c| c == 1) {
            return Ok(None);
        }
        self.settle(what, r).map(Some)
    }

    /// Rank 0's `yes` on every process (a broadcast; every process calls).
    pub fn root_decides(&self, yes: bool) -> bool {
        use mpi::topology::Communicator;
        use mpi::traits::Root;
        match &self.comm {
            None => yes,
            Some(c) => {
                let mut v = i32::from(yes);
                c.process_at_rank(0).broadcast_into(&mut v);
                v != 0
            }
        }
    }

    /// True when every process says `ok` (a reduction; every process calls).
    pub fn all(&self, ok: bool) -> bool {
        self.gather(i32::from(!ok)).iter().all(|&c| c == 0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn causes_are_read_from_the_drivers_words() {
        let sec2 = "file write failed: time = Sun Nov 23, filename = 'a.h5', file descriptor = 5, errno = 28, error message = 'No space left on device', buf = 0x5, total write size = 8, bytes this sub-write = 8, bytes actually written = 18446744073709551615, offset = 0";
        assert_eq!(Cause::of_text(sec2), Some(Cause::NoSpace));
        assert_eq!(Cause::of_text("errno = 122, error message = 'x'"), Some(Cause::Quota));
        assert_eq!(
            Cause::of_text("MPI error string is 'MPI_ERR_READ_ONLY'"),
            Some(Cause::ReadOnly)
        );
        assert_eq!(Cause::of_text("errno = 280, something"), None);
        assert_eq!(Cause::of_text("unable to flush"), None);
        // the most specific cause wins when processes disagree
        assert!(Cause::NoSpace > Cause::Other && Cause::from_code(Cause::NoSpace as i32) == Cause::NoSpace);
    }

    #[test]
    fn a_failure_names_the_file_the_call_the_ranks_and_the_cause() {
        let w = WriteFailed {
            path: PathBuf::from("/d/out.h5"),
            what: "writing output step 3".into(),
            cause: Cause::NoSpace,
            ranks: vec![1],
            free: Some(0),
            detail: None,
        };
        assert_eq!(
            w.to_string(),
            "/d/out.h5: writing output step 3 failed on rank 1: no space left on device (ENOSPC) (0 B free in /d)"
        );
        assert_eq!(human_bytes(3.0 * 1048576.0), "3.0 MiB");
        assert_eq!(dir_of(Path::new("x.h5")), PathBuf::from("."));
    }

    #[test]
    fn one_process_settles_alone() {
        let t = Team::new(Path::new("x.h5"), None);
        assert_eq!(t.settle(|| "a".into(), Ok(3)).unwrap(), 3);
        let e = t
            .settle_msg::<()>(|| "writing rows".into(), Err("internal".into()))
            .unwrap_err();
        let w = e.downcast_ref::<WriteFailed>().unwrap();
        assert_eq!((w.cause, w.ranks.len()), (Cause::Other, 0));
        assert!(t.all(true) && !t.all(false));
    }
}
