//! What a run may write, and how it ends when it cannot go on.
//!
//! - An output never replaces an input: an output path that resolves to a file the run reads
//!   (same canonical path, or the same device and inode: links count) is refused before
//!   anything is opened for writing (`refuse_inputs`).
//! - An existing file is replaced only when the user says so, and only when it is an eprop
//!   series (`check_existing`).
//! - One writer per output: an advisory lock (`flock`) on `<output>.lock`, taken before the
//!   output is opened and held to the end of the run (`OutputLock`). Readers never take it.
//! - The output must fit on its disk (`check_space`).
//! - A run that stops early ends every process with the same status and one message
//!   (`distribute::launch::Agreed`; the statuses are its `EXIT_*`).

use crate::config::Input;
use crate::guard::limits::{reserve, Budget};
use anyhow::{anyhow, bail, Result};
use eprop_series::outcome::{dir_of, free_bytes, human_bytes};
use eprop_series::vtkhdf::Kind;
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};

/// The canonical form of a path whose file may not exist yet: its directory made canonical.
fn canonical(path: &Path) -> Option<PathBuf> {
    if let Ok(p) = std::fs::canonicalize(path) {
        return Some(p);
    }
    let name = path.file_name()?;
    std::fs::canonicalize(dir_of(path)).ok().map(|d| d.join(name))
}

/// (device, inode) of an existing file, links followed.
fn identity(path: &Path) -> Option<(u64, u64)> {
    std::fs::metadata(path).ok().map(|m| (m.dev(), m.ino()))
}

/// Refuses an output path (`role`: how it was named, "the output file (--output)") that is or
/// will be one of the run's inputs.
pub fn refuse_inputs(out: &Path, role: &str, inputs: &[Input]) -> Result<()> {
    if let Ok(m) = std::fs::symlink_metadata(out) {
        if m.file_type().is_symlink() && std::fs::metadata(out).is_err() {
            bail!(
                "{}: {role} is a symbolic link to {}, which does not exist; fix: give the path of the file itself",
                out.display(),
                std::fs::read_link(out)
                    .map(|t| t.display().to_string())
                    .unwrap_or_default()
            );
        }
    }
    let (out_path, out_id) = (canonical(out), identity(out));
    for i in inputs {
        let same_path = out_path.is_some() && out_path == canonical(&i.path);
        let same_file = out_id.is_some() && out_id == identity(&i.path);
        if same_path || same_file {
            let how = if same_path {
                String::new()
            } else {
                format!(" (a link to the same file, {})", i.path.display())
            };
            bail!(
                "{}: {role} is {}{how}; writing it would destroy that input; fix: write to another file",
                out.display(),
                i.role
            );
        }
    }
    Ok(())
}

/// The fix that names another output for `out`: `-o FILE.h5` for a series, another `-o` prefix
/// for the files of export and fit (PREFIX_STEP.obj, PREFIX.json, ...), which take a prefix.
pub fn elsewhere(out: &Path) -> &'static str {
    match out.extension().and_then(|e| e.to_str()) {
        Some("h5") | None => "write another file with -o FILE.h5",
        Some(_) => "write other files with another -o PREFIX (export and fit write PREFIX_STEP.EXT and PREFIX.EXT)",
    }
}

/// Refuses to replace an existing file, unless it is an eprop series and `overwrite` is set.
/// `role` names how the path was given; `restart` is the command that would continue it (empty
/// when none can: the advice then leaves it out).
pub fn check_existing(path: &Path, role: &str, overwrite: bool, restart: &str) -> Result<()> {
    let Ok(meta) = std::fs::metadata(path) else {
        return Ok(());
    };
    if !meta.is_file() {
        bail!(
            "{}: {role} exists and is not a regular file; fix: give the path of a new .h5 file",
            path.display()
        );
    }
    match eprop_series::vtkhdf::kind_of(path)? {
        Kind::Series { steps, .. } if overwrite => {
            tracing::info!("{}: replacing a series of {steps} steps (--overwrite)", path.display());
            Ok(())
        }
        Kind::Series { steps, .. } => {
            let continue_it = if restart.is_empty() {
                String::new()
            } else {
                format!("continue it with `{restart}`, ")
            };
            bail!(
                "{}: {role} exists and holds an eprop series of {steps} complete step(s); eprop does not replace it silently; fix: {continue_it}replace it with --overwrite (or [output] overwrite = true), or {}",
                path.display(),
                elsewhere(path)
            )
        }
        other => {
            let what = if other == Kind::NotHdf5 {
                "is not an HDF5 file"
            } else {
                "is an HDF5 file but not an eprop series"
            };
            bail!(
                "{}: {role} exists and {what} ({}); eprop never replaces such a file, not even with --overwrite; fix: {}, or move this one away",
                path.display(),
                human_bytes(meta.len() as f64),
                elsewhere(path)
            )
        }
    }
}

/// An advisory lock for the one writer of an output file, taken before the output is opened
/// and held to the end of the run:
/// - `flock` on `<output>.lock` beside the file the output path resolves to (a symbolic link
///   is followed: writers through a link take the same lock), a file that holds
///   "eprop lock", the writer's process id and host;
/// - when the output exists (and once a series is created, `hold_output`), an open-file-
///   description lock on the output file itself, which is per device and inode: a writer
///   through a hard link is refused too; this value holds it.
///
/// The lock file is opened without following links, and anything at its path that is not a
/// regular file holding our lock format is refused, never written nor removed. Released (and
/// the side file removed) when dropped; the system releases both locks when the process dies.
pub struct OutputLock {
    path: PathBuf,
    /// The output's canonical path.
    output: PathBuf,
    file: std::fs::File,
    /// The output opened and locked by inode (None: it did not exist, or its file system has
    /// no such locks); replaced when the series creates a new inode (`hold_output`).
    inode: std::sync::Mutex<Option<std::fs::File>>,
}

/// First line of every lock file eprop writes.
const LOCK_MAGIC: &str = "eprop lock";

/// The side file of an output's lock: `<output>.lock` beside the file the path resolves to.
pub fn lock_path(output: &Path) -> PathBuf {
    let mut s = canonical(output)
        .unwrap_or_else(|| output.to_path_buf())
        .into_os_string();
    s.push(".lock");
    PathBuf::from(s)
}

/// Tries an exclusive open-file-description lock on one byte far past any data of `f`:
/// Ok(true) taken, Ok(false) held by another open file, Err when the file system has none.
fn ofd_lock(f: &std::fs::File) -> std::io::Result<bool> {
    use std::os::fd::AsRawFd;
    // SAFETY: a zeroed flock is a valid argument; fcntl only reads it
    let mut l: libc::flock = unsafe { std::mem::zeroed() };
    l.l_type = libc::F_WRLCK as _;
    l.l_whence = libc::SEEK_SET as _;
    l.l_start = 1 << 62;
    l.l_len = 1;
    // SAFETY: a valid descriptor and a valid flock
    let r = unsafe { libc::fcntl(f.as_raw_fd(), libc::F_OFD_SETLK, &l) };
    if r == 0 {
        return Ok(true);
    }
    let e = std::io::Error::last_os_error();
    match e.raw_os_error() {
        Some(libc::EAGAIN) | Some(libc::EACCES) => Ok(false),
        _ => Err(e),
    }
}

/// Locks the inode of the existing file `output` for this process (a no-op when it does not
/// exist, cannot be opened for writing, or its file system has no such locks); refuses when
/// another writer holds it.
fn lock_inode(output: &Path) -> Result<Option<std::fs::File>> {
    let Ok(meta) = std::fs::metadata(output) else {
        return Ok(None);
    };
    if !meta.is_file() {
        return Ok(None);
    }
    // without blocking: a FIFO put in the file's place since it was looked at is not waited on
    let Ok(f) =
        std::os::unix::fs::OpenOptionsExt::custom_flags(std::fs::OpenOptions::new().write(true), libc::O_NONBLOCK)
            .open(output)
    else {
        return Ok(None);
    };
    match ofd_lock(&f) {
        Ok(true) => Ok(Some(f)),
        Ok(false) => bail!(
            "{}: another eprop run is writing this file now, through another name (a hard link to the same file, device {} inode {}); two writers would mix their steps; fix: wait for that run to end, or {}",
            output.display(),
            meta.dev(),
            meta.ino(),
            elsewhere(output)
        ),
        Err(e) => {
            tracing::debug!("{}: no inode lock on this file system: {e}", output.display());
            Ok(None)
        }
    }
}

impl OutputLock {
    /// After the output this lock claims was created (a new file, a new inode): lock its
    /// inode too, so a writer through a hard link made later is refused. A no-op for another
    /// output than this lock's.
    pub fn hold_output(&self, output: &Path) {
        if canonical(output).unwrap_or_else(|| output.to_path_buf()) != self.output {
            return;
        }
        let mut inode = self.inode.lock().unwrap_or_else(|e| e.into_inner());
        let held = inode
            .as_ref()
            .and_then(|f| f.metadata().ok())
            .map(|m| (m.dev(), m.ino()));
        if held.is_some() && held == identity(output) {
            return;
        }
        match lock_inode(output) {
            Ok(f) => *inode = f,
            Err(e) => tracing::warn!("{e:#}"),
        }
    }

    /// Takes the lock of `output`, or says which process holds it.
    pub fn take(output: &Path) -> Result<OutputLock> {
        use std::io::{Read, Seek, Write};
        use std::os::unix::fs::OpenOptionsExt;
        let path = lock_path(output);
        for _ in 0..8 {
            let mut f = std::fs::OpenOptions::new()
                .read(true)
                .write(true)
                .create(true)
                .truncate(false)
                .custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK)
                .open(&path)
                .map_err(|e| {
                    if e.raw_os_error() == Some(libc::ELOOP) {
                        anyhow!(
                            "{}: the lock file of the output is a symbolic link; eprop never writes through a link there (it would overwrite the link's target); fix: remove the link {} if nothing uses it, or {}",
                            path.display(),
                            path.display(),
                            elsewhere(output)
                        )
                    } else {
                        anyhow!(
                            "{}: cannot create the lock file of the output: {e}; fix: make the directory writable or choose another output file",
                            path.display()
                        )
                    }
                })?;
            let meta = f.metadata()?;
            let mut text = String::new();
            let readable = meta.is_file() && f.read_to_string(&mut text).is_ok();
            if !meta.is_file()
                || !readable
                || !(text.is_empty() || text.starts_with(LOCK_MAGIC) || text.starts_with("pid "))
            {
                bail!(
                    "{}: the lock file of the output exists and is not an eprop lock file ({}); eprop neither overwrites nor removes it; fix: move it away if nothing uses it, or {}",
                    path.display(),
                    if meta.is_file() {
                        human_bytes(meta.len() as f64)
                    } else {
                        "not a regular file".to_string()
                    },
                    elsewhere(output)
                );
            }
            if f.try_lock().is_err() {
                let who = text.strip_prefix(LOCK_MAGIC).unwrap_or(&text).trim();
                let who = if who.is_empty() {
                    "another process".to_string()
                } else {
                    format!("another eprop run ({})", who.replace('\n', ", "))
                };
                bail!(
                    "{}: {who} is writing this file now (it holds {}); two writers would mix their steps; fix: wait for that run to end, or {}",
                    output.display(),
                    path.display(),
                    elsewhere(output)
                );
            }
            // the file locked must still be the one at `path` (a run that ended may have
            // removed it between our open and our lock)
            let same = match std::fs::symlink_metadata(&path) {
                Ok(b) => meta.dev() == b.dev() && meta.ino() == b.ino(),
                _ => false,
            };
            if !same {
                continue;
            }
            let inode = lock_inode(output)?;
            let host = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap_or_default();
            let _ = f.set_len(0).and_then(|_| f.rewind());
            let _ = write!(f, "{LOCK_MAGIC}\npid {} on {}\n", std::process::id(), host.trim());
            let _ = f.flush();
            return Ok(OutputLock {
                path,
                output: canonical(output).unwrap_or_else(|| output.to_path_buf()),
                file: f,
                inode: std::sync::Mutex::new(inode),
            });
        }
        bail!(
            "{}: the lock file keeps changing (runs starting and ending on this output); fix: try again",
            path.display()
        )
    }
}

impl Drop for OutputLock {
    fn drop(&mut self) {
        // the inode lock first: a run that takes the side file next finds the output free
        drop(self.inode.get_mut().unwrap_or_else(|e| e.into_inner()).take());
        // removed while still locked (and only while it is still ours): a run that opened it
        // meanwhile sees another inode and takes a new one
        let ours = match (self.file.metadata(), std::fs::symlink_metadata(&self.path)) {
            (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
            _ => false,
        };
        if ours {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

/// Claims a file that a command other than `run` writes (`role`: how it was named): it must
/// not be one of `inputs`, not be written by another run (the lock, held until the returned
/// guard drops), and an existing file is replaced only with `overwrite` (and only a regular
/// file).
pub fn claim_file(out: &Path, role: &str, inputs: &[Input], overwrite: bool) -> Result<OutputLock> {
    refuse_inputs(out, role, inputs)?;
    refuse_inputs(&lock_path(out), "the lock file of the output", inputs)?;
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        if !dir.is_dir() {
            bail!(
                "{}: {role}: the directory {} does not exist; fix: create it or write elsewhere",
                out.display(),
                dir.display()
            );
        }
    }
    let lock = OutputLock::take(out)?;
    if let Ok(meta) = std::fs::metadata(out) {
        if !meta.is_file() {
            bail!(
                "{}: {role} exists and is not a regular file; fix: give the path of a new file",
                out.display()
            );
        }
        if !overwrite {
            bail!(
                "{}: {role} exists ({}); eprop does not replace a file silently; fix: replace it with --overwrite, or write another file",
                out.display(),
                human_bytes(meta.len() as f64)
            );
        }
        tracing::info!("{}: replacing it (--overwrite)", out.display());
    }
    Ok(lock)
}

/// Refuses a run whose output (`need` bytes, estimated from `what`) exceeds the free space of
/// its directory (plus `reclaimed`, the bytes of a file the run replaces), unless `force`.
pub fn check_space(output: &Path, budget: &Budget, reclaimed: u64, what: &str, force: bool) -> Result<()> {
    let dir = dir_of(output);
    let Some(free) = free_bytes(&dir) else {
        return Ok(());
    };
    let free = free.saturating_add(reclaimed);
    let reserve = reserve(budget.step_bytes);
    if !force && budget.output_bytes + reserve > free as f64 {
        bail!(
            "{}: the run would write about {} ({what}) and keeps {} free while writing, but {} has {} free; fix: free space, write less (`[output] every`, `fields`, precision = \"float32\", or fewer steps), write elsewhere with -o, or start anyway with --force (the run then stops cleanly, with every step written so far, when the disk gets full)",
            output.display(),
            human_bytes(budget.output_bytes),
            human_bytes(reserve),
            dir.display(),
            human_bytes(free as f64)
        )
    }
    if budget.start_bytes + reserve > free as f64 {
        bail!(
            "{}: the first output step needs about {} (with the mesh, for a new series) and {} kept free while writing, but {} has {} free, so not even --force starts; fix: free space or write elsewhere with -o",
            output.display(),
            human_bytes(budget.start_bytes),
            human_bytes(reserve),
            dir.display(),
            human_bytes(free as f64)
        )
    }
    Ok(())
}

/// The command that continues a run's series and finishes the job:
/// `[mpirun -n N] eprop run SCENARIO --restart FILE [OPTIONS]`, with the options of the
/// interrupted run that change the job (`--steps N`, `--force`, ...) in `options`.
pub fn restart_command(scenario: &Path, file: &Path, processes: usize, options: &[String]) -> String {
    let mpi = if processes > 1 {
        format!("mpirun -n {processes} ")
    } else {
        String::new()
    };
    let quote = |p: &Path| {
        let s = p.display().to_string();
        if s.is_empty() || s.contains(|c: char| !(c.is_ascii_alphanumeric() || "/._-+,:=@%".contains(c))) {
            format!("'{}'", s.replace('\'', "'\\''"))
        } else {
            s
        }
    };
    let mut cmd = format!("{mpi}eprop run {} --restart {}", quote(scenario), quote(file));
    for o in options {
        cmd.push(' ');
        cmd.push_str(o);
    }
    cmd
}

#[cfg(test)]
mod tests {
    use super::*;

    fn input(role: &str, p: &Path) -> Input {
        Input {
            role: role.into(),
            path: p.to_path_buf(),
        }
    }

    #[test]
    fn an_output_that_is_an_input_is_refused_by_path_link_or_inode() {
        let t = tempfile::tempdir().unwrap();
        let d = t.path();
        let mesh = d.join("cyl.msh");
        std::fs::write(&mesh, "mesh").unwrap();
        std::fs::create_dir(d.join("sub")).unwrap();
        let inputs = [input("the mesh (cyl.msh, [mesh] file of s.toml)", &mesh)];
        let refused = |out: &Path| {
            refuse_inputs(out, "the output file (--output)", &inputs)
                .unwrap_err()
                .to_string()
        };
        let e = refused(&mesh);
        assert!(
            e.contains("cyl.msh: the output file (--output) is the mesh") && e.contains("fix:"),
            "{e}"
        );
        refused(&d.join("sub/../cyl.msh"));
        std::os::unix::fs::symlink(&mesh, d.join("soft.h5")).unwrap();
        refused(&d.join("soft.h5"));
        std::fs::hard_link(&mesh, d.join("hard.h5")).unwrap();
        assert!(refused(&d.join("hard.h5")).contains("a link to the same file"));
        std::os::unix::fs::symlink(d.join("gone.h5"), d.join("dangling.h5")).unwrap();
        assert!(refused(&d.join("dangling.h5")).contains("which does not exist"));
        assert!(refuse_inputs(&d.join("new.h5"), "x", &inputs).is_ok());
        assert_eq!(std::fs::read(&mesh).unwrap(), b"mesh");
    }

    #[test]
    fn a_second_lock_is_refused_and_released_with_the_first() {
        let t = tempfile::tempdir().unwrap();
        let out = t.path().join("o.h5");
        let first = OutputLock::take(&out).unwrap();
        let e = OutputLock::take(&out).err().unwrap().to_string();
        assert!(
            e.contains(&format!("another eprop run (pid {}", std::process::id())) && e.contains("fix:"),
            "{e}"
        );
        drop(first);
        assert!(!lock_path(&out).exists());
        let again = OutputLock::take(&out).unwrap();
        drop(again);
    }

    #[test]
    fn the_lock_covers_symbolic_and_hard_links_and_never_follows_a_link_at_the_lock() {
        let t = tempfile::tempdir().unwrap();
        let d = t.path();
        let out = d.join("o.h5");
        std::fs::write(&out, "series").unwrap();
        std::fs::create_dir(d.join("sub")).unwrap();
        std::os::unix::fs::symlink(&out, d.join("soft.h5")).unwrap();
        std::fs::hard_link(&out, d.join("sub/hard.h5")).unwrap();
        let first = OutputLock::take(&out).unwrap();
        let e = OutputLock::take(&d.join("soft.h5")).err().unwrap().to_string();
        assert!(e.contains("is writing this file now"), "{e}");
        let e = OutputLock::take(&d.join("sub/hard.h5")).err().unwrap().to_string();
        assert!(e.contains("a hard link to the same file"), "{e}");
        drop(first);
        drop(OutputLock::take(&d.join("sub/hard.h5")).unwrap());
        // a link where the lock goes is refused and kept, its target untouched
        std::os::unix::fs::symlink(&out, d.join("x.h5.lock")).unwrap();
        let e = OutputLock::take(&d.join("x.h5")).err().unwrap().to_string();
        assert!(e.contains("is a symbolic link") && e.contains("fix:"), "{e}");
        assert!(d.join("x.h5.lock").is_symlink());
        assert_eq!(std::fs::read(&out).unwrap(), b"series");
    }

    #[test]
    fn only_a_series_is_replaced_and_only_when_asked() {
        let t = tempfile::tempdir().unwrap();
        let txt = t.path().join("notes.txt");
        std::fs::write(&txt, "keep me").unwrap();
        for overwrite in [false, true] {
            let e = check_existing(&txt, "the output file", overwrite, "r")
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("is not an HDF5 file") && e.contains("not even with --overwrite"),
                "{e}"
            );
        }
        assert!(check_existing(&t.path().join("new.h5"), "x", false, "r").is_ok());
        let e = check_existing(t.path(), "the output file", true, "r")
            .unwrap_err()
            .to_string();
        assert!(e.contains("not a regular file"), "{e}");
    }

    #[test]
    fn space_is_checked_unless_forced() {
        let t = tempfile::tempdir().unwrap();
        let out = t.path().join("o.h5");
        let budget = |total: f64, start: f64| Budget {
            steps: 1,
            output_steps: 1,
            output_bytes: total,
            step_bytes: 1.0,
            start_bytes: start,
        };
        assert!(check_space(&out, &budget(1.0, 1.0), 0, "1 step", false).is_ok());
        let e = check_space(&out, &budget(1e30, 1.0), 0, "many steps", false)
            .unwrap_err()
            .to_string();
        assert!(e.contains("would write about") && e.contains("--force"), "{e}");
        assert!(check_space(&out, &budget(1e30, 1.0), 0, "many steps", true).is_ok());
        let e = check_space(&out, &budget(1e30, 1e30), 0, "many steps", true)
            .unwrap_err()
            .to_string();
        assert!(e.contains("not even --force starts"), "{e}");
        assert_eq!(
            restart_command(Path::new("s.toml"), Path::new("o.h5"), 2, &[]),
            "mpirun -n 2 eprop run s.toml --restart o.h5"
        );
        assert_eq!(
            restart_command(Path::new("a b.toml"), Path::new("o.h5"), 1, &["--steps 9".into()]),
            "eprop run 'a b.toml' --restart o.h5 --steps 9"
        );
    }
}
