//! The agent's side of supervising a node: a `run` node's main process
//! ([`Proc`]: our child, or one a previous agent started), [`RunNode`] (the
//! [`Supervised`] operations [`crate::supervise`] drives: start inside the
//! cgroup, wait, record exits and restarts), signals to a node's processes
//! (freeze/thaw) and the graceful stop SIGINT → SIGTERM → SIGKILL shared by
//! all nodes.

use std::time::{Duration, Instant};

use configbot_cgroups::NodeName;

use super::Agent;
use crate::events::AgentEvent;
use crate::policy::ExitKind;
use crate::procfs::{is_alive, read_proc};
use crate::spawn::spawn_in_cgroup;
use crate::spec::RunSpec;
use crate::supervise::Supervised;

/// How often exits of non-child processes are polled.
const POLL: Duration = Duration::from_millis(50);

/// A `run` node's main process: our child, or one a previous agent started.
#[derive(Debug)]
pub(crate) enum Proc {
    Child(tokio::process::Child, u32),
    Foreign { pid: u32, start: u64 },
}

impl Proc {
    fn pid(&self) -> u32 {
        match self {
            Self::Child(_, pid) | Self::Foreign { pid, .. } => *pid,
        }
    }

    async fn wait(&mut self, agent: &Agent) -> ExitKind {
        match self {
            Self::Child(c, _) => c
                .wait()
                .await
                .map_or(ExitKind::Unknown, ExitKind::from_status),
            Self::Foreign { pid, start } => {
                while is_alive(agent.proc_root(), *pid, *start) {
                    tokio::time::sleep(POLL).await;
                }
                ExitKind::Unknown
            }
        }
    }

    fn exited(&mut self, agent: &Agent) -> bool {
        match self {
            Self::Child(c, _) => !matches!(c.try_wait(), Ok(None)),
            Self::Foreign { pid, start } => !is_alive(agent.proc_root(), *pid, *start),
        }
    }
}

/// One `run` node of the agent, as its supervisor sees it.
#[derive(Debug)]
pub(crate) struct RunNode {
    pub agent: Agent,
    pub node: NodeName,
    pub spec: RunSpec,
}

impl Supervised for RunNode {
    type Proc = Proc;

    fn start(&self, reattach: Option<(u32, u64)>) -> Option<Proc> {
        let (agent, node) = (&self.agent, &self.node);
        if let Some((pid, start)) = reattach {
            agent.emit(AgentEvent::NodeReattached {
                node: node.clone(),
                pid,
            });
            return Some(Proc::Foreign { pid, start });
        }
        let files = agent.backend().join_files(node);
        match spawn_in_cgroup(&self.spec, &files, &agent.log_path(node)) {
            Ok(child) => {
                let pid = child.id()?;
                let start = read_proc(agent.proc_root(), pid).map_or(0, |p| p.start_time);
                agent.update_node(node, |n| n.main = Some((pid, start)));
                agent.emit(AgentEvent::NodeStarted {
                    node: node.clone(),
                    pid,
                });
                Some(Proc::Child(child, pid))
            }
            Err(e) => {
                agent.emit(AgentEvent::NodeSpawnFailed {
                    node: node.clone(),
                    error: super::error_chain(&e),
                });
                None
            }
        }
    }

    async fn wait(&self, proc: &mut Proc) -> ExitKind {
        proc.wait(&self.agent).await
    }

    async fn terminate(&self, proc: &mut Proc) {
        terminate(&self.agent, &self.node, Some(proc)).await;
    }

    fn exited(&self, proc: &Proc, exit: ExitKind) {
        self.agent.update_node(&self.node, |n| n.main = None);
        self.agent.emit(AgentEvent::NodeExited {
            node: self.node.clone(),
            pid: proc.pid(),
            exit,
        });
    }

    fn restarting(&self, delay: Duration) {
        let mut attempt = 0;
        self.agent.update_node(&self.node, |n| {
            n.restarts += 1;
            attempt = n.restarts;
        });
        self.agent
            .metrics()
            .restarts
            .with_label_values(&[self.node.as_str()])
            .inc();
        self.agent.emit(AgentEvent::NodeRestarting {
            node: self.node.clone(),
            attempt,
            delay_ms: u64::try_from(delay.as_millis()).unwrap_or(u64::MAX),
        });
    }

    fn stopped(&self) {
        self.agent.update_node(&self.node, |n| n.main = None);
        self.agent.emit(AgentEvent::NodeStopped {
            node: self.node.clone(),
        });
    }
}

/// Sends `sig` to `pid` (negative: a process group); false if it failed.
pub fn send_signal(pid: u32, sig: i32) -> bool {
    send_raw(i32::try_from(pid).unwrap_or(i32::MAX), sig)
}

/// Sends `sig` to the process group `pid` leads; false if it failed.
pub(crate) fn send_group(pid: u32, sig: i32) -> bool {
    send_raw(-i32::try_from(pid).unwrap_or(i32::MAX), sig)
}

/// Sends `sig` to every process in `node`'s cgroup, and again to any that
/// joined meanwhile (a child forked before a SIGSTOP landed), until a pass
/// finds none new. Returns the pids signalled; fails only when the cgroup
/// cannot be read.
pub(crate) fn signal_cgroup(
    agent: &Agent,
    node: &NodeName,
    sig: i32,
) -> configbot_cgroups::Result<Vec<u32>> {
    let mut done = std::collections::BTreeSet::new();
    for _ in 0..10 {
        let fresh: Vec<u32> = agent
            .backend()
            .pids(node)?
            .into_iter()
            .filter(|p| !done.contains(p))
            .collect();
        if fresh.is_empty() {
            break;
        }
        for pid in fresh {
            send_signal(pid, sig);
            done.insert(pid);
        }
    }
    Ok(done.into_iter().collect())
}

fn send_raw(target: i32, sig: i32) -> bool {
    #[allow(unsafe_code)]
    // SAFETY: kill(2) takes plain integers and touches no memory of ours.
    let rc = unsafe { libc::kill(target, sig) };
    rc == 0
}

/// Graceful stop of a node: SIGINT (as roslaunch does), then SIGTERM, then
/// SIGKILL, each followed by up to `stopTimeout` of waiting. With a main
/// process (a `run` node, session leader) its process group gets the first two
/// signals; without one (a `match` node) every process in the cgroup does.
/// SIGKILL always goes to everything left in the node's cgroup.
pub(crate) async fn terminate(agent: &Agent, node: &NodeName, mut main: Option<&mut Proc>) {
    let timeout = agent.settings().stop_timeout;
    for sig in [libc::SIGINT, libc::SIGTERM, libc::SIGKILL] {
        let pids = agent.backend().pids(node).unwrap_or_default();
        match main.as_deref() {
            Some(p) if sig != libc::SIGKILL => {
                send_group(p.pid(), sig);
                send_signal(p.pid(), sig);
            }
            _ => {
                for pid in pids {
                    send_signal(pid, sig);
                }
            }
        }
        let deadline = Instant::now() + timeout;
        loop {
            let main_gone = main.as_deref_mut().is_none_or(|p| p.exited(agent));
            let empty = agent.backend().pids(node).map_or(true, |p| p.is_empty());
            if main_gone && empty {
                return;
            }
            if Instant::now() >= deadline {
                break;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }
}
