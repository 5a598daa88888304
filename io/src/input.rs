//! Reading an input file whole, for every file eprop reads (meshes, scenarios, tables).
//!
//! Only regular files are read (after following symbolic links): a FIFO would block the reader
//! forever and a device such as `/dev/zero` never ends. Every failure is a message naming the
//! file, what is wrong and a fix: missing file, dangling link, link loop, directory or special
//! file, permissions, and not enough memory for the file's size.

use anyhow::{anyhow, Result};
use std::io::{ErrorKind, Read};
use std::path::Path;

/// `ELOOP` (too many levels of symbolic links) of the system; None where it is not known here
/// (a loop is then reported in the system's words).
const ELOOP: Option<i32> = if cfg!(any(target_os = "linux", target_os = "android")) {
    Some(40)
} else if cfg!(any(
    target_vendor = "apple",
    target_os = "freebsd",
    target_os = "netbsd",
    target_os = "openbsd",
    target_os = "dragonfly"
)) {
    Some(62)
} else {
    None
};

/// Reads a whole input file. `role` names it in messages ("mesh", "scenario", "table", ...).
pub fn read_input_file(path: &Path, role: &str) -> Result<Vec<u8>> {
    let shown = path.display();
    let meta = std::fs::metadata(path).map_err(|e| open_error(path, role, &e))?;
    check_regular(path, role, &meta)?;
    let mut f = std::fs::File::open(path).map_err(|e| open_error(path, role, &e))?;
    // the file that was opened, which may not be the one looked at a moment ago
    let meta = f.metadata().map_err(|e| open_error(path, role, &e))?;
    check_regular(path, role, &meta)?;
    let len = meta.len();
    let mut bytes = Vec::new();
    usize::try_from(len)
        .ok()
        .and_then(|n| bytes.try_reserve_exact(n).ok())
        .ok_or_else(|| out_of_memory(path, len))?;
    f.read_to_end(&mut bytes).map_err(|e| match e.kind() {
        ErrorKind::OutOfMemory => out_of_memory(path, len),
        _ => anyhow!("{shown}: cannot read: {e}; fix: check the file and the disk it is on"),
    })?;
    Ok(bytes)
}

/// Reads a whole input file as UTF-8 text.
pub fn read_input_text(path: &Path, role: &str) -> Result<String> {
    let bytes = read_input_file(path, role)?;
    String::from_utf8(bytes).map_err(|e| {
        let b = e.as_bytes();
        let at = e.utf8_error().valid_up_to();
        let line = b[..at].iter().filter(|&&c| c == b'\n').count() + 1;
        anyhow!(
            "{}:{line}: not UTF-8 text (byte {at}); fix: save the {role} file as UTF-8 text",
            path.display()
        )
    })
}

fn out_of_memory(path: &Path, len: u64) -> anyhow::Error {
    anyhow!(
        "{}: not enough memory to read it ({len} bytes); fix: free memory or use a machine with more",
        path.display()
    )
}

/// Refuses anything but a regular file, saying what it is.
fn check_regular(path: &Path, role: &str, meta: &std::fs::Metadata) -> Result<()> {
    let t = meta.file_type();
    if t.is_file() {
        return Ok(());
    }
    let what = if t.is_dir() { "a directory" } else { special_kind(&t) };
    Err(anyhow!(
        "{}: is {what}, not a regular file; fix: give the path of a {role} file (eprop reads only regular files: copy data from a pipe or device into a file first)",
        path.display()
    ))
}

/// What a file that is not a regular file or a directory is, for a message ("a FIFO (named
/// pipe)", "a character device", ...).
#[cfg(unix)]
pub fn special_kind(t: &std::fs::FileType) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    if t.is_fifo() {
        "a FIFO (named pipe)"
    } else if t.is_char_device() {
        "a character device"
    } else if t.is_block_device() {
        "a block device"
    } else if t.is_socket() {
        "a socket"
    } else {
        "a special file"
    }
}

#[cfg(not(unix))]
pub fn special_kind(_: &std::fs::FileType) -> &'static str {
    "a special file"
}

/// Why a file could not be looked at or opened.
fn open_error(path: &Path, role: &str, e: &std::io::Error) -> anyhow::Error {
    let shown = path.display();
    if e.raw_os_error().is_some() && e.raw_os_error() == ELOOP {
        return anyhow!(
            "{shown}: is a symbolic link loop (following it leads back to a link already followed); fix: point the link at the {role} file"
        );
    }
    match e.kind() {
        ErrorKind::NotFound => match std::fs::read_link(path) {
            Ok(target) => anyhow!(
                "{shown}: is a symbolic link to {}, which does not exist; fix: point the link at the {role} file",
                target.display()
            ),
            Err(_) => anyhow!(
                "{shown}: no such {role} file; fix: check the path (relative paths in a scenario are relative to the scenario file)"
            ),
        },
        ErrorKind::PermissionDenied => anyhow!("{shown}: cannot read: {e}; fix: check the permissions"),
        ErrorKind::OutOfMemory => anyhow!("{shown}: cannot read: {e}; fix: free memory or use a machine with more"),
        _ => anyhow!("{shown}: cannot read: {e}; fix: check the path and the file"),
    }
}

#[cfg(all(test, unix))]
mod tests {
    use super::*;

    fn err(p: &Path) -> String {
        format!("{:#}", read_input_file(p, "mesh").unwrap_err())
    }

    #[test]
    fn refuses_what_is_not_a_regular_file() {
        let t = tempfile::tempdir().unwrap();
        let d = t.path();
        let ok = d.join("a.msh");
        std::fs::write(&ok, b"abc").unwrap();
        assert_eq!(read_input_file(&ok, "mesh").unwrap(), b"abc");
        let via = d.join("via.msh");
        std::os::unix::fs::symlink(&ok, &via).unwrap();
        assert_eq!(read_input_file(&via, "mesh").unwrap(), b"abc");
        let e = err(d);
        assert!(e.contains("is a directory") && e.contains("fix:"), "{e}");
        let zero = d.join("zero.msh");
        std::os::unix::fs::symlink("/dev/zero", &zero).unwrap();
        let e = err(&zero);
        assert!(
            e.contains("character device") && e.contains("zero.msh") && e.contains("fix:"),
            "{e}"
        );
        let (l1, l2) = (d.join("l1.msh"), d.join("l2.msh"));
        std::os::unix::fs::symlink(&l2, &l1).unwrap();
        std::os::unix::fs::symlink(&l1, &l2).unwrap();
        let e = err(&l1);
        assert!(e.contains("symbolic link loop") && e.contains("fix:"), "{e}");
        let dangling = d.join("dangling.msh");
        std::os::unix::fs::symlink(d.join("gone.msh"), &dangling).unwrap();
        let e = err(&dangling);
        assert!(e.contains("gone.msh, which does not exist"), "{e}");
        let e = err(&d.join("missing.msh"));
        assert!(e.contains("no such mesh file") && e.contains("fix:"), "{e}");
        std::fs::write(d.join("t.toml"), b"a = 1\n\xff\n").unwrap();
        let e = format!("{:#}", read_input_text(&d.join("t.toml"), "scenario").unwrap_err());
        assert!(e.contains("t.toml:2: not UTF-8"), "{e}");
    }
}
