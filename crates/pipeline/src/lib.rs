//! vdbcook's orchestration below the binary: input expansion (files,
//! directories, globs, frame patterns), grid choice, frames fed from files to
//! the [`vdbcook_cook::Cooker`], the lossless reference a comparison needs, the
//! sources an asset records, and the typed cook settings (`options`) that both
//! `vdbcook cook`'s flags and bake manifests are built from.
//!
//! No terminal, no exit codes: progress goes through [`vdbcook_cook::Progress`],
//! failures are an [`Error`] whose [`Error::is_usage`] tells the caller's
//! usage errors from the rest.

pub mod auto;
mod check;
pub mod cook;
pub mod grids;
pub mod inputs;
pub mod options;
pub mod recorded;
pub mod source_time;
pub mod summary;

pub use check::{validate_file, Sources};
pub use cook::{cook_asset, cook_formats, cook_lossless_levels, feed, selection_of, CookJob, Cooked};
pub use grids::{Channels, FrameFile, GridSelection};
pub use options::{CookSettings, FrameRange, SettingError};

type BoxError = Box<dyn std::error::Error + Send + Sync>;

/// Why a job failed. The messages are the user's (one line each, the
/// context first, as `vdbcook: error:` prints them).
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The caller's settings or arguments are at fault (the CLI exits with 2).
    #[error("{0}")]
    Usage(String),
    #[error("{0}")]
    Failed(String),
    /// What failed (a file, a frame), and why.
    #[error("{0}")]
    In(String, #[source] Box<Error>),
    #[error(transparent)]
    Compare(#[from] vdbcook_validate::CompareError),
    #[error(transparent)]
    Other(BoxError),
}

impl Error {
    /// Whether the caller's settings or arguments were at fault.
    pub fn is_usage(&self) -> bool {
        match self {
            Error::Usage(_) => true,
            Error::In(_, e) => e.is_usage(),
            Error::Compare(e) => e.is_usage(),
            _ => false,
        }
    }
}

macro_rules! from_other {
    ($($t:ty),*) => {$( impl From<$t> for Error { fn from(e: $t) -> Self { Error::Other(Box::new(e)) } } )*};
}
from_other!(std::io::Error, vdbcook_vdb::Error, vdbcook_vpak::Error, vdbcook_validate::Error, glob::PatternError);

/// A cook error in the settings (channel groups, grids whose voxel sizes do
/// not combine) is the caller's fault.
impl From<vdbcook_cook::Error> for Error {
    fn from(e: vdbcook_cook::Error) -> Self {
        match e.is_settings_error() {
            true => Error::Usage(e.to_string()),
            false => Error::Other(Box::new(e)),
        }
    }
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Adds what failed to an error (as `anyhow::Context` does).
pub trait Context<T> {
    fn context<C: std::fmt::Display>(self, c: C) -> Result<T>;
    fn with_context<C: std::fmt::Display, F: FnOnce() -> C>(self, f: F) -> Result<T>;
}

impl<T, E: Into<Error>> Context<T> for std::result::Result<T, E> {
    fn context<C: std::fmt::Display>(self, c: C) -> Result<T> {
        self.map_err(|e| Error::In(c.to_string(), Box::new(e.into())))
    }
    fn with_context<C: std::fmt::Display, F: FnOnce() -> C>(self, f: F) -> Result<T> {
        self.map_err(|e| Error::In(f().to_string(), Box::new(e.into())))
    }
}

/// Whether `path` is a .vpak asset or a part of one (its header says so), whatever its name.
pub fn is_vpak(path: &std::path::Path) -> bool {
    use std::io::Read;
    let mut magic = [0u8; 8];
    std::fs::File::open(path).and_then(|mut f| f.read_exact(&mut magic)).is_ok() && (magic == vdbcook_vpak::MAGIC || magic == vdbcook_vpak::segments::PART_MAGIC)
}

/// The error and its causes joined by ": ", each fact once: a context that the
/// next cause repeats at its start (a path, "/out/a.vpak" before "/out/a.vpak
/// already exists") and a cause that the message before it already ends with
/// (an error whose text includes its source's) are left out.
pub fn one_line(err: &(dyn std::error::Error + 'static)) -> String {
    let parts: Vec<String> = std::iter::successors(Some(err), |e| e.source()).map(|e| e.to_string().replace('\n', " ")).collect();
    let mut kept: Vec<&str> = Vec::new();
    for (i, p) in parts.iter().enumerate() {
        if p.is_empty() || kept.last().is_some_and(|k| k.ends_with(p.as_str())) {
            continue;
        }
        if parts.get(i + 1).is_some_and(|n| n == p || n.starts_with(&format!("{p} "))) {
            continue;
        }
        kept.push(p);
    }
    kept.join(": ")
}
