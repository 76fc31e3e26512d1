//! Last-resort monitor: polls `/proc` every `scan_interval` and diffs the
//! process table. A pid that appears (or whose start time changed) is
//! reported as Exec, a pid that vanished as Exit, a pid whose `comm` changed
//! as Exec (an `execve` in place); zombies count as exited. Processes that live shorter than one
//! interval can be missed, and exit codes are unknown; timestamps are the
//! time of the scan. The first scan is the baseline and reports nothing.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use tokio::sync::mpsc;
use tokio::time::MissedTickBehavior;

use crate::event::{
    MonitorKind, ProcEvent, ProcEventKind, StatInfo, monotonic_now_ns, read_cgroup, read_exe,
    read_stat,
};
use crate::{MonitorConfig, Shared, Started};

/// Errors of the /proc scan monitor.
#[derive(Debug, thiserror::Error)]
pub enum ScanError {
    #[error("reading process list {path}")]
    ReadDir {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path} lists no processes (is procfs mounted there?)")]
    Empty { path: PathBuf },
    #[error("scan interval must be positive")]
    ZeroInterval,
    #[error("/proc scan worker thread failed")]
    Worker(#[source] tokio::task::JoinError),
}

/// Pid → what the last scan saw.
pub(crate) type Snapshot = HashMap<u32, StatInfo>;

/// A difference between two snapshots.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Change {
    /// New pid, a reused pid, or an exec in place.
    Exec(u32),
    /// Pid gone (or reused: then an Exec of the same pid follows).
    Exit(u32),
}

/// Compares two snapshots; exits come before execs so a reused pid reads
/// Exit then Exec. Pure.
pub(crate) fn diff(old: &Snapshot, new: &Snapshot) -> Vec<Change> {
    let mut exits = Vec::new();
    let mut execs = Vec::new();
    for (pid, before) in old {
        match new.get(pid) {
            None => exits.push(*pid),
            Some(now) if now.starttime != before.starttime => {
                exits.push(*pid);
                execs.push(*pid);
            }
            Some(now) if now.comm != before.comm => execs.push(*pid),
            Some(_) => {}
        }
    }
    execs.extend(new.keys().filter(|pid| !old.contains_key(pid)));
    exits.sort_unstable();
    execs.sort_unstable();
    exits
        .into_iter()
        .map(Change::Exit)
        .chain(execs.into_iter().map(Change::Exec))
        .collect()
}

/// Reads every process's stat under `proc_root`.
pub(crate) fn snapshot(proc_root: &Path) -> Result<Snapshot, ScanError> {
    let entries = std::fs::read_dir(proc_root).map_err(|source| ScanError::ReadDir {
        path: proc_root.to_path_buf(),
        source,
    })?;
    let mut snap = Snapshot::new();
    for entry in entries.flatten() {
        let Some(pid) = entry
            .file_name()
            .to_str()
            .and_then(|n| n.parse::<u32>().ok())
        else {
            continue;
        };
        // A process may vanish between read_dir and read: skip it. A zombie
        // has exited already (only its parent has not reaped it): skip it too.
        if let Some(info) = read_stat(proc_root, pid).filter(|i| !matches!(i.state, 'Z' | 'X')) {
            snap.insert(pid, info);
        }
    }
    Ok(snap)
}

/// Builds the events for `changes`.
fn events(proc_root: &Path, old: &Snapshot, new: &Snapshot, changes: &[Change]) -> Vec<ProcEvent> {
    let now = monotonic_now_ns();
    changes
        .iter()
        .filter_map(|change| match change {
            Change::Exit(pid) => {
                let info = old.get(pid)?;
                Some(ProcEvent {
                    kind: ProcEventKind::Exit,
                    pid: *pid,
                    ppid: Some(info.ppid),
                    comm: Some(info.comm.clone()),
                    filename: None,
                    cgroup_id: None,
                    cgroup: None,
                    exit_code: None,
                    timestamp_ns: now,
                    source: MonitorKind::ProcScan,
                })
            }
            Change::Exec(pid) => {
                let info = new.get(pid)?;
                Some(ProcEvent {
                    kind: ProcEventKind::Exec,
                    pid: *pid,
                    ppid: Some(info.ppid),
                    comm: Some(info.comm.clone()),
                    filename: read_exe(proc_root, *pid),
                    cgroup_id: None,
                    cgroup: read_cgroup(proc_root, *pid),
                    exit_code: None,
                    timestamp_ns: now,
                    source: MonitorKind::ProcScan,
                })
            }
        })
        .collect()
}

pub(crate) async fn start(
    config: &MonitorConfig,
    tx: mpsc::Sender<ProcEvent>,
    shared: Arc<Shared>,
) -> Result<Started, ScanError> {
    if config.scan_interval.is_zero() {
        return Err(ScanError::ZeroInterval);
    }
    let proc_root = config.proc_root.clone();
    let root = proc_root.clone();
    let baseline = tokio::task::spawn_blocking(move || snapshot(&root))
        .await
        .map_err(ScanError::Worker)??;
    if baseline.is_empty() {
        return Err(ScanError::Empty { path: proc_root });
    }
    let interval = config.scan_interval;
    let task = tokio::spawn(async move {
        let mut ticker = tokio::time::interval(interval);
        ticker.set_missed_tick_behavior(MissedTickBehavior::Delay);
        ticker.tick().await; // the first tick is immediate
        let mut old = baseline;
        loop {
            ticker.tick().await;
            let root = proc_root.clone();
            let step = tokio::task::spawn_blocking(move || {
                let new = snapshot(&root)?;
                let changes = diff(&old, &new);
                let events = events(&root, &old, &new, &changes);
                Ok::<_, ScanError>((new, events))
            })
            .await;
            let (new, events) = match step {
                Ok(Ok(step)) => step,
                Ok(Err(err)) => {
                    shared.fail(crate::error_chain(&err));
                    return;
                }
                Err(err) => {
                    shared.fail(crate::error_chain(&ScanError::Worker(err)));
                    return;
                }
            };
            old = new;
            for event in events {
                if tx.send(event).await.is_err() {
                    return;
                }
            }
        }
    });
    Ok(Started {
        task,
        lost_counter: None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn info(comm: &str, starttime: u64) -> StatInfo {
        StatInfo {
            comm: comm.into(),
            state: 'S',
            ppid: 1,
            starttime,
        }
    }

    #[test]
    fn diff_reports_new_gone_reused_and_exec_in_place() {
        let old: Snapshot = [
            (10, info("bash", 5)),
            (11, info("gone", 6)),
            (12, info("old", 7)),
            (13, info("sh", 8)),
        ]
        .into();
        let new: Snapshot = [
            (10, info("bash", 5)),
            (12, info("reused", 99)),
            (13, info("true", 8)),
            (14, info("new", 100)),
        ]
        .into();
        assert_eq!(
            diff(&old, &new),
            vec![
                Change::Exit(11),
                Change::Exit(12),
                Change::Exec(12),
                Change::Exec(13),
                Change::Exec(14),
            ]
        );
        assert!(diff(&new, &new).is_empty());
    }

    #[test]
    fn snapshot_of_real_proc_contains_self() {
        let snap = snapshot(Path::new("/proc")).expect("reads /proc");
        let me = snap.get(&std::process::id()).expect("own pid listed");
        assert!(me.starttime > 0);
    }

    #[test]
    fn snapshot_of_missing_dir_names_path() {
        let err = snapshot(Path::new("/nonexistent/configbot-proc")).expect_err("fails");
        assert!(err.to_string().contains("/nonexistent/configbot-proc"));
    }
}
