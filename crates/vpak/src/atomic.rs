//! Writing a file whole or not at all.

use crate::{write_to, Error, Section};
use std::path::Path;

/// Writes `bytes` to `path` atomically (see [`write_atomic_with`]).
pub fn write_atomic(path: &Path, bytes: &[u8], overwrite: bool) -> Result<(), Error> {
    write_atomic_with(path, overwrite, |w| w.write_all(bytes))
}

/// Writes `sections` as a .vpak file at `path` atomically.
pub fn write_file(path: &Path, sections: &[Section], overwrite: bool) -> Result<(), Error> {
    write_atomic_with(path, overwrite, |w| write_to(w, sections))
}

/// Writes to a temporary file beside `path`, then puts it in place. Where the
/// system has unnamed temporary files (Linux: `O_TMPFILE`, linked in through
/// `/proc/self/fd`), the data has no name until it is complete, so a process
/// that dies meanwhile (out of memory, a signal) leaves nothing behind;
/// elsewhere it is a hidden file beside `path`, removed on any failure.
/// Without `overwrite`, an existing `path` is never replaced; on any failure
/// `path` is untouched.
pub fn write_atomic_with(path: &Path, overwrite: bool, fill: impl FnOnce(&mut dyn std::io::Write) -> std::io::Result<()>) -> Result<(), Error> {
    if !overwrite && path.exists() {
        return Err(Error::Exists(path.display().to_string()));
    }
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    match unnamed::create(dir) {
        Some(file) => {
            let file = filled(file, fill)?;
            if overwrite {
                // A name for the instant between the link and the rename.
                let tmp = temp_name(dir, path);
                unnamed::link(&file, &tmp)?;
                std::fs::rename(&tmp, path).inspect_err(|_| {
                    let _ = std::fs::remove_file(&tmp);
                })?;
            } else {
                // Linking fails if `path` appeared meanwhile: no clobbering, even racing.
                unnamed::link(&file, path).map_err(|e| if e.kind() == std::io::ErrorKind::AlreadyExists { Error::Exists(path.display().to_string()) } else { Error::Io(e) })?;
            }
            Ok(())
        }
        None => write_named(path, dir, overwrite, fill),
    }
}

/// `fill`s `file` through a buffer, then flushes and syncs it.
fn filled(file: std::fs::File, fill: impl FnOnce(&mut dyn std::io::Write) -> std::io::Result<()>) -> Result<std::fs::File, Error> {
    use std::io::Write;
    let mut f = std::io::BufWriter::with_capacity(1 << 20, file);
    fill(&mut f)?;
    f.flush()?;
    let f = f.into_inner().map_err(|e| Error::Io(e.into_error()))?;
    f.sync_all()?;
    Ok(f)
}

/// A fresh hidden name beside `path` (never an existing file or symlink): pid, time and a counter.
fn temp_name(dir: &Path, path: &Path) -> std::path::PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "out".into());
    static SERIAL: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.subsec_nanos());
    let serial = SERIAL.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    dir.join(format!(".{name}.{}-{nanos}-{serial}.tmp", std::process::id()))
}

/// The portable way: a hidden named file, renamed (or linked) into place.
fn write_named(path: &Path, dir: &Path, overwrite: bool, fill: impl FnOnce(&mut dyn std::io::Write) -> std::io::Result<()>) -> Result<(), Error> {
    let tmp = temp_name(dir, path);
    let result = (|| -> Result<(), Error> {
        let file = std::fs::OpenOptions::new().write(true).create_new(true).open(&tmp)?;
        drop(filled(file, fill)?);
        if overwrite {
            std::fs::rename(&tmp, path)?;
        } else {
            // A hard link fails if `path` appeared meanwhile: no clobbering, even racing.
            match std::fs::hard_link(&tmp, path) {
                Ok(()) => std::fs::remove_file(&tmp)?,
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => return Err(Error::Exists(path.display().to_string())),
                // File systems without hard links: check, then rename.
                Err(_) if !path.exists() => std::fs::rename(&tmp, path)?,
                Err(_) => return Err(Error::Exists(path.display().to_string())),
            }
        }
        Ok(())
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// Unnamed temporary files (Linux).
mod unnamed {
    use std::path::Path;

    /// An unnamed file in `dir`, where the system and the file system have them
    /// (and `/proc/self/fd`, through which it gets its name).
    #[cfg(target_os = "linux")]
    pub fn create(dir: &Path) -> Option<std::fs::File> {
        use std::os::unix::fs::OpenOptionsExt;
        if !Path::new("/proc/self/fd").is_dir() {
            return None;
        }
        std::fs::OpenOptions::new().write(true).mode(0o666).custom_flags(libc::O_TMPFILE).open(dir).ok()
    }

    #[cfg(not(target_os = "linux"))]
    pub fn create(_dir: &Path) -> Option<std::fs::File> {
        None
    }

    /// Gives the unnamed `file` the name `path` (which must not exist).
    #[cfg(target_os = "linux")]
    pub fn link(file: &std::fs::File, path: &Path) -> std::io::Result<()> {
        use std::os::unix::ffi::OsStrExt;
        use std::os::unix::io::AsRawFd;
        let src = std::ffi::CString::new(format!("/proc/self/fd/{}", file.as_raw_fd()))?;
        let dst = std::ffi::CString::new(path.as_os_str().as_bytes())?;
        // SAFETY: two NUL-terminated paths that live across the call.
        match unsafe { libc::linkat(libc::AT_FDCWD, src.as_ptr(), libc::AT_FDCWD, dst.as_ptr(), libc::AT_SYMLINK_FOLLOW) } {
            0 => Ok(()),
            _ => Err(std::io::Error::last_os_error()),
        }
    }

    #[cfg(not(target_os = "linux"))]
    pub fn link(_file: &std::fs::File, _path: &Path) -> std::io::Result<()> {
        Err(std::io::ErrorKind::Unsupported.into())
    }
}
