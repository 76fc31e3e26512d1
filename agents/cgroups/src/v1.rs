//! cgroup v1 backend: the `cpu` and `cpuacct` hierarchies only.
//!
//! `cpuset` is deliberately not used: no ConfigBot knob sets CPU affinity yet,
//! and a v1 cpuset cgroup starts with empty `cpuset.cpus`/`cpuset.mems`, so
//! joining it before copying them from the parent fails. When a cpuset knob
//! arrives, create the cpuset node dir, copy both files from the parent, then
//! add it to [`V1Backend::dirs`].

use std::path::{Path, PathBuf};

use crate::backend::{BackendKind, CgroupBackend};
use crate::error::{Error, Result};
use crate::fsio::{create_dir, read_file, read_ids, read_number, remove_dir, write_file};
use crate::limit::{CpuMax, CpuWeight};
use crate::name::{NodeName, SubtreeRoot};
use crate::stats::{CpuStats, apply_cpu_stat};
use crate::threads::{self, AgentThreads, ThreadPlacement};

/// v1 backend over the `cpu` and `cpuacct` mounts (which may be one mount).
#[derive(Debug, Clone)]
pub struct V1Backend {
    cpu: PathBuf,
    cpuacct: PathBuf,
}

impl V1Backend {
    /// `cpu_mount`/`cpuacct_mount` are the hierarchy mount points; `root` the agent's subtree.
    pub fn new(cpu_mount: PathBuf, cpuacct_mount: PathBuf, root: SubtreeRoot) -> Self {
        Self {
            cpu: cpu_mount.join(root.as_path()),
            cpuacct: cpuacct_mount.join(root.as_path()),
        }
    }

    /// The subtree directories, deduplicated when cpu and cpuacct share a mount.
    fn dirs(&self) -> Vec<&Path> {
        if self.cpu == self.cpuacct {
            vec![&self.cpu]
        } else {
            vec![&self.cpu, &self.cpuacct]
        }
    }

    fn cpu_file(&self, node: &NodeName, file: &str) -> PathBuf {
        self.cpu.join(node.dir_name()).join(file)
    }
}

impl CgroupBackend for V1Backend {
    fn kind(&self) -> BackendKind {
        BackendKind::V1
    }

    fn node_path(&self, node: &NodeName) -> PathBuf {
        self.cpu.join(node.dir_name())
    }

    fn create(&self, node: &NodeName) -> Result<()> {
        for d in self.dirs() {
            create_dir(&d.join(node.dir_name()))?;
        }
        Ok(())
    }

    fn exists(&self, node: &NodeName) -> bool {
        self.dirs().iter().all(|d| d.join(node.dir_name()).is_dir())
    }

    /// Those in either hierarchy: a node removed halfway (its `cpu`
    /// directory gone, its `cpuacct` one not) is still listed, so that it
    /// can be removed.
    fn nodes(&self) -> Result<Vec<NodeName>> {
        let mut out = Vec::new();
        for d in self.dirs() {
            out.extend(list_nodes(d)?);
        }
        out.sort();
        out.dedup();
        Ok(out)
    }

    fn add_pid(&self, node: &NodeName, pid: u32) -> Result<()> {
        // Writing to cgroup.procs (not tasks) moves the whole thread group at
        // once, so a thread created during the move cannot be left behind.
        for d in self.dirs() {
            write_file(
                &d.join(node.dir_name()).join("cgroup.procs"),
                &pid.to_string(),
            )?;
        }
        Ok(())
    }

    fn join_files(&self, node: &NodeName) -> Vec<PathBuf> {
        self.dirs()
            .iter()
            .map(|d| d.join(node.dir_name()).join("cgroup.procs"))
            .collect()
    }

    fn set_cpu_max(&self, node: &NodeName, max: CpuMax) -> Result<()> {
        // Lift the quota first so a shorter period never briefly yields a
        // ratio the kernel rejects, then set period, then the new quota.
        let quota = self.cpu_file(node, "cpu.cfs_quota_us");
        write_file(&quota, "-1")?;
        write_file(
            &self.cpu_file(node, "cpu.cfs_period_us"),
            &max.period_us.to_string(),
        )?;
        if max.quota_us.is_some() {
            write_file(&quota, &max.v1_quota())?;
        }
        Ok(())
    }

    fn cpu_max(&self, node: &NodeName) -> Result<CpuMax> {
        let qp = self.cpu_file(node, "cpu.cfs_quota_us");
        let q = read_file(&qp)?;
        let p = read_file(&self.cpu_file(node, "cpu.cfs_period_us"))?;
        CpuMax::parse_v1(&q, &p).ok_or_else(|| Error::Parse {
            path: qp,
            reason: format!("quota {:?} period {:?}", q.trim(), p.trim()),
        })
    }

    fn set_weight(&self, node: &NodeName, weight: CpuWeight) -> Result<()> {
        write_file(
            &self.cpu_file(node, "cpu.shares"),
            &weight.v1_shares().to_string(),
        )
    }

    fn weight(&self, node: &NodeName) -> Result<CpuWeight> {
        read_shares(&self.cpu_file(node, "cpu.shares"))
    }

    fn stats(&self, node: &NodeName) -> Result<CpuStats> {
        let mut s = CpuStats {
            usage_ns: read_number(&self.cpuacct.join(node.dir_name()).join("cpuacct.usage"))?,
            ..CpuStats::default()
        };
        apply_cpu_stat(&mut s, &read_file(&self.cpu_file(node, "cpu.stat"))?, false);
        Ok(s)
    }

    /// Those in either hierarchy (the same ones, as `add_pid` moves a
    /// process into both): of a node removed halfway, what runs in the part
    /// that is left. Only a missing directory counts as absent; the error
    /// (the `cpu` one first) when the node is in neither, or when one
    /// cannot be read for another reason.
    fn pids(&self, node: &NodeName) -> Result<Vec<u32>> {
        let mut out: Option<Vec<u32>> = None;
        let mut absent = None;
        for d in self.dirs() {
            match read_ids(&d.join(node.dir_name()).join("cgroup.procs")) {
                Ok(ids) => out.get_or_insert_with(Vec::new).extend(ids),
                Err(e) if e.is_not_found() => {
                    absent.get_or_insert(e);
                }
                Err(e) => return Err(e),
            }
        }
        match (out, absent) {
            (Some(mut ids), _) => {
                ids.sort_unstable();
                ids.dedup();
                Ok(ids)
            }
            (None, Some(e)) => Err(e),
            (None, None) => Ok(Vec::new()),
        }
    }

    fn tids(&self, node: &NodeName) -> Result<Vec<u32>> {
        read_ids(&self.cpu_file(node, "tasks"))
    }

    fn remove(&self, node: &NodeName) -> Result<()> {
        for d in self.dirs() {
            remove_dir(&d.join(node.dir_name()))?;
        }
        Ok(())
    }

    fn remove_root(&self) -> Result<()> {
        for d in self.dirs() {
            threads::release_v1(d)?;
            remove_dir(d)?;
        }
        Ok(())
    }

    fn set_root_weight(&self, weight: CpuWeight) -> Result<()> {
        for d in self.dirs() {
            create_dir(d)?;
        }
        write_file(
            &self.cpu.join("cpu.shares"),
            &weight.v1_shares().to_string(),
        )
    }

    fn root_weight(&self) -> Result<CpuWeight> {
        read_shares(&self.cpu.join("cpu.shares"))
    }

    fn agent_threads(&self, group: AgentThreads) -> Result<Option<ThreadPlacement>> {
        ThreadPlacement::create_v1(&self.dirs(), group).map(Some)
    }
}

/// Lists node cgroups (directories named `node-*`) below `dir`; a missing dir is empty.
pub(crate) fn list_nodes(dir: &Path) -> Result<Vec<NodeName>> {
    let entries = match std::fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(source) => {
            return Err(Error::Read {
                path: dir.to_path_buf(),
                source,
            });
        }
    };
    let mut out = Vec::new();
    for e in entries {
        let e = e.map_err(|source| Error::Read {
            path: dir.to_path_buf(),
            source,
        })?;
        if e.file_type().is_ok_and(|t| t.is_dir())
            && let Some(n) = e.file_name().to_str().and_then(NodeName::from_dir_name)
        {
            out.push(n);
        }
    }
    out.sort();
    Ok(out)
}

/// Reads a `cpu.shares` file as a weight.
fn read_shares(path: &Path) -> Result<CpuWeight> {
    read_number(path).map(CpuWeight::from_v1_shares)
}
