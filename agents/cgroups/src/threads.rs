//! The agent's own latency-critical threads (its data plane's: the meters
//! that stamp each message of a core metric as it arrives) in a cgroup of
//! their own inside the subtree, [`AGENT_THREADS_DIR`], at the largest
//! weight: beside the node cgroups, so a busy robot cannot hold them off
//! the CPU the way it holds off a process outside the subtree.
//!
//! Only cgroup v1 moves single threads between cgroups freely; on v2 a
//! thread may leave its process's cgroup only inside a threaded subtree,
//! which the node cgroups (domains) rule out, so [`CgroupBackend::agent_threads`]
//! is `None` there and the threads stay where the agent runs.

use std::path::{Path, PathBuf};

use crate::error::Result;
use crate::fsio::{create_dir, read_ids, remove_dir, write_file};
use crate::limit::CpuWeight;

/// The directory of the agent's threads below the subtree root. Not a node
/// cgroup (those are `node-*`), so node listings never include it.
pub const AGENT_THREADS_DIR: &str = "agent-threads";

/// Where the agent puts a thread of its own; cheap to clone and share with
/// a runtime's thread-start hook.
#[derive(Debug, Clone)]
pub struct ThreadPlacement {
    /// `tasks` files of the agent's thread cgroup, one per hierarchy.
    tasks: Vec<PathBuf>,
}

impl ThreadPlacement {
    /// Creates the agent's thread cgroup below each of `subtree_dirs` (v1:
    /// the `cpu` and `cpuacct` subtree roots) with `weight` in the `cpu`
    /// one (the first).
    pub(crate) fn create_v1(subtree_dirs: &[&Path], weight: CpuWeight) -> Result<Self> {
        let mut tasks = Vec::new();
        for (i, d) in subtree_dirs.iter().enumerate() {
            let dir = d.join(AGENT_THREADS_DIR);
            create_dir(&dir)?;
            if i == 0 {
                write_file(&dir.join("cpu.shares"), &weight.v1_shares().to_string())?;
            }
            tasks.push(dir.join("tasks"));
        }
        Ok(Self { tasks })
    }

    /// Moves the calling thread (only it, not its process) into the agent's
    /// thread cgroup. Threads it creates later start there too.
    pub fn place_current_thread(&self) -> Result<()> {
        // v1 `tasks`: 0 is the writing thread (not its thread group).
        for t in &self.tasks {
            write_file(t, "0")?;
        }
        Ok(())
    }
}

/// Removes the agent's thread cgroup below `subtree_dir` (v1), first moving
/// any thread still in it up to the subtree's parent: the agent tears its
/// subtree down while its data plane may still be running.
pub(crate) fn release_v1(subtree_dir: &Path) -> Result<()> {
    let dir = subtree_dir.join(AGENT_THREADS_DIR);
    if !dir.exists() {
        return Ok(());
    }
    if let Some(parent) = subtree_dir.parent() {
        for tid in read_ids(&dir.join("tasks")).unwrap_or_default() {
            // A thread that exited meanwhile is gone from the list anyway.
            let _ = write_file(&parent.join("tasks"), &tid.to_string());
        }
    }
    remove_dir(&dir)
}
