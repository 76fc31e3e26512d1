//! Child processes of a test: a guard that kills and reaps one on drop
//! (also when the test fails), a child in its own process group whose
//! stdout lines are kept with their arrival times ([`GroupChild`]), SIGKILL
//! by pid, and `which`.

use std::io::{BufRead, BufReader};
use std::os::unix::process::CommandExt;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crate::wait::try_wait_until;

/// Kills and reaps the child on drop, even when the test fails.
#[derive(Debug)]
pub struct ChildGuard(pub Child);

impl ChildGuard {
    pub fn id(&self) -> u32 {
        self.0.id()
    }
}

impl Drop for ChildGuard {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// A child in its own process group (so that what it starts goes with it),
/// its stdout lines kept with their arrival times by a reader thread, its
/// stderr and stdin null; the whole group is killed and the child reaped on
/// drop, also when the test fails.
#[derive(Debug)]
pub struct GroupChild {
    pub child: Child,
    lines: Arc<Mutex<Vec<(Instant, String)>>>,
}

impl GroupChild {
    /// Spawns `c` (panics, naming it, when it cannot start).
    pub fn spawn(mut c: Command) -> GroupChild {
        c.stdout(Stdio::piped())
            .stderr(Stdio::null())
            .stdin(Stdio::null())
            .process_group(0);
        let mut child = c.spawn().unwrap_or_else(|e| panic!("spawning {c:?}: {e}"));
        let lines = Arc::new(Mutex::new(Vec::new()));
        let out = child.stdout.take().expect("stdout is piped");
        let kept = lines.clone();
        std::thread::spawn(move || {
            for line in BufReader::new(out).lines().map_while(Result::ok) {
                kept.lock().unwrap().push((Instant::now(), line));
            }
        });
        GroupChild { child, lines }
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Whether some stdout line so far contains `s`.
    pub fn has_line(&self, s: &str) -> bool {
        self.lines
            .lock()
            .unwrap()
            .iter()
            .any(|(_, l)| l.contains(s))
    }

    /// Every stdout line so far.
    pub fn lines(&self) -> Vec<String> {
        self.lines
            .lock()
            .unwrap()
            .iter()
            .map(|(_, l)| l.clone())
            .collect()
    }

    /// The stdout lines that arrived in `[from, to)`.
    pub fn lines_between(&self, from: Instant, to: Instant) -> Vec<String> {
        self.lines
            .lock()
            .unwrap()
            .iter()
            .filter(|(t, _)| *t >= from && *t < to)
            .map(|(_, l)| l.clone())
            .collect()
    }

    /// Sends `signal` (a name such as `INT`, `TERM`, `STOP`) to the child
    /// alone, or with `group` to its whole process group; true when `kill`
    /// delivered it.
    pub fn signal(&self, signal: &str, group: bool) -> bool {
        let pid = self.child.id().to_string();
        let target = if group { format!("-{pid}") } else { pid };
        Command::new("kill")
            .args([&format!("-{signal}"), "--", &target])
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success())
    }

    /// Waits up to `timeout` for the child to exit; true when it did.
    pub fn wait_exit(&mut self, timeout: Duration) -> bool {
        try_wait_until(
            "the child to exit",
            timeout,
            Duration::from_millis(20),
            || matches!(self.child.try_wait(), Ok(Some(_))),
        )
        .is_ok()
    }

    /// SIGKILL to the whole process group, then the child is reaped.
    pub fn kill(&mut self) {
        self.signal("KILL", true);
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for GroupChild {
    fn drop(&mut self) {
        self.kill();
    }
}

/// SIGKILL to process `pid` (no `kill` binary needed); a pid that does not
/// fit a `pid_t` is ignored.
pub fn kill9(pid: u32) {
    let Ok(pid) = libc::pid_t::try_from(pid) else {
        return;
    };
    #[allow(unsafe_code)]
    // SAFETY: kill(2) takes plain integers and touches no memory of ours.
    unsafe {
        libc::kill(pid, libc::SIGKILL);
    }
}

/// The first file named `name` in a `PATH` directory.
pub fn which(name: &str) -> Option<PathBuf> {
    std::env::var_os("PATH")
        .into_iter()
        .flat_map(|p| std::env::split_paths(&p).collect::<Vec<_>>())
        .map(|d| d.join(name))
        .find(|p| p.is_file())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_group_child_keeps_its_lines_and_takes_its_group_with_it() {
        let mut c = std::process::Command::new("sh");
        c.args(["-c", "echo one; echo two; sleep 600 & echo \"$!\"; wait"]);
        let from = Instant::now();
        let mut child = GroupChild::spawn(c);
        let poll = Duration::from_millis(20);
        crate::wait_until("three lines", Duration::from_secs(10), poll, || {
            child.lines_between(from, Instant::now()).len() == 3
        });
        let lines = child.lines_between(from, Instant::now());
        assert_eq!(lines[..2], ["one", "two"]);
        assert!(child.has_line("two") && !child.has_line("three"));
        assert!(
            child
                .lines_between(Instant::now(), Instant::now())
                .is_empty()
        );
        let sleeper: u32 = lines[2].parse().unwrap();
        assert!(
            !child.wait_exit(Duration::from_millis(100)),
            "still running"
        );
        drop(child);
        // The sleep it started went with its group.
        crate::wait_until(
            "the group's sleep to go",
            Duration::from_secs(10),
            poll,
            || {
                let stat =
                    std::fs::read_to_string(format!("/proc/{sleeper}/stat")).unwrap_or_default();
                !stat.contains("(sleep)") || stat.contains(") Z ")
            },
        );
    }

    #[test]
    fn the_guard_kills_and_reaps_its_child() {
        let child = std::process::Command::new("sleep")
            .arg("600")
            .spawn()
            .unwrap();
        let pid = child.id();
        drop(ChildGuard(child));
        // Reaped: the pid no longer names our child (not even a zombie).
        let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
        assert!(!stat.contains("(sleep)"), "{stat}");
    }

    #[test]
    fn kill9_kills() {
        let mut child = std::process::Command::new("sleep")
            .arg("600")
            .spawn()
            .unwrap();
        kill9(child.id());
        let status = child.wait().unwrap();
        use std::os::unix::process::ExitStatusExt;
        assert_eq!(status.signal(), Some(libc::SIGKILL));
    }

    #[test]
    fn which_finds_programs_on_the_path_only() {
        assert!(which("sh").is_some_and(|p| p.is_file()));
        assert_eq!(which("configbot-no-such-program"), None);
    }
}
