//! Cgroup roots left by a `demo` or `bench` that is gone. Each private robot
//! puts its nodes under `configbot-demo-<pid of the demo or bench>`, and
//! `PrivateRobot::close` removes that root; a SIGKILL (or a crash) skips
//! `close`, so the root stays. A new private robot removes every such root
//! whose process no longer exists ([`stale_roots`] decides, pure;
//! [`sweep`] does the IO), killing what still runs in it first.

use std::path::Path;
use std::time::{Duration, Instant};

use configbot_cgroups::{CgroupBackend, Layout, NodeName, SubtreeRoot, open_backend};

/// Prefix of a private robot's cgroup root; the rest is its owner's pid.
const PREFIX: &str = "configbot-demo-";
/// How long the processes left in a stale root get to die after SIGKILL.
const KILL_TIMEOUT: Duration = Duration::from_secs(5);

/// The cgroup root of a private robot owned by process `pid`.
pub fn private_root(pid: u32) -> String {
    format!("{PREFIX}{pid}")
}

/// The private roots among `dirs` (directory names below a hierarchy's
/// mount) whose owner is not `alive`, sorted. Names that only look alike
/// (`configbot-demo-x`, `configbot-demo-12a`) are not ours and stay.
pub fn stale_roots<'a>(
    dirs: impl IntoIterator<Item = &'a str>,
    alive: impl Fn(u32) -> bool,
) -> Vec<String> {
    let mut out: Vec<String> = dirs
        .into_iter()
        .filter(|d| {
            d.strip_prefix(PREFIX)
                .filter(|pid| !pid.is_empty() && pid.bytes().all(|b| b.is_ascii_digit()))
                .and_then(|pid| pid.parse::<u32>().ok())
                .is_some_and(|pid| !alive(pid))
        })
        .map(str::to_owned)
        .collect();
    out.sort();
    out
}

/// Removes the stale private roots of this host's CPU hierarchies (those the
/// agent uses: v1 `cpu` and `cpuacct`, else cgroup2): SIGKILL to what still
/// runs in their node cgroups, then the node cgroups and the root. A root
/// left in `cpuacct` alone (a close killed halfway) is found too. Returns
/// each stale root with what became of it; one that cannot be removed does
/// not stop the rest.
pub fn sweep() -> anyhow::Result<Vec<(String, anyhow::Result<()>)>> {
    let layout = Layout::detect()?;
    let mounts: Vec<&Path> = if layout.v1_cpu.is_some() {
        [&layout.v1_cpu, &layout.v1_cpuacct]
            .into_iter()
            .flatten()
            .map(|p| p.as_path())
            .collect()
    } else {
        layout.unified.iter().map(|p| p.as_path()).collect()
    };
    let mut names: Vec<String> = Vec::new();
    for mount in mounts {
        names.extend(
            std::fs::read_dir(mount)?
                .filter_map(|e| e.ok())
                .filter(|e| e.file_type().is_ok_and(|t| t.is_dir()))
                .filter_map(|e| e.file_name().into_string().ok()),
        );
    }
    names.sort();
    names.dedup();
    let stale = stale_roots(names.iter().map(String::as_str), |pid| {
        Path::new("/proc").join(pid.to_string()).exists()
    });
    Ok(stale
        .into_iter()
        .map(|root| {
            let done = remove_root(&layout, &root);
            (root, done)
        })
        .collect())
}

fn remove_root(layout: &Layout, root: &str) -> anyhow::Result<()> {
    let backend = open_backend(layout, SubtreeRoot::new(root)?)?;
    for node in backend.nodes()? {
        kill_all(backend.as_ref(), &node)?;
        backend.remove(&node)?;
    }
    backend.remove_root()?;
    Ok(())
}

/// SIGKILL to every process of `node`'s cgroup until it is empty.
fn kill_all(backend: &dyn CgroupBackend, node: &NodeName) -> anyhow::Result<()> {
    let deadline = Instant::now() + KILL_TIMEOUT;
    loop {
        let pids = backend.pids(node)?;
        if pids.is_empty() {
            return Ok(());
        }
        if Instant::now() > deadline {
            anyhow::bail!("processes {pids:?} of {} did not die", node.as_str());
        }
        for pid in pids {
            configbot_agent::send_signal(pid, libc::SIGKILL);
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[cfg(test)]
mod tests {
    use std::os::unix::process::ExitStatusExt;
    use std::process::{Child, Command};

    use super::*;

    /// Each test's sweep removes every dead owner's root, the other test's
    /// too: they take turns.
    static SWEEPING: std::sync::Mutex<()> = std::sync::Mutex::new(());

    /// Kills the stand-in and removes the root if the test fails halfway.
    struct Leftover(Child, Layout, String);

    impl Drop for Leftover {
        fn drop(&mut self) {
            let _ = self.0.kill();
            let _ = self.0.wait();
            let _ = remove_root(&self.1, &self.2);
        }
    }

    /// Removes test cgroups (and what runs in them) if the test fails halfway.
    struct RemoveOnDrop(Vec<std::path::PathBuf>);

    impl Drop for RemoveOnDrop {
        fn drop(&mut self) {
            use configbot_test_support::cgroup::{REMOVE_TIMEOUT, remove_tree};
            let _ = remove_tree(&self.0, REMOVE_TIMEOUT);
        }
    }

    #[test]
    fn a_dead_owners_root_is_killed_and_removed() {
        let _turn = SWEEPING.lock().unwrap_or_else(|e| e.into_inner());
        let layout = Layout::detect().unwrap();
        // A pid whose process is gone, as a SIGKILLed bench's.
        let mut owner = Command::new("true").spawn().unwrap();
        let pid = owner.id();
        owner.wait().unwrap();
        assert!(!Path::new(&format!("/proc/{pid}")).exists());
        let root = private_root(pid);
        let node = NodeName::new("/left_over").unwrap();
        let backend = open_backend(&layout, SubtreeRoot::new(&root).unwrap());
        let made = backend.as_ref().map(|b| b.create(&node));
        if !configbot_test_support::require(
            &format!("root and a CPU cgroup hierarchy (creating {root}: {made:?})"),
            matches!(made, Ok(Ok(()))),
        ) {
            return;
        }
        let backend = backend.unwrap();
        let child = Command::new("sleep").arg("600").spawn().unwrap();
        backend.add_pid(&node, child.id()).unwrap();
        let mut left = Leftover(child, layout, root.clone());

        let swept = sweep().unwrap();
        let (_, done) = swept
            .iter()
            .find(|(r, _)| *r == root)
            .unwrap_or_else(|| panic!("{root} not swept: {swept:?}"));
        assert!(done.is_ok(), "{done:?}");
        let status = left.0.wait().unwrap();
        assert_eq!(status.signal(), Some(libc::SIGKILL), "{status:?}");
        assert!(!backend.exists(&node));
        let mounts = [&left.1.v1_cpu, &left.1.v1_cpuacct, &left.1.unified];
        for mount in mounts.into_iter().flatten() {
            assert!(
                !mount.join(&root).exists(),
                "{root} still in {}",
                mount.display()
            );
        }
    }

    #[test]
    fn a_root_left_in_cpuacct_alone_is_removed() {
        let _turn = SWEEPING.lock().unwrap_or_else(|e| e.into_inner());
        let layout = Layout::detect().unwrap();
        let (Some(cpu), Some(acct)) = (layout.v1_cpu.clone(), layout.v1_cpuacct.clone()) else {
            eprintln!("no v1 cpu and cpuacct hierarchies: a root cannot be left in one alone");
            return;
        };
        if cpu == acct {
            eprintln!("cpu and cpuacct share a mount: a root cannot be left in one alone");
            return;
        }
        let mut owner = Command::new("true").spawn().unwrap();
        let pid = owner.id();
        owner.wait().unwrap();
        let root = private_root(pid);
        let node = NodeName::new("/half_removed").unwrap();
        let backend = open_backend(&layout, SubtreeRoot::new(&root).unwrap()).unwrap();
        let made = backend.create(&node);
        if !configbot_test_support::require(
            &format!("root (creating {root}: {made:?})"),
            made.is_ok(),
        ) {
            return;
        }
        let _left = RemoveOnDrop(vec![acct.join(&root), cpu.join(&root)]);
        // A close killed halfway: the cpu side went, the cpuacct side stayed.
        std::fs::remove_dir(cpu.join(&root).join(node.dir_name())).unwrap();
        std::fs::remove_dir(cpu.join(&root)).unwrap();

        let swept = sweep().unwrap();
        assert!(
            swept.iter().any(|(r, done)| *r == root && done.is_ok()),
            "{root} not swept: {swept:?}"
        );
        assert!(!acct.join(&root).exists(), "{root} still in cpuacct");
    }

    #[test]
    fn only_private_roots_of_dead_owners_are_stale() {
        let dirs = [
            "configbot-demo-100",
            "configbot-demo-200",
            "configbot-demo-",
            "configbot-demo-x",
            "configbot-demo-12a",
            "configbot-demo-+7",
            "configbot",
            "user.slice",
            "configbot-demo-99999999999",
        ];
        let alive = |pid| pid == 200;
        assert_eq!(stale_roots(dirs, alive), vec!["configbot-demo-100"]);
    }

    #[test]
    fn a_private_root_names_its_owner() {
        let root = private_root(4242);
        assert_eq!(stale_roots([root.as_str()], |_| true), Vec::<String>::new());
        assert_eq!(stale_roots([root.as_str()], |p| p != 4242), vec![root]);
    }
}
