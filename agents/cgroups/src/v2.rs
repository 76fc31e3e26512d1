//! cgroup v2 backend: `cpu.max`, `cpu.stat`, `cpu.pressure` in one unified tree.

use std::path::{Path, PathBuf};

use crate::backend::{BackendKind, CgroupBackend};
use crate::error::{Error, Result};
use crate::fsio::{create_dir, read_file, read_ids, read_number, remove_dir, write_file};
use crate::limit::{CpuMax, CpuWeight};
use crate::name::{NodeName, SubtreeRoot};
use crate::stats::{CpuStats, apply_cpu_stat, parse_pressure};
use crate::threads::{AgentThreads, ThreadPlacement};
use crate::v1::list_nodes;

/// v2 backend over the cgroup2 mount.
#[derive(Debug, Clone)]
pub struct V2Backend {
    mount: PathBuf,
    root: PathBuf,
}

impl V2Backend {
    /// `mount` is the cgroup2 mount point (or a delegated cgroup); `root` the agent's subtree.
    pub fn new(mount: PathBuf, root: SubtreeRoot) -> Self {
        Self {
            root: mount.join(root.as_path()),
            mount,
        }
    }

    fn file(&self, node: &NodeName, file: &str) -> PathBuf {
        self.root.join(node.dir_name()).join(file)
    }

    /// Enables the cpu controller for the children of `dir` unless it already is.
    fn enable_cpu(dir: &Path) -> Result<()> {
        let path = dir.join("cgroup.subtree_control");
        let current = read_file(&path)?;
        if !current.split_whitespace().any(|c| c == "cpu") {
            write_file(&path, "+cpu")?;
        }
        Ok(())
    }

    /// Creates the subtree below the mount, enabling `cpu` at every level
    /// (the agent root holds no processes, per v2's no-internal-process rule).
    fn ensure_root(&self) -> Result<()> {
        let rel = self.root.strip_prefix(&self.mount).unwrap_or(Path::new(""));
        let mut dir = self.mount.clone();
        Self::enable_cpu(&dir)?;
        for c in rel.components() {
            dir.push(c);
            create_dir(&dir)?;
            Self::enable_cpu(&dir)?;
        }
        Ok(())
    }
}

impl CgroupBackend for V2Backend {
    fn kind(&self) -> BackendKind {
        BackendKind::V2
    }

    fn node_path(&self, node: &NodeName) -> PathBuf {
        self.root.join(node.dir_name())
    }

    fn create(&self, node: &NodeName) -> Result<()> {
        self.ensure_root()?;
        create_dir(&self.root.join(node.dir_name()))
    }

    fn exists(&self, node: &NodeName) -> bool {
        self.root.join(node.dir_name()).is_dir()
    }

    fn nodes(&self) -> Result<Vec<NodeName>> {
        list_nodes(&self.root)
    }

    fn add_pid(&self, node: &NodeName, pid: u32) -> Result<()> {
        // In a domain cgroup, cgroup.procs migrates every thread of the process.
        write_file(&self.file(node, "cgroup.procs"), &pid.to_string())
    }

    fn join_files(&self, node: &NodeName) -> Vec<PathBuf> {
        vec![self.file(node, "cgroup.procs")]
    }

    fn set_cpu_max(&self, node: &NodeName, max: CpuMax) -> Result<()> {
        write_file(&self.file(node, "cpu.max"), &max.to_v2())
    }

    fn cpu_max(&self, node: &NodeName) -> Result<CpuMax> {
        let path = self.file(node, "cpu.max");
        let text = read_file(&path)?;
        CpuMax::parse_v2(&text).ok_or_else(|| Error::Parse {
            path,
            reason: format!("bad cpu.max {:?}", text.trim()),
        })
    }

    fn set_weight(&self, node: &NodeName, weight: CpuWeight) -> Result<()> {
        write_file(&self.file(node, "cpu.weight"), &weight.v2().to_string())
    }

    fn weight(&self, node: &NodeName) -> Result<CpuWeight> {
        read_weight(&self.file(node, "cpu.weight"))
    }

    fn stats(&self, node: &NodeName) -> Result<CpuStats> {
        let mut s = CpuStats::default();
        apply_cpu_stat(&mut s, &read_file(&self.file(node, "cpu.stat"))?, true);
        // PSI may be disabled (psi=0); that is not an error.
        s.pressure = read_file(&self.file(node, "cpu.pressure"))
            .ok()
            .and_then(|t| parse_pressure(&t));
        Ok(s)
    }

    fn pids(&self, node: &NodeName) -> Result<Vec<u32>> {
        read_ids(&self.file(node, "cgroup.procs"))
    }

    fn tids(&self, node: &NodeName) -> Result<Vec<u32>> {
        read_ids(&self.file(node, "cgroup.threads"))
    }

    fn remove(&self, node: &NodeName) -> Result<()> {
        remove_dir(&self.root.join(node.dir_name()))
    }

    fn remove_root(&self) -> Result<()> {
        remove_dir(&self.root)
    }

    fn set_root_weight(&self, weight: CpuWeight) -> Result<()> {
        self.ensure_root()?;
        write_file(&self.root.join("cpu.weight"), &weight.v2().to_string())
    }

    fn root_weight(&self) -> Result<CpuWeight> {
        read_weight(&self.root.join("cpu.weight"))
    }

    fn agent_threads(&self, _group: AgentThreads) -> Result<Option<ThreadPlacement>> {
        Ok(None)
    }
}

/// Reads a `cpu.weight` file.
fn read_weight(path: &Path) -> Result<CpuWeight> {
    CpuWeight::named(read_number(path)?, &path.display().to_string())
}
