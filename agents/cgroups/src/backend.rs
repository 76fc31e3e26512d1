//! The [`CgroupBackend`] trait every hierarchy implements, and [`open_backend`]
//! which picks one for a detected [`Layout`].

use std::fmt::Debug;
use std::path::PathBuf;

use crate::error::{Error, Result};
use crate::layout::Layout;
use crate::limit::{CpuMax, CpuWeight};
use crate::name::{NodeName, SubtreeRoot};
use crate::stats::CpuStats;
use crate::threads::{AgentThreads, ThreadPlacement};
use crate::{V1Backend, V2Backend};

/// Which backend implementation is in use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BackendKind {
    V1,
    V2,
}

/// One ROS node = one cgroup below the agent's subtree. All methods are
/// idempotent where that makes sense (create, remove).
pub trait CgroupBackend: Debug + Send + Sync {
    /// v1 or v2.
    fn kind(&self) -> BackendKind;
    /// The node's cgroup directory in the main (cpu) hierarchy, for display.
    fn node_path(&self, node: &NodeName) -> PathBuf;
    /// Creates the subtree root (if needed) and the node's cgroup.
    fn create(&self, node: &NodeName) -> Result<()>;
    /// Whether the node's cgroup exists.
    fn exists(&self, node: &NodeName) -> bool;
    /// Node cgroups that currently exist below the subtree (for re-adoption
    /// and removal; on v1, those in either hierarchy).
    fn nodes(&self) -> Result<Vec<NodeName>>;
    /// Moves a process with all its threads into the node's cgroup. Children it
    /// forks later start in the same cgroup.
    fn add_pid(&self, node: &NodeName, pid: u32) -> Result<()>;
    /// The `cgroup.procs` files a freshly forked child writes `0` into to join
    /// the node's cgroup before `exec` (see the agent's spawner).
    fn join_files(&self, node: &NodeName) -> Vec<PathBuf>;
    /// Writes quota and period.
    fn set_cpu_max(&self, node: &NodeName, max: CpuMax) -> Result<()>;
    /// Reads quota and period back.
    fn cpu_max(&self, node: &NodeName) -> Result<CpuMax>;
    /// Writes the node's CPU weight against its sibling nodes (v2
    /// `cpu.weight`, v1 `cpu.shares`).
    fn set_weight(&self, node: &NodeName, weight: CpuWeight) -> Result<()>;
    /// Reads the node's CPU weight back.
    fn weight(&self, node: &NodeName) -> Result<CpuWeight>;
    /// Cumulative usage, throttling and (v2) pressure.
    fn stats(&self, node: &NodeName) -> Result<CpuStats>;
    /// Process ids in the node's cgroup (on v1, in either hierarchy: of a
    /// node removed halfway, what runs in what is left of it).
    fn pids(&self, node: &NodeName) -> Result<Vec<u32>>;
    /// Thread ids in the node's cgroup.
    fn tids(&self, node: &NodeName) -> Result<Vec<u32>>;
    /// Removes the node's cgroup; fails (EBUSY) while processes remain in it.
    fn remove(&self, node: &NodeName) -> Result<()>;
    /// Removes the subtree root itself once it has no node cgroups left.
    fn remove_root(&self) -> Result<()>;
    /// Sets the subtree root's CPU weight against its siblings (the host's
    /// other services), creating the root if needed: how much of a busy
    /// machine the robot's nodes get together.
    fn set_root_weight(&self, weight: CpuWeight) -> Result<()>;
    /// The subtree root's CPU weight.
    fn root_weight(&self) -> Result<CpuWeight>;
    /// Creates the cgroup of one group of the agent's own threads (see
    /// [`crate::threads`]); `None` where single threads cannot have a
    /// cgroup of their own (v2).
    fn agent_threads(&self, group: AgentThreads) -> Result<Option<ThreadPlacement>>;
}

/// Picks the backend for a layout: the v1 `cpu` hierarchy when it exists
/// (v1 and hybrid hosts), else cgroup2 if its root offers the `cpu` controller.
pub fn open_backend(layout: &Layout, root: SubtreeRoot) -> Result<Box<dyn CgroupBackend>> {
    if let Some(cpu) = &layout.v1_cpu {
        let acct = layout.v1_cpuacct.clone().unwrap_or_else(|| cpu.clone());
        return Ok(Box::new(V1Backend::new(cpu.clone(), acct, root)));
    }
    if let Some(unified) = &layout.unified {
        let controllers = crate::fsio::read_file(&unified.join("cgroup.controllers"))?;
        if controllers.split_whitespace().any(|c| c == "cpu") {
            return Ok(Box::new(V2Backend::new(unified.clone(), root)));
        }
    }
    Err(Error::NoCpuController)
}
