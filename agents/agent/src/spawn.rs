//! Starting a `run` node's process inside its cgroup before its first instruction.
//!
//! The parent opens the node's `cgroup.procs` files (close-on-exec) and the
//! log file; the forked child, still running agent code, writes `0` ("me")
//! into each procs file, starts a new session (so signals reach its whole
//! process group and the agent's death does not), gives the stop signals
//! back their default action, drops to the configured user, and only then
//! execs. There is no window in which the node runs
//! outside its cgroup. Output goes straight to an O_APPEND log file, not a
//! pipe, so a node keeps running (and logging) when the agent is killed.

use std::fs::{File, OpenOptions};
use std::os::fd::AsRawFd;
use std::path::PathBuf;
use std::process::Stdio;

use crate::error::{Error, Result};
use crate::procfs::lookup_user;
use crate::spec::RunSpec;

/// Opens the log file for appending, creating its directory.
pub fn open_log(path: &PathBuf) -> Result<File> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|source| Error::Io {
            path: dir.to_path_buf(),
            source,
        })?;
    }
    OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .map_err(|source| Error::Io {
            path: path.clone(),
            source,
        })
}

/// Signals a child starts with at their default action, whatever the agent
/// inherited: those the agent stops its children with, and the terminal's.
/// An ignored signal stays ignored across exec, and a shell cannot trap one
/// it started with ignored (nor Python turn it into KeyboardInterrupt): an
/// agent started in the background by a script (`cmd &` ignores SIGINT)
/// would otherwise hand every node and recorder a SIGINT that cannot stop
/// it gracefully. Children start as under init.
const STOP_SIGNALS: [i32; 4] = [libc::SIGINT, libc::SIGTERM, libc::SIGQUIT, libc::SIGHUP];

/// Sets [`STOP_SIGNALS`] to their default action. Async-signal-safe: for a
/// forked child before exec.
fn reset_stop_signals() -> std::io::Result<()> {
    for sig in STOP_SIGNALS {
        #[allow(unsafe_code)]
        // SAFETY: signal(2) is async-signal-safe; SIG_DFL installs no handler.
        if unsafe { libc::signal(sig, libc::SIG_DFL) } == libc::SIG_ERR {
            return Err(std::io::Error::last_os_error());
        }
    }
    Ok(())
}

/// Has `cmd`'s child start with [`STOP_SIGNALS`] at their default action.
pub(crate) fn default_stop_signals(cmd: &mut tokio::process::Command) {
    #[allow(unsafe_code)]
    // SAFETY: the closure runs in the forked child before exec and calls
    // only signal(2) (see `reset_stop_signals`).
    unsafe {
        cmd.pre_exec(reset_stop_signals);
    }
}

/// Spawns `spec` so that it joins the cgroup(s) behind `join_files` before exec.
pub fn spawn_in_cgroup(
    spec: &RunSpec,
    join_files: &[PathBuf],
    log: &PathBuf,
) -> Result<tokio::process::Child> {
    let ids = match &spec.user {
        None => None,
        Some(u) => {
            let passwd = std::fs::read_to_string("/etc/passwd").map_err(|source| Error::Io {
                path: "/etc/passwd".into(),
                source,
            })?;
            Some(lookup_user(&passwd, u).ok_or_else(|| Error::UnknownUser(u.clone()))?)
        }
    };
    let procs: Vec<File> = join_files
        .iter()
        .map(|p| {
            OpenOptions::new()
                .write(true)
                .open(p)
                .map_err(|source| Error::Io {
                    path: p.clone(),
                    source,
                })
        })
        .collect::<Result<_>>()?;
    let fds: Vec<i32> = procs.iter().map(AsRawFd::as_raw_fd).collect();
    let out = open_log(log)?;
    let err = out.try_clone().map_err(|source| Error::Io {
        path: log.clone(),
        source,
    })?;

    let mut cmd = tokio::process::Command::new(&spec.command);
    cmd.args(&spec.args)
        .envs(&spec.env)
        .stdin(Stdio::null())
        .stdout(Stdio::from(out))
        .stderr(Stdio::from(err));
    if let Some(dir) = &spec.working_dir {
        cmd.current_dir(dir);
    }
    #[allow(unsafe_code)]
    // SAFETY: the closure runs in the forked child before exec, where only
    // async-signal-safe calls are allowed. It calls only write(2), setsid(2),
    // signal(2), setgroups(2), setgid(2) and setuid(2) on values prepared in the parent
    // (fds kept open by `procs` until spawn returns, plain integers); it does
    // not allocate, lock, or touch Rust-managed state.
    unsafe {
        cmd.pre_exec(move || {
            for &fd in &fds {
                if libc::write(fd, b"0".as_ptr().cast(), 1) != 1 {
                    return Err(std::io::Error::last_os_error());
                }
            }
            if libc::setsid() < 0 {
                return Err(std::io::Error::last_os_error());
            }
            reset_stop_signals()?;
            if let Some((uid, gid)) = ids
                && (libc::setgroups(1, &gid) != 0
                    || libc::setgid(gid) != 0
                    || libc::setuid(uid) != 0)
            {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    let child = cmd.spawn().map_err(|source| Error::Spawn {
        command: spec.command.clone(),
        source,
    })?;
    drop(procs);
    Ok(child)
}

/// Rotates `path` when it exceeds `max_bytes`: `.N-1`→`.N`, …, copy to `.1`,
/// truncate in place (the child keeps its O_APPEND descriptor). Lines written
/// between copy and truncate may be lost; the bound is what matters here.
pub fn rotate_if_needed(path: &PathBuf, max_bytes: u64, keep: u32) -> std::io::Result<bool> {
    let len = match std::fs::metadata(path) {
        Ok(m) => m.len(),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(false),
        Err(e) => return Err(e),
    };
    if len <= max_bytes {
        return Ok(false);
    }
    let numbered = |k: u32| {
        let mut p = path.clone().into_os_string();
        p.push(format!(".{k}"));
        PathBuf::from(p)
    };
    if keep > 0 {
        for k in (1..keep).rev() {
            let from = numbered(k);
            if from.exists() {
                std::fs::rename(&from, numbered(k + 1))?;
            }
        }
        std::fs::copy(path, numbered(1))?;
    }
    OpenOptions::new().write(true).open(path)?.set_len(0)?;
    Ok(true)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotation_keeps_a_bounded_number_of_files() {
        let dir = tempfile::tempdir().unwrap();
        let log = dir.path().join("n.log");
        for round in 0..5u8 {
            std::fs::write(&log, vec![b'a' + round; 100]).unwrap();
            assert!(rotate_if_needed(&log, 50, 2).unwrap());
        }
        assert!(!rotate_if_needed(&log, 50, 2).unwrap());
        let mut names: Vec<String> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        names.sort();
        assert_eq!(names, ["n.log", "n.log.1", "n.log.2"]);
        assert_eq!(std::fs::read(dir.path().join("n.log.1")).unwrap()[0], b'e');
        assert_eq!(std::fs::read(dir.path().join("n.log.2")).unwrap()[0], b'd');
        assert_eq!(std::fs::metadata(&log).unwrap().len(), 0);
    }
}
