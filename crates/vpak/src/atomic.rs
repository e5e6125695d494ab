//! Writing a file whole or not at all.

use crate::{write_to, Error, Section};
use std::path::{Path, PathBuf};

/// Writes `bytes` to `path` atomically (see [`write_atomic_with`]).
pub fn write_atomic(path: &Path, bytes: &[u8], overwrite: bool) -> Result<(), Error> {
    write_atomic_with(path, overwrite, |w| w.write_all(bytes))
}

/// Writes `sections` as a one-body .vpak file (the version-6 layout) at `path` atomically.
pub fn write_file(path: &Path, sections: &[Section], overwrite: bool) -> Result<(), Error> {
    write_atomic_with(path, overwrite, |w| write_to(w, sections))
}

/// Writes through `fill` into an [`AtomicFile`] for `path`, buffered, then
/// puts it in place.
pub fn write_atomic_with(path: &Path, overwrite: bool, fill: impl FnOnce(&mut dyn std::io::Write) -> std::io::Result<()>) -> Result<(), Error> {
    use std::io::Write;
    let mut out = AtomicFile::create(path, overwrite)?;
    let mut w = std::io::BufWriter::with_capacity(1 << 20, out.file());
    fill(&mut w)?;
    w.flush()?;
    drop(w);
    out.commit()
}

/// A file that gets its name only once it is complete. Where the system has
/// unnamed temporary files (Linux: `O_TMPFILE`, linked in through
/// `/proc/self/fd`), the data has no name until [`AtomicFile::commit`], so a
/// process that dies meanwhile (out of memory, a signal) leaves nothing
/// behind; elsewhere it is a hidden file beside `path`, removed when the
/// `AtomicFile` is dropped uncommitted. Without `overwrite`, an existing
/// `path` is never replaced; on any failure `path` is untouched.
pub struct AtomicFile {
    file: std::fs::File,
    path: PathBuf,
    dir: PathBuf,
    overwrite: bool,
    /// The hidden name of a named temporary file (the portable way).
    named: Option<PathBuf>,
}

impl AtomicFile {
    pub fn create(path: &Path, overwrite: bool) -> Result<AtomicFile, Error> {
        if !overwrite && path.exists() {
            return Err(Error::Exists(path.display().to_string()));
        }
        let dir = directory_of(path);
        let (file, named) = match unnamed::create(&dir) {
            Some(f) => (f, None),
            None => {
                let tmp = temp_name(&dir, path);
                (std::fs::OpenOptions::new().read(true).write(true).create_new(true).open(&tmp)?, Some(tmp))
            }
        };
        Ok(AtomicFile { file, path: path.to_path_buf(), dir, overwrite, named })
    }

    /// The file to write (and seek in, and read back).
    pub fn file(&mut self) -> &mut std::fs::File {
        &mut self.file
    }

    /// Syncs the file and gives it its name.
    pub fn commit(mut self) -> Result<(), Error> {
        self.file.sync_all()?;
        let path = self.path.clone();
        let exists = || Error::Exists(path.display().to_string());
        match self.named.take() {
            None if self.overwrite => {
                // A name for the instant between the link and the rename.
                let tmp = temp_name(&self.dir, &path);
                unnamed::link(&self.file, &tmp)?;
                std::fs::rename(&tmp, &path).inspect_err(|_| {
                    let _ = std::fs::remove_file(&tmp);
                })?;
            }
            // Linking fails if `path` appeared meanwhile: no clobbering, even racing.
            None => unnamed::link(&self.file, &path).map_err(|e| if e.kind() == std::io::ErrorKind::AlreadyExists { exists() } else { Error::Io(e) })?,
            Some(tmp) => {
                let placed = if self.overwrite {
                    std::fs::rename(&tmp, &path).map_err(Error::from)
                } else {
                    match std::fs::hard_link(&tmp, &path) {
                        Ok(()) => Ok(()),
                        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => Err(exists()),
                        // File systems without hard links: check, then rename.
                        Err(_) if !path.exists() => std::fs::rename(&tmp, &path).map_err(Error::from),
                        Err(_) => Err(exists()),
                    }
                };
                let _ = std::fs::remove_file(&tmp);
                placed?;
            }
        }
        Ok(())
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        if let Some(tmp) = &self.named {
            let _ = std::fs::remove_file(tmp);
        }
    }
}

/// The directory a file at `path` goes in (`.` for a bare name): where its
/// temporary files go too.
pub fn directory_of(path: &Path) -> PathBuf {
    path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new(".")).to_path_buf()
}

/// A fresh hidden name beside `path` (never an existing file or symlink): pid, time and a counter.
fn temp_name(dir: &Path, path: &Path) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "out".into());
    static SERIAL: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.subsec_nanos());
    let serial = SERIAL.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    dir.join(format!(".{name}.{}-{nanos}-{serial}.tmp", std::process::id()))
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
        std::fs::OpenOptions::new().read(true).write(true).mode(0o666).custom_flags(libc::O_TMPFILE).open(dir).ok()
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
