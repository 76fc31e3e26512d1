//! The agent's own threads (its data plane's) in cgroups of their own
//! inside the subtree, beside the node cgroups, one per [`AgentThreads`]
//! group: the meters that stamp each message of a metric as it arrives at
//! the largest weight, so a busy robot cannot hold them off the CPU the way
//! it holds off a process outside the subtree; the relays that forward
//! messages to adapted subscribers at a node's weight, so their copies of a
//! camera's images do not come before the nodes' own work.
//!
//! Only cgroup v1 moves single threads between cgroups freely; on v2 a
//! thread may leave its process's cgroup only inside a threaded subtree,
//! which the node cgroups (domains) rule out, so [`CgroupBackend::agent_threads`]
//! is `None` there and the threads stay where the agent runs.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use crate::error::Result;
use crate::fsio::{create_dir, read_ids, remove_dir, write_file};
use crate::limit::CpuWeight;

/// A group of the agent's threads with a cgroup of its own below the
/// subtree root. Not node cgroups (those are `node-*`), so node listings
/// never include them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AgentThreads {
    /// Threads that stamp messages as they arrive (meters): nothing on the
    /// robot may hold them back, or a rate reads lower than it is.
    Metering,
    /// Threads that copy messages for others (relays to adapted
    /// subscribers): bulk work, no more urgent than a node's own.
    Relaying,
}

impl AgentThreads {
    /// Every group, in the order they are created.
    pub const ALL: [AgentThreads; 2] = [AgentThreads::Metering, AgentThreads::Relaying];

    /// The group's directory below the subtree root.
    pub fn dir_name(self) -> &'static str {
        match self {
            AgentThreads::Metering => "agent-threads",
            AgentThreads::Relaying => "agent-relays",
        }
    }

    /// The group's CPU weight against the node cgroups.
    pub fn weight(self) -> CpuWeight {
        match self {
            AgentThreads::Metering => CpuWeight::MAX,
            AgentThreads::Relaying => CpuWeight::DEFAULT,
        }
    }
}

/// Where the agent puts a thread of its own; cheap to clone and share with
/// a runtime's thread-start hook.
#[derive(Debug, Clone)]
pub struct ThreadPlacement {
    /// `tasks` files of the agent's thread cgroup, one per hierarchy.
    tasks: Vec<PathBuf>,
}

impl ThreadPlacement {
    /// Creates `group`'s cgroup below each of `subtree_dirs` (v1: the `cpu`
    /// and `cpuacct` subtree roots) with its weight in the `cpu` one (the
    /// first).
    pub(crate) fn create_v1(subtree_dirs: &[&Path], group: AgentThreads) -> Result<Self> {
        let mut tasks = Vec::new();
        for (i, d) in subtree_dirs.iter().enumerate() {
            let dir = d.join(group.dir_name());
            create_dir(&dir)?;
            if i == 0 {
                let shares = group.weight().v1_shares().to_string();
                write_file(&dir.join("cpu.shares"), &shares)?;
            }
            tasks.push(dir.join("tasks"));
        }
        Ok(Self { tasks })
    }

    /// Moves the calling thread (only it, not its process) into the group's
    /// cgroup. Threads it creates later start there too.
    pub fn place_current_thread(&self) -> Result<()> {
        // v1 `tasks`: 0 is the writing thread (not its thread group).
        for t in &self.tasks {
            write_file(t, "0")?;
        }
        Ok(())
    }
}

/// How long [`release_v1`] keeps moving threads out of a group whose
/// threads keep starting new ones (a new thread starts in its parent's
/// cgroup, and the data plane's start hook places it there too).
const RELEASE_DEADLINE: Duration = Duration::from_secs(2);

/// Removes the agent's thread cgroups below `subtree_dir` (v1), first
/// moving any thread still in one up to the subtree's parent: the agent
/// tears its subtree down while its data plane may still be running, so a
/// thread may start in a group between the move and the removal; the move
/// is repeated until the group is empty and gone, or the deadline passes.
pub(crate) fn release_v1(subtree_dir: &Path) -> Result<()> {
    for group in AgentThreads::ALL {
        let dir = subtree_dir.join(group.dir_name());
        let deadline = Instant::now() + RELEASE_DEADLINE;
        while dir.exists() {
            if let Some(parent) = subtree_dir.parent() {
                for tid in read_ids(&dir.join("tasks")).unwrap_or_default() {
                    // A thread that exited meanwhile is gone from the list anyway.
                    let _ = write_file(&parent.join("tasks"), &tid.to_string());
                }
            }
            match remove_dir(&dir) {
                Ok(()) => break,
                Err(e) if e.is_busy() && Instant::now() < deadline => std::thread::yield_now(),
                Err(e) => return Err(e),
            }
        }
    }
    Ok(())
}
