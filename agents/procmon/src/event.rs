//! Event and monitor-kind data types shared by all monitor backends, plus the
//! small pure parsers for `/proc/<pid>/{stat,cgroup}` they all use.

use std::fmt;
use std::path::Path;

use serde::{Deserialize, Serialize};

/// What happened to a process.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ProcEventKind {
    /// The process replaced its program image (`execve`).
    Exec,
    /// The process (its whole thread group) exited.
    Exit,
}

/// One process event as delivered to the agent.
///
/// Which fields are filled depends on the backend ([`ProcEvent::source`]):
/// eBPF fills everything from the kernel at the event; the proc connector and
/// the /proc scan read `comm`, `ppid`, `filename` and `cgroup` from `/proc`
/// when the event is received, which fails (`None`) if the process is already
/// gone.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ProcEvent {
    pub kind: ProcEventKind,
    /// Process id (thread-group id).
    pub pid: u32,
    /// Parent process id.
    pub ppid: Option<u32>,
    /// Kernel `comm` (at most 15 bytes).
    pub comm: Option<String>,
    /// Exec only. eBPF: the path given to `execve` (may be relative);
    /// fallbacks: the resolved `/proc/<pid>/exe` link.
    pub filename: Option<String>,
    /// cgroup v2 id (inode of the cgroup directory on the unified hierarchy); eBPF only.
    pub cgroup_id: Option<u64>,
    /// Path of the process's CPU cgroup (v1 `cpu` hierarchy if present, else the
    /// v2 path) read from `/proc/<pid>/cgroup` on receipt; exec events only.
    pub cgroup: Option<String>,
    /// Exit only: the raw wait status (`exit(3)` → `0x300`, SIGKILL → `9`).
    pub exit_code: Option<i32>,
    /// CLOCK_MONOTONIC nanoseconds: when the kernel saw the event (eBPF,
    /// proc connector) or when the scan noticed it (/proc scan).
    pub timestamp_ns: u64,
    /// Which monitor produced the event.
    pub source: MonitorKind,
}

/// The monitor backends, in the default order of preference.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MonitorKind {
    /// BTF tracepoints `sched_process_exec`/`sched_process_exit` + ring buffer.
    Ebpf,
    /// Netlink proc connector (`NETLINK_CONNECTOR`, `CN_IDX_PROC`).
    ProcConnector,
    /// Periodic diff of the pids in `/proc`.
    ProcScan,
}

impl MonitorKind {
    /// All kinds, best first.
    pub const ALL: [MonitorKind; 3] = [
        MonitorKind::Ebpf,
        MonitorKind::ProcConnector,
        MonitorKind::ProcScan,
    ];

    /// Stable label value, e.g. for a Prometheus gauge
    /// `configbot_agent_process_monitor{kind="ebpf"} 1`.
    pub fn label(self) -> &'static str {
        match self {
            MonitorKind::Ebpf => "ebpf",
            MonitorKind::ProcConnector => "proc_connector",
            MonitorKind::ProcScan => "proc_scan",
        }
    }

    /// Parses a [`MonitorKind::label`] value.
    pub fn from_label(label: &str) -> Option<MonitorKind> {
        MonitorKind::ALL.into_iter().find(|k| k.label() == label)
    }
}

impl fmt::Display for MonitorKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.label())
    }
}

/// CLOCK_MONOTONIC now, in nanoseconds (the clock of `bpf_ktime_get_ns` and
/// of the proc connector's timestamps).
pub fn monotonic_now_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; CLOCK_MONOTONIC is always
    // supported on Linux, so the call only writes `ts`.
    #[allow(unsafe_code)]
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    if rc != 0 {
        return 0;
    }
    u64::try_from(ts.tv_sec).unwrap_or(0) * 1_000_000_000 + u64::try_from(ts.tv_nsec).unwrap_or(0)
}

/// The fields of `/proc/<pid>/stat` the monitors use.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StatInfo {
    pub comm: String,
    /// State letter (`R`, `S`, `Z` zombie, ...).
    pub state: char,
    pub ppid: u32,
    /// Start time in clock ticks since boot (tells a reused pid apart).
    pub starttime: u64,
}

/// Parses `/proc/<pid>/stat`. The comm is inside the outermost parentheses
/// and may itself contain spaces and parentheses.
pub fn parse_stat(text: &str) -> Option<StatInfo> {
    let open = text.find('(')?;
    let close = text.rfind(')')?;
    let comm = text.get(open + 1..close)?.to_owned();
    // After ") ": state(3) ppid(4) ... starttime(22); index 0 here is field 3.
    let rest: Vec<&str> = text.get(close + 1..)?.split_whitespace().collect();
    let state = rest.first()?.chars().next()?;
    let ppid = rest.get(1)?.parse().ok()?;
    let starttime = rest.get(19)?.parse().ok()?;
    Some(StatInfo {
        comm,
        state,
        ppid,
        starttime,
    })
}

/// Picks the CPU cgroup path from `/proc/<pid>/cgroup` text: the v1 line whose
/// controllers include `cpu`, else the v2 (`0::`) line.
pub fn parse_proc_cgroup(text: &str) -> Option<String> {
    let mut unified = None;
    for line in text.lines() {
        let mut parts = line.splitn(3, ':');
        let (Some(id), Some(controllers), Some(path)) = (parts.next(), parts.next(), parts.next())
        else {
            continue;
        };
        if controllers.split(',').any(|c| c == "cpu") {
            return Some(path.to_owned());
        }
        if id == "0" && controllers.is_empty() {
            unified = Some(path.to_owned());
        }
    }
    unified
}

/// Reads and parses `<proc_root>/<pid>/stat`.
pub(crate) fn read_stat(proc_root: &Path, pid: u32) -> Option<StatInfo> {
    let text = std::fs::read_to_string(proc_root.join(pid.to_string()).join("stat")).ok()?;
    parse_stat(&text)
}

/// Reads the CPU cgroup path of `pid`.
pub(crate) fn read_cgroup(proc_root: &Path, pid: u32) -> Option<String> {
    let text = std::fs::read_to_string(proc_root.join(pid.to_string()).join("cgroup")).ok()?;
    parse_proc_cgroup(&text)
}

/// Resolves `<proc_root>/<pid>/exe`.
pub(crate) fn read_exe(proc_root: &Path, pid: u32) -> Option<String> {
    let target = std::fs::read_link(proc_root.join(pid.to_string()).join("exe")).ok()?;
    Some(target.to_string_lossy().into_owned())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stat_with_parens_and_spaces_in_comm() {
        let text =
            "4242 (a (b) c) S 17 4242 4242 0 -1 4194560 100 0 0 0 1 2 0 0 20 0 1 0 987654 1000 10";
        let info = parse_stat(text).expect("parses");
        assert_eq!(info.comm, "a (b) c");
        assert_eq!(info.ppid, 17);
        assert_eq!(info.state, 'S');
        assert_eq!(info.starttime, 987654);
    }

    #[test]
    fn stat_truncated_is_none() {
        assert_eq!(parse_stat("12 (x) S 1 2 3"), None);
        assert_eq!(parse_stat("garbage"), None);
    }

    #[test]
    fn cgroup_prefers_v1_cpu_then_v2() {
        let hybrid =
            "12:memory:/user.slice\n5:cpuacct:/a\n4:cpu:/configbot/n1\n0::/user.slice/x.scope\n";
        assert_eq!(parse_proc_cgroup(hybrid).as_deref(), Some("/configbot/n1"));
        let merged = "3:cpu,cpuacct:/m\n0::/u\n";
        assert_eq!(parse_proc_cgroup(merged).as_deref(), Some("/m"));
        let v2 = "0::/system.slice/configbot.service\n";
        assert_eq!(
            parse_proc_cgroup(v2).as_deref(),
            Some("/system.slice/configbot.service")
        );
        assert_eq!(parse_proc_cgroup("5:cpuacct:/a\n"), None);
    }

    #[test]
    fn labels_round_trip() {
        for kind in MonitorKind::ALL {
            assert_eq!(MonitorKind::from_label(kind.label()), Some(kind));
        }
        assert_eq!(MonitorKind::from_label("nope"), None);
    }

    #[test]
    fn monotonic_clock_advances() {
        let a = monotonic_now_ns();
        let b = monotonic_now_ns();
        assert!(a > 0 && b >= a);
    }
}
