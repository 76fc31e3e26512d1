//! Process exec/exit monitor for the ConfigBot node agent.
//!
//! [`ProcessMonitor::start`] tries the monitors in order of preference —
//! eBPF (BTF tracepoints `sched_process_exec`/`sched_process_exit`, ring
//! buffer), then the netlink proc connector, then a periodic /proc scan —
//! and returns a [`MonitorHandle`] (which monitor is active, why the others
//! failed, lost-event count) and an [`EventStream`] of [`ProcEvent`]s.
//! Several monitors may run at once in one process; dropping the handle stops
//! its monitor (BPF programs detach, sockets close).

mod connector;
mod ebpf;
mod event;
mod procscan;

use std::error::Error as StdError;
use std::fmt::Write as _;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use serde::Serialize;
use tokio::sync::mpsc;
use tokio::task::JoinHandle;

pub use connector::ConnectorError;
pub use ebpf::EbpfMonitorError;
pub use event::{
    MonitorKind, ProcEvent, ProcEventKind, StatInfo, monotonic_now_ns, parse_proc_cgroup,
    parse_stat,
};
pub use procscan::ScanError;

/// Stream of process events; `recv()` returns `None` once the monitor stopped.
pub type EventStream = mpsc::Receiver<ProcEvent>;

/// Which monitors to try.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Preference {
    /// eBPF, then proc connector, then /proc scan.
    Auto,
    /// Exactly this monitor (tests, benchmarks, operator override).
    Only(MonitorKind),
    /// These monitors, in this order.
    Order(Vec<MonitorKind>),
}

impl Preference {
    /// The kinds to try, in order.
    pub fn order(&self) -> Vec<MonitorKind> {
        match self {
            Preference::Auto => MonitorKind::ALL.to_vec(),
            Preference::Only(kind) => vec![*kind],
            Preference::Order(kinds) => kinds.clone(),
        }
    }
}

/// Settings of a monitor.
#[derive(Debug, Clone)]
pub struct MonitorConfig {
    pub preference: Preference,
    /// Poll interval of the /proc scan fallback.
    pub scan_interval: Duration,
    /// Capacity of the event channel; a full channel back-pressures the reader
    /// (the kernel side then drops and counts, see [`MonitorHandle::lost_events`]).
    pub channel_capacity: usize,
    /// procfs mount (for `comm`, `ppid`, `exe`, `cgroup` look-ups and the scan).
    pub proc_root: PathBuf,
}

impl Default for MonitorConfig {
    fn default() -> Self {
        MonitorConfig {
            preference: Preference::Auto,
            scan_interval: Duration::from_millis(250),
            channel_capacity: 4096,
            proc_root: PathBuf::from("/proc"),
        }
    }
}

impl MonitorConfig {
    /// Default settings with one preference.
    pub fn with_preference(preference: Preference) -> Self {
        MonitorConfig {
            preference,
            ..MonitorConfig::default()
        }
    }
}

/// A monitor that could not be started, and why.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct FailedAttempt {
    pub kind: MonitorKind,
    pub reason: String,
}

/// Which monitor is active and why the better ones are not.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct MonitorStatus {
    pub active: MonitorKind,
    /// Monitors tried before `active`, best first.
    pub failed: Vec<FailedAttempt>,
}

impl MonitorStatus {
    /// One line for the agent's status, e.g.
    /// `process monitor: proc_scan (ebpf failed: ...; proc_connector failed: ...)`.
    pub fn summary(&self) -> String {
        let mut line = format!("process monitor: {}", self.active);
        if !self.failed.is_empty() {
            let reasons: Vec<String> = self
                .failed
                .iter()
                .map(|f| format!("{} failed: {}", f.kind, f.reason))
                .collect();
            let _ = write!(line, " ({})", reasons.join("; "));
        }
        line
    }
}

/// Errors of [`ProcessMonitor::start`].
#[derive(Debug, thiserror::Error)]
pub enum MonitorError {
    #[error("no process monitor could be started: {}", summarize(.0))]
    NoneAvailable(Vec<FailedAttempt>),
    #[error("process monitor channel capacity must be positive, got {0}")]
    ZeroCapacity(usize),
}

fn summarize(failed: &[FailedAttempt]) -> String {
    failed
        .iter()
        .map(|f| format!("{}: {}", f.kind, f.reason))
        .collect::<Vec<_>>()
        .join("; ")
}

/// Renders an error and its `source()` chain as `a: b: c`.
pub fn error_chain(err: &dyn StdError) -> String {
    let mut text = err.to_string();
    let mut source = err.source();
    while let Some(cause) = source {
        let cause_text = cause.to_string();
        // Some errors (aya's) already print their source: don't repeat it.
        if !text.contains(&cause_text) {
            let _ = write!(text, ": {cause_text}");
        }
        source = cause.source();
    }
    text
}

/// State shared between a backend task and its handle.
#[derive(Debug, Default)]
pub(crate) struct Shared {
    /// Events known to be lost (proc connector `ENOBUFS` overruns count 1 each).
    pub(crate) lost: AtomicU64,
    /// Why the backend task stopped, if it stopped on an error.
    pub(crate) failure: std::sync::Mutex<Option<String>>,
}

impl Shared {
    pub(crate) fn fail(&self, reason: String) {
        if let Ok(mut slot) = self.failure.lock() {
            *slot = Some(reason);
        }
    }
}

/// A started backend.
pub(crate) struct Started {
    pub(crate) task: JoinHandle<()>,
    pub(crate) lost_counter: Option<ebpf::DropCounter>,
}

/// Entry point.
#[derive(Debug)]
pub struct ProcessMonitor;

impl ProcessMonitor {
    /// Starts the first monitor of `config.preference` that works. Must be
    /// called inside a Tokio runtime with IO and time enabled.
    pub async fn start(
        config: MonitorConfig,
    ) -> Result<(MonitorHandle, EventStream), MonitorError> {
        if config.channel_capacity == 0 {
            return Err(MonitorError::ZeroCapacity(config.channel_capacity));
        }
        let mut failed = Vec::new();
        for kind in config.preference.order() {
            let (tx, rx) = mpsc::channel(config.channel_capacity);
            let shared = Arc::new(Shared::default());
            let result = match kind {
                MonitorKind::Ebpf => {
                    ebpf::start(&config, tx, Arc::clone(&shared)).map_err(|e| error_chain(&e))
                }
                MonitorKind::ProcConnector => connector::start(&config, tx, Arc::clone(&shared))
                    .await
                    .map_err(|e| error_chain(&e)),
                MonitorKind::ProcScan => procscan::start(&config, tx, Arc::clone(&shared))
                    .await
                    .map_err(|e| error_chain(&e)),
            };
            match result {
                Ok(started) => {
                    let handle = MonitorHandle {
                        status: MonitorStatus {
                            active: kind,
                            failed,
                        },
                        shared,
                        started,
                    };
                    return Ok((handle, rx));
                }
                Err(reason) => failed.push(FailedAttempt { kind, reason }),
            }
        }
        Err(MonitorError::NoneAvailable(failed))
    }
}

/// A running monitor. Dropping it stops the monitor and closes the stream.
pub struct MonitorHandle {
    status: MonitorStatus,
    shared: Arc<Shared>,
    started: Started,
}

impl std::fmt::Debug for MonitorHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MonitorHandle")
            .field("status", &self.status)
            .field("shared", &self.shared)
            .finish_non_exhaustive()
    }
}

impl MonitorHandle {
    /// The active monitor.
    pub fn kind(&self) -> MonitorKind {
        self.status.active
    }

    /// Active monitor plus the reasons the better ones failed.
    pub fn status(&self) -> &MonitorStatus {
        &self.status
    }

    /// Label value for a Prometheus gauge of the active monitor.
    pub fn label(&self) -> &'static str {
        self.status.active.label()
    }

    /// Events the kernel or the reader could not deliver (eBPF: ring buffer
    /// full; proc connector: socket overruns, each counted once).
    pub fn lost_events(&self) -> u64 {
        let kernel = self
            .started
            .lost_counter
            .as_ref()
            .map_or(0, ebpf::DropCounter::read);
        kernel + self.shared.lost.load(Ordering::Relaxed)
    }

    /// Why the monitor stopped, if it stopped on an error (the stream is then closed).
    pub fn failure(&self) -> Option<String> {
        self.shared.failure.lock().ok().and_then(|f| f.clone())
    }

    /// Stops the monitor and waits until its task is gone (BPF links detached,
    /// sockets closed).
    pub async fn stop(self) {
        let mut this = self;
        this.started.task.abort();
        let _ = (&mut this.started.task).await;
    }
}

impl Drop for MonitorHandle {
    fn drop(&mut self) {
        self.started.task.abort();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn auto_order_is_best_first() {
        assert_eq!(
            Preference::Auto.order(),
            vec![
                MonitorKind::Ebpf,
                MonitorKind::ProcConnector,
                MonitorKind::ProcScan
            ]
        );
        assert_eq!(
            Preference::Only(MonitorKind::ProcScan).order(),
            vec![MonitorKind::ProcScan]
        );
    }

    #[derive(Debug, thiserror::Error)]
    #[error("outer {0}")]
    struct Outer(#[source] std::io::Error);

    #[derive(Debug, thiserror::Error)]
    #[error("plain outer")]
    struct Plain(#[source] std::io::Error);

    #[test]
    fn error_chain_joins_and_dedups() {
        let io = || std::io::Error::from_raw_os_error(libc::EPERM);
        assert_eq!(
            error_chain(&Plain(io())),
            "plain outer: Operation not permitted (os error 1)"
        );
        assert_eq!(
            error_chain(&Outer(io())),
            "outer Operation not permitted (os error 1)"
        );
    }

    #[test]
    fn summary_names_failures() {
        let status = MonitorStatus {
            active: MonitorKind::ProcScan,
            failed: vec![
                FailedAttempt {
                    kind: MonitorKind::Ebpf,
                    reason: "loading bpf object: permission denied".into(),
                },
                FailedAttempt {
                    kind: MonitorKind::ProcConnector,
                    reason: "socket: protocol not supported".into(),
                },
            ],
        };
        assert_eq!(
            status.summary(),
            "process monitor: proc_scan (ebpf failed: loading bpf object: permission denied; \
             proc_connector failed: socket: protocol not supported)"
        );
    }
}
