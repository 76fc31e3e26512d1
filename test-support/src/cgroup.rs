//! Private cgroups of a test on the v1 CPU hierarchies (`cpu`, `cpuacct`;
//! no other controller): names unique to the test process, a [`CpuCgroup`]
//! that processes (the test itself too) can join and that is emptied and
//! removed on drop, [`remove_tree`] (and [`remove_subtree`]) for a subtree
//! another program made, and
//! [`leftovers`] for the check that nothing of a finished test remains.
//!
//! The hierarchies' mount points are the caller's (`configbot_cgroups::
//! Layout` knows them), so that this crate depends on no workspace crate.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Duration;

use crate::process::kill9;
use crate::wait::{TimedOut, try_wait_until};

static COUNTER: AtomicU32 = AtomicU32::new(0);

/// `<prefix><sep><pid><sep><n>`: unique to this process and call (one
/// counter for every prefix). With `-`, a cgroup name whose owner
/// [`leftovers`] parses back; with `_`, a valid ROS name.
pub fn unique(prefix: &str, sep: char) -> String {
    format!(
        "{prefix}{sep}{}{sep}{}",
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    )
}

/// How long [`CpuCgroup`]'s drop goes on killing and removing.
pub const REMOVE_TIMEOUT: Duration = Duration::from_secs(10);

/// Moves process `pid` (all its threads) into the cgroup at `dir`.
pub fn add_to(dir: &Path, pid: u32) -> std::io::Result<()> {
    std::fs::write(dir.join("cgroup.procs"), pid.to_string())
}

/// A cgroup `<cpu mount>/<name>` in the v1 `cpu` hierarchy, made for one
/// test. On drop the test process goes back to the cgroup it came from
/// (if it joined), every other process still inside is killed and the
/// cgroup is removed (for up to [`REMOVE_TIMEOUT`]; a failure is printed).
#[derive(Debug)]
pub struct CpuCgroup {
    dir: PathBuf,
    /// The test process's cgroup before [`CpuCgroup::join`].
    home: Option<PathBuf>,
}

impl CpuCgroup {
    /// Creates `<cpu_mount>/<name>` (no error when it exists).
    pub fn create(cpu_mount: &Path, name: &str) -> std::io::Result<CpuCgroup> {
        let dir = cpu_mount.join(name);
        std::fs::create_dir_all(&dir)?;
        Ok(CpuCgroup { dir, home: None })
    }

    pub fn path(&self) -> &Path {
        &self.dir
    }

    /// Where the test process was before [`CpuCgroup::join`] (None before
    /// it joined).
    pub fn home(&self) -> Option<&Path> {
        self.home.as_deref()
    }

    /// Writes a control file, e.g. `cpu.shares` or `cpu.cfs_quota_us`.
    pub fn set(&self, file: &str, value: impl std::fmt::Display) -> std::io::Result<()> {
        std::fs::write(self.dir.join(file), value.to_string())
    }

    /// Moves process `pid` (all its threads) into this cgroup.
    pub fn add(&self, pid: u32) -> std::io::Result<()> {
        add_to(&self.dir, pid)
    }

    /// Moves this test process in; drop moves it back to where it was (in
    /// the hierarchy mounted at `cpu_mount`, from /proc/self/cgroup).
    pub fn join(&mut self, cpu_mount: &Path) -> std::io::Result<()> {
        self.home = own_cpu_cgroup(cpu_mount);
        self.add(std::process::id())
    }
}

impl Drop for CpuCgroup {
    fn drop(&mut self) {
        if let Some(home) = self.home.take() {
            let _ = std::fs::write(home.join("cgroup.procs"), std::process::id().to_string());
        }
        if let Err(e) = remove_tree(std::slice::from_ref(&self.dir), REMOVE_TIMEOUT) {
            eprintln!("test-support: {e}");
        }
    }
}

/// This process's cgroup in the v1 hierarchy that has the `cpu` controller,
/// mounted at `cpu_mount` (from /proc/self/cgroup).
pub fn own_cpu_cgroup(cpu_mount: &Path) -> Option<PathBuf> {
    let text = std::fs::read_to_string("/proc/self/cgroup").ok()?;
    text.lines().find_map(|l| {
        let mut parts = l.splitn(3, ':');
        let (_, controllers, path) = (parts.next()?, parts.next()?, parts.next()?);
        controllers
            .split(',')
            .any(|c| c == "cpu")
            .then(|| cpu_mount.join(path.trim_start_matches('/')))
    })
}

/// Kills every process (but this one) in the cgroups `dirs` and below and
/// removes them, the deepest first, retrying every 20 ms for up to
/// `timeout` (a killed process leaves its cgroup once reaped). This
/// process's own threads there (an in-process agent's data plane, which
/// has a cgroup of its own) move up to the parent of their tree's root.
/// `Ok` when none of them exists any more. For a subtree root in each CPU
/// hierarchy.
pub fn remove_tree(dirs: &[PathBuf], timeout: Duration) -> Result<(), TimedOut> {
    let what = format!("cgroups {dirs:?} to empty and go");
    try_wait_until(&what, timeout, Duration::from_millis(20), || {
        let mut gone = true;
        for dir in dirs {
            for cg in depth_first(dir) {
                if std::fs::remove_dir(&cg).is_ok() {
                    continue;
                }
                gone = false;
                for pid in procs(&cg) {
                    kill9(pid);
                }
                if let Some(parent) = dir.parent() {
                    for tid in own_threads(&cg) {
                        let _ = std::fs::write(parent.join("tasks"), tid.to_string());
                    }
                }
            }
        }
        gone
    })
}

/// The threads of this process in the v1 cgroup `dir`.
fn own_threads(dir: &Path) -> Vec<u32> {
    std::fs::read_to_string(dir.join("tasks"))
        .unwrap_or_default()
        .lines()
        .filter_map(|l| l.trim().parse::<u32>().ok())
        .filter(|t| Path::new("/proc/self/task").join(t.to_string()).exists())
        .collect()
}

/// [`remove_tree`] of the cgroup `name` directly below each of `mounts`
/// (a subtree root in each CPU hierarchy).
pub fn remove_subtree(
    mounts: impl IntoIterator<Item = PathBuf>,
    name: &str,
    timeout: Duration,
) -> Result<(), TimedOut> {
    let dirs: Vec<PathBuf> = mounts.into_iter().map(|m| m.join(name)).collect();
    remove_tree(&dirs, timeout)
}

/// `dir` and the cgroups below it, children before their parent; empty
/// when `dir` does not exist.
fn depth_first(dir: &Path) -> Vec<PathBuf> {
    if !dir.is_dir() {
        return Vec::new();
    }
    let mut out: Vec<PathBuf> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .filter(|e| e.file_type().is_ok_and(|t| t.is_dir()))
        .flat_map(|e| depth_first(&e.path()))
        .collect();
    out.push(dir.to_path_buf());
    out
}

/// The processes in cgroup `dir` but this one.
fn procs(dir: &Path) -> Vec<u32> {
    std::fs::read_to_string(dir.join("cgroup.procs"))
        .unwrap_or_default()
        .lines()
        .filter_map(|l| l.trim().parse().ok())
        .filter(|p| *p != std::process::id())
        .collect()
}

/// Cgroups named `<prefix>-<pid>-...` (see [`unique`]) directly below the
/// `mounts` whose test process `pid` is gone (or is this one, which runs
/// last): what a finished test left behind.
pub fn leftovers(mounts: &[PathBuf], prefix: &str) -> Vec<PathBuf> {
    let me = std::process::id().to_string();
    let mut left = Vec::new();
    for mount in mounts {
        for e in std::fs::read_dir(mount).unwrap_or_else(|e| panic!("{}: {e}", mount.display())) {
            let name = e.unwrap().file_name().into_string().unwrap_or_default();
            let Some(rest) = name.strip_prefix(prefix).and_then(|r| r.strip_prefix('-')) else {
                continue;
            };
            let pid = rest.split('-').next().unwrap_or("");
            // A live owner (a test binary still running, e.g. another clone's) is not ours to judge.
            if pid != me && Path::new("/proc").join(pid).exists() {
                continue;
            }
            left.push(mount.join(&name));
        }
    }
    left
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unique_names_differ_per_call_and_carry_the_pid() {
        let (a, b) = (unique("t", '-'), unique("t", '-'));
        assert_ne!(a, b);
        let pid = std::process::id().to_string();
        assert_eq!(a.split('-').nth(1), Some(pid.as_str()), "{a}");
        assert!(unique("ros", '_').starts_with(&format!("ros_{pid}_")));
    }

    #[test]
    fn leftovers_are_the_prefixed_dirs_of_dead_owners_and_of_this_process() {
        let mount = tempfile_dir("leftovers");
        let me = std::process::id();
        // pid 0 never names a live process in /proc.
        for name in [
            format!("cbt-{me}-0"),
            "cbt-0-1".to_string(),
            "cbt-1-0".to_string(),
            "other-0-0".to_string(),
            "cbt".to_string(),
        ] {
            std::fs::create_dir(mount.join(name)).unwrap();
        }
        let mut left = leftovers(std::slice::from_ref(&mount), "cbt");
        left.sort();
        // pid 1 (init) is alive: its dir is not ours to judge.
        assert_eq!(
            left,
            vec![mount.join("cbt-0-1"), mount.join(format!("cbt-{me}-0"))]
        );
        std::fs::remove_dir_all(&mount).unwrap();
    }

    #[test]
    fn remove_tree_and_remove_subtree_remove_nested_dirs_deepest_first() {
        // Empty plain directories stand in for cgroups (a cgroup's control
        // files do not keep rmdir from removing it; plain files would).
        let root = tempfile_dir("tree");
        std::fs::create_dir_all(root.join("a/b/c")).unwrap();
        std::fs::create_dir_all(root.join("d")).unwrap();
        remove_tree(
            &[root.clone(), root.join("missing")],
            Duration::from_secs(1),
        )
        .unwrap();
        assert!(!root.exists());
        // The same subtree below two mounts.
        let mounts = [tempfile_dir("mount"), tempfile_dir("mount")];
        for m in &mounts {
            std::fs::create_dir_all(m.join("sub/node-a")).unwrap();
        }
        remove_subtree(mounts.clone(), "sub", Duration::from_secs(1)).unwrap();
        for m in &mounts {
            assert!(!m.join("sub").exists());
            std::fs::remove_dir(m).unwrap();
        }
    }

    #[test]
    fn remove_tree_times_out_naming_the_cgroups_it_could_not_remove() {
        let root = tempfile_dir("stuck");
        std::fs::write(root.join("cgroup.procs"), "").unwrap();
        let err = remove_tree(std::slice::from_ref(&root), Duration::from_millis(50)).unwrap_err();
        assert!(
            err.to_string().contains(&root.display().to_string()),
            "{err}"
        );
        std::fs::remove_dir_all(&root).unwrap();
    }

    /// A real `cpu` cgroup below this process's own (so a test run from a
    /// low-priority cgroup stays inside it): a sleeping child added to it
    /// is killed on drop and the cgroup removed; joining moves this process
    /// in and drop moves it back. Needs root and a v1 `cpu` hierarchy.
    #[test]
    fn a_cpu_cgroup_is_joined_left_emptied_and_removed_on_drop() {
        let mount = Path::new("/sys/fs/cgroup/cpu");
        let home = own_cpu_cgroup(mount).filter(|h| h.is_dir());
        let Some(home) = home else {
            crate::skip("no cgroup v1 cpu hierarchy at /sys/fs/cgroup/cpu");
            return;
        };
        let name = unique("configbot-test-support", '-');
        let mut cg = match CpuCgroup::create(&home, &name) {
            Ok(cg) => cg,
            Err(e) => {
                crate::skip(&format!(
                    "cannot create a cpu cgroup in {}: {e}",
                    home.display()
                ));
                return;
            }
        };
        let dir = cg.path().to_path_buf();
        cg.set("cpu.shares", 2048).unwrap();
        let mut child = std::process::Command::new("sleep")
            .arg("600")
            .spawn()
            .unwrap();
        cg.add(child.id()).unwrap();
        cg.join(mount).unwrap();
        assert_eq!(own_cpu_cgroup(mount).as_deref(), Some(dir.as_path()));
        // (Children that other tests spawn meanwhile land here too.)
        assert!(procs(&dir).contains(&child.id()));
        drop(cg);
        assert_eq!(own_cpu_cgroup(mount), Some(home));
        assert!(!child.wait().unwrap().success(), "the child was killed");
        assert!(!dir.exists());
    }

    fn tempfile_dir(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(unique(&format!("configbot-test-support-{tag}"), '-'));
        std::fs::create_dir(&d).unwrap();
        d
    }
}
