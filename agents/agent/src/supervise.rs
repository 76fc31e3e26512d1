//! Supervision of `run` nodes (spawn, wait, restart with backoff) and the
//! graceful stop sequence SIGINT → SIGTERM → SIGKILL shared by all nodes.

use std::time::{Duration, Instant};

use configbot_cgroups::NodeName;
use tokio::sync::watch;

use crate::agent::Agent;
use crate::events::AgentEvent;
use crate::policy::{Backoff, ExitKind, should_restart};
use crate::procfs::{is_alive, read_proc};
use crate::spawn::spawn_in_cgroup;
use crate::spec::RunSpec;

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

/// Sends `sig` to `pid` (negative: a process group); false if it failed.
pub(crate) fn send_signal(pid: u32, sig: i32) -> bool {
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

/// Runs one `run` node until stopped: spawn (or re-attach), wait, restart per policy.
pub(crate) async fn supervise(
    agent: Agent,
    node: NodeName,
    spec: RunSpec,
    mut stop: watch::Receiver<bool>,
    mut reattach: Option<(u32, u64)>,
) {
    let s = agent.settings();
    let mut backoff = Backoff::new(s.backoff_initial, s.backoff_max);
    loop {
        let started = Instant::now();
        let proc = match reattach.take() {
            Some((pid, start)) => {
                agent.emit(AgentEvent::NodeReattached {
                    node: node.clone(),
                    pid,
                });
                Some(Proc::Foreign { pid, start })
            }
            None => spawn(&agent, &node, &spec),
        };
        let exit = match proc {
            None => ExitKind::Unknown,
            Some(mut p) => {
                let pid = p.pid();
                let exit = tokio::select! {
                    e = p.wait(&agent) => e,
                    _ = stop.changed() => {
                        terminate(&agent, &node, Some(&mut p)).await;
                        stopped(&agent, &node);
                        return;
                    }
                };
                agent.update_node(&node, |n| n.main = None);
                agent.emit(AgentEvent::NodeExited {
                    node: node.clone(),
                    pid,
                    exit,
                });
                exit
            }
        };
        if !should_restart(spec.restart_policy, exit) {
            return;
        }
        let delay = backoff.next_delay(started.elapsed());
        let mut attempt = 0;
        agent.update_node(&node, |n| {
            n.restarts += 1;
            attempt = n.restarts;
        });
        agent
            .metrics()
            .restarts
            .with_label_values(&[node.as_str()])
            .inc();
        agent.emit(AgentEvent::NodeRestarting {
            node: node.clone(),
            attempt,
            delay_ms: u64::try_from(delay.as_millis()).unwrap_or(u64::MAX),
        });
        tokio::select! {
            () = tokio::time::sleep(delay) => {}
            _ = stop.changed() => {
                stopped(&agent, &node);
                return;
            }
        }
    }
}

fn spawn(agent: &Agent, node: &NodeName, spec: &RunSpec) -> Option<Proc> {
    let files = agent.backend().join_files(node);
    match spawn_in_cgroup(spec, &files, &agent.log_path(node)) {
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
                error: crate::agent::error_chain(&e),
            });
            None
        }
    }
}

fn stopped(agent: &Agent, node: &NodeName) {
    agent.update_node(node, |n| n.main = None);
    agent.emit(AgentEvent::NodeStopped { node: node.clone() });
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
