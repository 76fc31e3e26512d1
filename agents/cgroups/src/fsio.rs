//! Small file helpers that attach the path (and value) to every IO error.

use std::fs::OpenOptions;
use std::io::Write;
use std::path::Path;

use crate::error::{Error, Result};

/// Writes `value` to an existing control file in one `write(2)` call, as
/// cgroup files expect. Never creates the file.
pub(crate) fn write_file(path: &Path, value: &str) -> Result<()> {
    let err = |source| Error::Write {
        path: path.to_path_buf(),
        value: value.to_owned(),
        source,
    };
    let mut f = OpenOptions::new()
        .write(true)
        .truncate(true)
        .open(path)
        .map_err(err)?;
    f.write_all(value.as_bytes()).map_err(err)
}

/// Reads a whole control file.
pub(crate) fn read_file(path: &Path) -> Result<String> {
    std::fs::read_to_string(path).map_err(|source| Error::Read {
        path: path.to_path_buf(),
        source,
    })
}

/// Reads a control file that holds one number (`cpu.shares`, `cpu.weight`,
/// `cpuacct.usage`).
pub(crate) fn read_number<T: std::str::FromStr>(path: &Path) -> Result<T>
where
    T::Err: std::fmt::Display,
{
    read_file(path)?.trim().parse().map_err(|e| Error::Parse {
        path: path.to_path_buf(),
        reason: format!("{e}"),
    })
}

/// Parses a file of one integer per line (`cgroup.procs`, `tasks`).
pub(crate) fn read_ids(path: &Path) -> Result<Vec<u32>> {
    let text = read_file(path)?;
    text.lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .map(|l| {
            l.parse::<u32>().map_err(|e| Error::Parse {
                path: path.to_path_buf(),
                reason: format!("bad id {l:?}: {e}"),
            })
        })
        .collect()
}

/// Creates a directory (and parents) if it is missing.
pub(crate) fn create_dir(path: &Path) -> Result<()> {
    std::fs::create_dir_all(path).map_err(|source| Error::Create {
        path: path.to_path_buf(),
        source,
    })
}

/// Removes a cgroup directory; a missing one is fine.
pub(crate) fn remove_dir(path: &Path) -> Result<()> {
    match std::fs::remove_dir(path) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(source) => Err(Error::Remove {
            path: path.to_path_buf(),
            source,
        }),
    }
}
