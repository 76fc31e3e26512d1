//! Reading /proc: process identity (start time), names, command lines,
//! parent links, and matching for `match` nodes. Parsers are pure.

use std::path::Path;

use regex::Regex;

use crate::spec::MatchSpec;

/// What the agent knows about one process.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ProcInfo {
    pub pid: u32,
    pub ppid: u32,
    /// Start time in clock ticks since boot: (pid, start) identifies a process
    /// across pid reuse.
    pub start_time: u64,
    pub comm: String,
    pub cmdline: String,
}

/// Parses `/proc/PID/stat`: returns (comm, ppid, starttime); `None` for zombies.
pub fn parse_stat(text: &str) -> Option<(String, u32, u64)> {
    // comm may contain spaces and parentheses: it ends at the last ')'.
    let open = text.find('(')?;
    let close = text.rfind(')')?;
    let comm = text.get(open + 1..close)?.to_owned();
    let rest: Vec<&str> = text.get(close + 2..)?.split_whitespace().collect();
    if matches!(rest.first(), Some(&"Z" | &"X")) {
        return None;
    }
    // rest[0] is field 3 (state); ppid is field 4, starttime field 22.
    let ppid = rest.get(1)?.parse().ok()?;
    let start = rest.get(19)?.parse().ok()?;
    Some((comm, ppid, start))
}

/// Reads one process; `None` if it is gone (or a kernel thread without cmdline is fine too).
pub fn read_proc(proc_root: &Path, pid: u32) -> Option<ProcInfo> {
    let dir = proc_root.join(pid.to_string());
    let stat = std::fs::read_to_string(dir.join("stat")).ok()?;
    let (comm, ppid, start_time) = parse_stat(&stat)?;
    let raw = std::fs::read(dir.join("cmdline")).unwrap_or_default();
    let cmdline = String::from_utf8_lossy(&raw)
        .trim_end_matches('\0')
        .replace('\0', " ");
    Some(ProcInfo {
        pid,
        ppid,
        start_time,
        comm,
        cmdline,
    })
}

/// All processes visible in `proc_root`.
pub fn list_procs(proc_root: &Path) -> Vec<ProcInfo> {
    let Ok(entries) = std::fs::read_dir(proc_root) else {
        return Vec::new();
    };
    entries
        .filter_map(|e| e.ok()?.file_name().to_str()?.parse::<u32>().ok())
        .filter_map(|pid| read_proc(proc_root, pid))
        .collect()
}

/// Whether `pid` still is the process that started at `start_time`.
pub fn is_alive(proc_root: &Path, pid: u32, start_time: u64) -> bool {
    std::fs::read_to_string(proc_root.join(pid.to_string()).join("stat"))
        .ok()
        .and_then(|t| parse_stat(&t))
        .is_some_and(|(_, _, st)| st == start_time)
}

/// A compiled [`MatchSpec`].
#[derive(Debug, Clone)]
pub struct Matcher {
    process_name: Option<String>,
    cmdline: Option<Regex>,
}

impl Matcher {
    /// Compiles the spec; `None` if it has no criterion or a bad regex
    /// (the stack is validated before, so this does not happen in practice).
    pub fn new(spec: &MatchSpec) -> Option<Self> {
        let cmdline = match &spec.cmdline_regex {
            Some(r) => Some(Regex::new(r).ok()?),
            None => None,
        };
        if spec.process_name.is_none() && cmdline.is_none() {
            return None;
        }
        Some(Self {
            process_name: spec.process_name.clone(),
            cmdline,
        })
    }

    /// All given criteria must hold. Kernel threads (empty cmdline) never match.
    pub fn matches(&self, p: &ProcInfo) -> bool {
        !p.cmdline.is_empty()
            && self.process_name.as_ref().is_none_or(|n| *n == p.comm)
            && self.cmdline.as_ref().is_none_or(|r| r.is_match(&p.cmdline))
    }
}

/// `root` and all its descendants among `procs`, parents first.
pub fn with_descendants(procs: &[ProcInfo], root: u32) -> Vec<u32> {
    let mut out = vec![root];
    let mut i = 0;
    while let Some(&p) = out.get(i) {
        out.extend(
            procs
                .iter()
                .filter(|c| c.ppid == p && c.pid != p)
                .map(|c| c.pid),
        );
        i += 1;
    }
    out
}

/// Looks a user up in passwd-format text: (uid, gid).
pub fn lookup_user(passwd: &str, user: &str) -> Option<(u32, u32)> {
    passwd.lines().find_map(|l| {
        let f: Vec<&str> = l.split(':').collect();
        if f.len() >= 4 && f[0] == user {
            Some((f[2].parse().ok()?, f[3].parse().ok()?))
        } else {
            None
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_stat_with_odd_comm() {
        let line = "1234 (my (odd) proc) S 77 1234 1234 0 -1 4194304 1 0 0 0 0 0 0 0 20 0 1 0 98765 1000 10";
        assert_eq!(parse_stat(line), Some(("my (odd) proc".into(), 77, 98765)));
        assert_eq!(parse_stat("garbage"), None);
        let zombie = line.replace(") S ", ") Z ");
        assert_eq!(parse_stat(&zombie), None, "zombies count as gone");
    }

    #[test]
    fn matcher_and_descendants() {
        let p = |pid, ppid, comm: &str, cmd: &str| ProcInfo {
            pid,
            ppid,
            start_time: 1,
            comm: comm.into(),
            cmdline: cmd.into(),
        };
        let procs = [
            p(10, 1, "python3", "python3 camera_node.py --fast"),
            p(11, 10, "sh", "sh -c x"),
            p(12, 11, "sleep", "sleep 5"),
            p(13, 1, "kworker", ""),
        ];
        let m = Matcher::new(&MatchSpec {
            process_name: Some("python3".into()),
            cmdline_regex: Some("camera_node".into()),
            ros_node: None,
        })
        .unwrap();
        assert!(m.matches(&procs[0]));
        assert!(!m.matches(&procs[1]));
        let any = Matcher::new(&MatchSpec {
            process_name: Some("kworker".into()),
            cmdline_regex: None,
            ros_node: None,
        })
        .unwrap();
        assert!(!any.matches(&procs[3]), "kernel threads never match");
        assert_eq!(with_descendants(&procs, 10), [10, 11, 12]);
        assert!(Matcher::new(&MatchSpec::default()).is_none());
    }

    #[test]
    fn passwd_lookup() {
        let passwd = "root:x:0:0:root:/root:/bin/bash\nnobody:x:65534:65534:nobody:/nonexistent:/usr/sbin/nologin\n";
        assert_eq!(lookup_user(passwd, "nobody"), Some((65534, 65534)));
        assert_eq!(lookup_user(passwd, "ghost"), None);
    }

    #[test]
    fn reads_own_process() {
        let me = read_proc(Path::new("/proc"), std::process::id()).unwrap();
        assert!(is_alive(Path::new("/proc"), me.pid, me.start_time));
        assert!(!is_alive(Path::new("/proc"), me.pid, me.start_time + 1));
    }
}
