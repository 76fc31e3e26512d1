//! Shared test helpers: unique cgroup subtrees, a guard that kills every
//! process in them and removes them on drop, event waiting and raw HTTP.
//! Condition waits and skips (a failure under CI) come from
//! `configbot_test_support`.
#![allow(dead_code)]

pub mod rt;

use std::io::{Read, Write};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use configbot_agent::{Agent, AgentSettings, ConfigUpdate, StackSpec};
use configbot_cgroups::{CgroupBackend, CpuLimit, Layout, NodeName, SubtreeRoot, V1Backend};
use configbot_test_support::cgroup::remove_subtree;
use configbot_test_support::wait_until_async;

/// How often the tests' condition waits look.
pub const POLL: Duration = Duration::from_millis(20);

/// `configbot-agtest-<pid>-<n>`: the leftover check parses the pid back out.
pub fn unique_root() -> String {
    configbot_test_support::unique("configbot-agtest", '-')
}

pub fn v1_backend(root: &str) -> V1Backend {
    let l = Layout::detect().unwrap();
    V1Backend::new(
        l.v1_cpu.unwrap(),
        l.v1_cpuacct.unwrap(),
        SubtreeRoot::new(root).unwrap(),
    )
}

/// Kills every process in the subtree `root` (in the v1 cpu and cpuacct
/// hierarchies), then removes its cgroups; panics after 10 s unless the
/// test already fails.
pub fn nuke(root: &str) {
    let l = Layout::detect().unwrap();
    let mounts = [l.v1_cpu, l.v1_cpuacct].into_iter().flatten();
    if let Err(e) = remove_subtree(mounts, root, Duration::from_secs(10)) {
        assert!(std::thread::panicking(), "{e}");
        eprintln!("{e}");
    }
}

/// Owns a test's subtree, temp dir, agent and extra children.
pub struct Env {
    pub root: String,
    pub dir: tempfile::TempDir,
    pub agent: Option<Agent>,
    pub children: Vec<std::process::Child>,
}

impl Env {
    pub fn new() -> Self {
        Self {
            root: unique_root(),
            dir: tempfile::tempdir().unwrap(),
            agent: None,
            children: Vec::new(),
        }
    }

    pub fn settings(&self) -> AgentSettings {
        AgentSettings {
            cgroup_root: SubtreeRoot::new(&self.root).unwrap(),
            state_file: self.dir.path().join("state.json"),
            log_dir: self.dir.path().join("logs"),
            stop_timeout: Duration::from_millis(1500),
            backoff_initial: Duration::from_millis(20),
            backoff_max: Duration::from_millis(500),
            scan_interval: Duration::from_millis(100),
            ..AgentSettings::default()
        }
    }

    pub async fn start(&mut self, stack: StackSpec) -> Agent {
        self.start_with(stack, self.settings()).await
    }

    pub async fn start_with(&mut self, stack: StackSpec, settings: AgentSettings) -> Agent {
        let backend = Box::new(v1_backend(&self.root));
        let agent = Agent::start(backend, settings, stack).await.unwrap();
        self.agent = Some(agent.clone());
        agent
    }

    pub fn path(&self, name: &str) -> PathBuf {
        self.dir.path().join(name)
    }
}

impl Drop for Env {
    fn drop(&mut self) {
        if let Some(a) = &self.agent {
            a.detach();
        }
        for c in &mut self.children {
            let _ = c.kill();
            let _ = c.wait();
        }
        nuke(&self.root);
        if !std::thread::panicking() {
            let b = v1_backend(&self.root);
            assert!(
                b.nodes().unwrap().is_empty(),
                "cgroups left behind under {}",
                self.root
            );
        }
    }
}

pub fn node(name: &str) -> NodeName {
    NodeName::new(name).unwrap()
}

/// Waits up to `timeout` for an event that `pred` accepts (events missed
/// by lagging behind are skipped); `None` on timeout. Panics when the
/// channel closes.
pub async fn try_wait_event<E: Clone>(
    rx: &mut tokio::sync::broadcast::Receiver<E>,
    timeout: Duration,
    mut pred: impl FnMut(&E) -> bool,
) -> Option<E> {
    tokio::time::timeout(timeout, async {
        loop {
            match rx.recv().await {
                Ok(ev) if pred(&ev) => return ev,
                Ok(_) | Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => {}
                Err(e) => panic!("event channel: {e}"),
            }
        }
    })
    .await
    .ok()
}

/// [`try_wait_event`] that panics on timeout naming `what`.
pub async fn wait_event<E: Clone>(
    rx: &mut tokio::sync::broadcast::Receiver<E>,
    what: &str,
    timeout: Duration,
    pred: impl FnMut(&E) -> bool,
) -> E {
    try_wait_event(rx, timeout, pred)
        .await
        .unwrap_or_else(|| panic!("timed out after {timeout:?} waiting for {what}"))
}

/// Waits until node `n` of `agent` has a process in its cgroup.
pub async fn wait_running(agent: &Agent, n: &NodeName, timeout: Duration, what: &str) {
    wait_until_async(what, timeout, POLL, async || {
        !agent.backend().pids(n).unwrap().is_empty()
    })
    .await;
}

/// Puts a config that sets node `n`'s CPU limit and no adaptor rates.
pub fn set_limit(agent: &Agent, n: &NodeName, limit: CpuLimit) {
    agent
        .put_config(ConfigUpdate {
            limits: [(n.clone(), limit)].into(),
            adaptor_rates: Vec::new(),
        })
        .unwrap();
}

/// CPUs used by a node's cgroup over `window`.
pub async fn measure_cpus(b: &dyn CgroupBackend, n: &NodeName, window: Duration) -> f64 {
    let u0 = b.stats(n).unwrap().usage_ns;
    let t0 = Instant::now();
    tokio::time::sleep(window).await;
    let u1 = b.stats(n).unwrap().usage_ns;
    (u1 - u0) as f64 / t0.elapsed().as_nanos() as f64
}

/// One blocking HTTP/1.1 request over any stream; returns (status, body).
pub fn http(
    mut s: impl Read + Write,
    method: &str,
    path: &str,
    body: Option<&str>,
    token: Option<&str>,
) -> (u16, String) {
    let body = body.unwrap_or("");
    let auth = token
        .map(|t| format!("Authorization: Bearer {t}\r\n"))
        .unwrap_or_default();
    write!(
        s,
        "{method} {path} HTTP/1.1\r\nHost: agent\r\nConnection: close\r\n{auth}Content-Type: application/json\r\nContent-Length: {}\r\n\r\n{body}",
        body.len()
    )
    .unwrap();
    let mut out = String::new();
    s.read_to_string(&mut out).unwrap();
    let status = out.split_whitespace().nth(1).unwrap().parse().unwrap();
    let body = out
        .split_once("\r\n\r\n")
        .map(|(_, b)| b.to_owned())
        .unwrap_or_default();
    (status, body)
}

pub fn stack_json(json: &str) -> StackSpec {
    serde_json::from_str(json).unwrap()
}

/// The scheduler state letter of `pid` (`T`: stopped by a signal).
pub fn proc_state(pid: u32) -> Option<char> {
    stat_fields(pid)?.first()?.chars().next()
}

/// The parent of `pid`.
pub fn proc_ppid(pid: u32) -> Option<u32> {
    stat_fields(pid)?.get(1)?.parse().ok()
}

/// The fields of `/proc/<pid>/stat` after the command name: state, ppid, …
fn stat_fields(pid: u32) -> Option<Vec<String>> {
    let s = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    Some(
        s.rsplit_once(')')?
            .1
            .split_whitespace()
            .map(str::to_owned)
            .collect(),
    )
}

/// Whether none of `pids` (a frozen node's processes) can run: each is
/// stopped by a signal, or is a vfork parent (`D`, as dash runs a simple
/// command) whose child among `pids` was stopped before its exec; that
/// parent waits in the kernel until the child is continued (seen in CI:
/// `while :; do sleep 0.01; done` frozen mid-vfork).
pub fn all_held(pids: &[u32]) -> bool {
    let stopped = |p: u32| proc_state(p) == Some('T');
    pids.iter().all(|&p| {
        stopped(p)
            || (proc_state(p) == Some('D')
                && pids.iter().any(|&c| proc_ppid(c) == Some(p) && stopped(c)))
    })
}
