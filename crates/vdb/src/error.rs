//! The reader's one error type.  Messages are lowercase and say what was
//! found and what was expected; the caller adds the file's path.

#[derive(Debug, thiserror::Error)]
pub enum Error {
    // Transparent: the I/O error is the message and has no source of its own,
    // so a `{:#}` chain prints it once.
    #[error(transparent)]
    Io(#[from] std::io::Error),
    #[error("not an OpenVDB file (magic number {0:#010x}, expected 0x56444220)")]
    NotVdb(u64),
    #[error("unsupported file version {0} (need 220 or newer)")]
    Version(u32),
    #[error("truncated {what}: needs {need} bytes at offset {offset}, only {have} remain")]
    Truncated { what: &'static str, offset: u64, need: u64, have: u64 },
    #[error("implausible {what} {count} at offset {offset} (only {remaining} bytes remain)")]
    Implausible { what: &'static str, count: u64, offset: u64, remaining: u64 },
    #[error("{what} offset {offset} is outside the file ({len} bytes)")]
    BadOffset { what: &'static str, offset: i64, len: u64 },
    #[error("invalid {what} at offset {offset}: {detail}")]
    Invalid { what: &'static str, offset: u64, detail: String },
    #[error("blosc chunk at offset {offset}: {error}")]
    Blosc { offset: u64, error: vdbcook_blosc::Error },
    #[error("zlib chunk at offset {offset}: {detail}")]
    Zip { offset: u64, detail: String },
    #[error("grid \"{grid}\": {error}")]
    InGrid { grid: String, error: Box<Error> },
    #[error("no grid named \"{name}\" (the file has: {available})")]
    NoSuchGrid { name: String, available: String },
    #[error("no scalar float grid to read (the file has: {available})")]
    NoScalarGrid { available: String },
    #[error("grid \"{grid}\" cannot be read: {reason}")]
    Unsupported { grid: String, reason: String },
}

impl Error {
    pub(crate) fn invalid(what: &'static str, offset: usize, detail: impl Into<String>) -> Error {
        Error::Invalid { what, offset: offset as u64, detail: detail.into() }
    }

    pub(crate) fn in_grid(self, grid: &str) -> Error {
        match self {
            e @ Error::InGrid { .. } => e,
            e => Error::InGrid { grid: grid.to_string(), error: Box::new(e) },
        }
    }
}
