//! The crate's error type: every IO error names the file and, for writes, the value.

use std::path::PathBuf;

/// Result alias for this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Errors of the cgroups crate.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("invalid node name {name:?}: {reason}")]
    InvalidName { name: String, reason: &'static str },
    #[error("invalid subtree root {root:?}: {reason}")]
    InvalidRoot { root: String, reason: &'static str },
    #[error("invalid cpu limit for {node}: {reason}")]
    InvalidLimit { node: String, reason: String },
    #[error("cannot write {value:?} to {path}")]
    Write {
        path: PathBuf,
        value: String,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot read {path}")]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot create cgroup {path}")]
    Create {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot remove cgroup {path}")]
    Remove {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot parse {path}: {reason}")]
    Parse { path: PathBuf, reason: String },
    #[error("no cgroup hierarchy with a cpu controller found")]
    NoCpuController,
    #[error("read back {path} gave {got:?}, wrote {wanted:?}")]
    ReadBack {
        path: PathBuf,
        wanted: String,
        got: String,
    },
    #[error(
        "apply failed at node {node} (rolled back {rolled_back} node(s), {rollback_failures} rollback failure(s))"
    )]
    Apply {
        node: String,
        rolled_back: usize,
        rollback_failures: usize,
        #[source]
        source: Box<Error>,
    },
}

impl Error {
    /// A read of a file that does not exist (its cgroup is gone or was never made).
    pub fn is_not_found(&self) -> bool {
        matches!(self, Error::Read { source, .. } if source.kind() == std::io::ErrorKind::NotFound)
    }

    /// A removal refused because the cgroup still holds a task (`EBUSY`).
    pub fn is_busy(&self) -> bool {
        matches!(self, Error::Remove { source, .. } if source.kind() == std::io::ErrorKind::ResourceBusy)
    }
}
