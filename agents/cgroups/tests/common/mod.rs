//! Test guard: a uniquely named subtree on the real v1 cpu/cpuacct hierarchies
//! that kills its processes and removes its cgroups on drop, even on failure.
#![allow(dead_code)]

use std::path::PathBuf;
use std::process::Child;
use std::time::{Duration, Instant};

use configbot_cgroups::{CgroupBackend, Layout, NodeName, SubtreeRoot, V1Backend};
use configbot_test_support::try_wait_until;

/// `configbot-agtest-<pid>-<n>`: the leftover check parses the pid back out.
pub fn unique_root() -> String {
    configbot_test_support::unique("configbot-agtest", '-')
}

pub struct Tree {
    pub backend: V1Backend,
    pub root: String,
    pub cpu_root: PathBuf,
    pub nodes: Vec<NodeName>,
    pub children: Vec<Child>,
}

impl Tree {
    pub fn new() -> Self {
        let layout = Layout::detect().unwrap();
        let cpu = layout.v1_cpu.clone().expect("v1 cpu hierarchy");
        let acct = layout.v1_cpuacct.clone().expect("v1 cpuacct hierarchy");
        let root = unique_root();
        let backend = V1Backend::new(cpu.clone(), acct, SubtreeRoot::new(&root).unwrap());
        Self {
            backend,
            cpu_root: cpu.join(&root),
            root,
            nodes: Vec::new(),
            children: Vec::new(),
        }
    }

    pub fn node(&mut self, name: &str) -> NodeName {
        let n = NodeName::new(name).unwrap();
        self.backend.create(&n).unwrap();
        self.nodes.push(n.clone());
        n
    }

    pub fn spawn(&mut self, program: &str, args: &[&str]) -> u32 {
        let child = std::process::Command::new(program)
            .args(args)
            .spawn()
            .unwrap();
        let pid = child.id();
        self.children.push(child);
        pid
    }
}

impl Drop for Tree {
    fn drop(&mut self) {
        for c in &mut self.children {
            let _ = c.kill();
            let _ = c.wait();
        }
        for n in &self.nodes {
            // Processes leave the cgroup once reaped; retry briefly.
            let _ = try_wait_until(
                &format!("{n} to go"),
                Duration::from_secs(5),
                Duration::from_millis(20),
                || self.backend.remove(n).is_ok(),
            );
        }
        let _ = self.backend.remove_root();
        if !std::thread::panicking() {
            assert!(
                !self.cpu_root.exists(),
                "left behind {}",
                self.cpu_root.display()
            );
        }
    }
}

/// CPUs used by a node over `window` from its cgroup usage counter.
pub fn measure_cpus(b: &dyn CgroupBackend, n: &NodeName, window: Duration) -> f64 {
    let u0 = b.stats(n).unwrap().usage_ns;
    let t0 = Instant::now();
    std::thread::sleep(window);
    let u1 = b.stats(n).unwrap().usage_ns;
    (u1 - u0) as f64 / t0.elapsed().as_nanos() as f64
}
