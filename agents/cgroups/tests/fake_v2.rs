//! v2 file formats against a temp-dir fake root (this host's cgroup2 mount has
//! no cpu controller), plus a real-v2 test that runs only where cpu is delegated.

use std::collections::BTreeMap;
use std::fs;
use std::path::Path;

use configbot_cgroups::{
    CgroupBackend, CgroupConfig, CpuLimit, CpuMax, CpuWeight, Error, NodeName, SubtreeRoot,
    V2Backend, apply,
};

fn fake_node(dir: &Path) {
    fs::create_dir_all(dir).unwrap();
    fs::write(dir.join("cpu.max"), "max 100000\n").unwrap();
    fs::write(
        dir.join("cpu.stat"),
        "usage_usec 2500\nuser_usec 2000\nsystem_usec 500\nnr_periods 9\nnr_throttled 3\nthrottled_usec 700\n",
    )
    .unwrap();
    fs::write(
        dir.join("cpu.pressure"),
        "some avg10=2.00 avg60=1.00 avg300=0.50 total=999\nfull avg10=0.00 avg60=0.00 avg300=0.00 total=0\n",
    )
    .unwrap();
    fs::write(dir.join("cgroup.procs"), "").unwrap();
    fs::write(dir.join("cpu.weight"), "100\n").unwrap();
}

#[test]
fn v2_formats_and_rollback_on_fake_root() {
    let tmp = tempfile::tempdir().unwrap();
    let mount = tmp.path();
    fs::write(
        mount.join("cgroup.controllers"),
        "cpuset cpu io memory pids\n",
    )
    .unwrap();
    fs::write(mount.join("cgroup.subtree_control"), "memory\n").unwrap();
    let root = mount.join("configbot");
    fs::create_dir(&root).unwrap();
    fs::write(root.join("cgroup.subtree_control"), "").unwrap();
    fake_node(&root.join("node-a"));
    fake_node(&root.join("node-b"));

    fs::write(root.join("cpu.weight"), "100\n").unwrap();
    let be = V2Backend::new(mount.to_path_buf(), SubtreeRoot::default());
    assert_eq!(be.root_weight().unwrap(), CpuWeight::DEFAULT);
    be.set_root_weight(CpuWeight::new(6400).unwrap()).unwrap();
    assert_eq!(fs::read_to_string(root.join("cpu.weight")).unwrap(), "6400");
    let a = NodeName::new("/a").unwrap();
    let b = NodeName::new("/b").unwrap();
    be.create(&a).unwrap();
    assert_eq!(
        fs::read_to_string(root.join("cgroup.subtree_control")).unwrap(),
        "+cpu"
    );
    assert_eq!(
        fs::read_to_string(mount.join("cgroup.subtree_control")).unwrap(),
        "+cpu"
    );

    be.set_cpu_max(
        &a,
        CpuLimit {
            cpus: Some(0.35),
            period_us: 20_000,
            weight: CpuWeight::DEFAULT,
        }
        .to_cpu_max("/a")
        .unwrap(),
    )
    .unwrap();
    assert_eq!(
        fs::read_to_string(root.join("node-a/cpu.max")).unwrap(),
        "7000 20000"
    );
    assert_eq!(
        be.cpu_max(&a).unwrap(),
        CpuMax {
            quota_us: Some(7000),
            period_us: 20_000
        }
    );

    let s = be.stats(&a).unwrap();
    assert_eq!(
        (s.usage_ns, s.nr_throttled, s.throttled_ns),
        (2_500_000, 3, 700_000)
    );
    assert_eq!(s.pressure.unwrap().avg10, 2.0);

    be.add_pid(&a, 4242).unwrap();
    assert_eq!(
        fs::read_to_string(root.join("node-a/cgroup.procs")).unwrap(),
        "4242"
    );
    assert_eq!(be.nodes().unwrap(), vec![a.clone(), b.clone()]);

    // Make b's cpu.max unwritable: apply must restore a and name b's file.
    fs::remove_file(root.join("node-b/cpu.max")).unwrap();
    fs::create_dir(root.join("node-b/cpu.max")).unwrap();
    let protected = CpuLimit {
        weight: CpuWeight::MAX,
        ..CpuLimit::cpus(0.5)
    };
    let config = CgroupConfig {
        limits: BTreeMap::from([(a.clone(), protected), (b.clone(), CpuLimit::cpus(0.5))]),
    };
    // Reading b's previous value already fails, before any write.
    let err = apply(&be, &config).unwrap_err();
    assert!(matches!(err, Error::Read { .. }), "{err}");
    assert_eq!(
        fs::read_to_string(root.join("node-a/cpu.max")).unwrap(),
        "7000 20000"
    );

    // A write that fails mid-apply (second node) must roll back both nodes.
    let flaky = FailSecondWrite {
        inner: be.clone(),
        writes: Default::default(),
    };
    fs::remove_dir(root.join("node-b/cpu.max")).unwrap();
    fs::write(root.join("node-b/cpu.max"), "max 100000").unwrap();
    let err = apply(&flaky, &config).unwrap_err();
    let Error::Apply {
        node,
        rolled_back,
        source,
        ..
    } = &err
    else {
        panic!("{err}")
    };
    assert_eq!((node.as_str(), *rolled_back), ("/b", 2));
    let Error::Write { path, value, .. } = source.as_ref() else {
        panic!("{source}")
    };
    assert!(path.ends_with("node-b/cpu.max"));
    assert_eq!(value, "50000 100000");
    assert_eq!(
        fs::read_to_string(root.join("node-a/cpu.max")).unwrap(),
        "7000 20000"
    );
    assert_eq!(
        fs::read_to_string(root.join("node-b/cpu.max")).unwrap(),
        "max 100000"
    );
    // a's weight was written before b failed, and restored with its limit.
    assert_eq!(
        fs::read_to_string(root.join("node-a/cpu.weight")).unwrap(),
        "100"
    );

    // A whole apply writes each node's weight (v2 cpu.weight) and reads it back.
    let applied = apply(&be, &config).unwrap();
    assert_eq!(applied[0].weight, CpuWeight::MAX);
    assert_eq!(
        fs::read_to_string(root.join("node-a/cpu.weight")).unwrap(),
        "10000"
    );
    assert_eq!(be.weight(&a).unwrap(), CpuWeight::MAX);
    assert_eq!(be.weight(&b).unwrap(), CpuWeight::DEFAULT);
}

/// Wraps a backend and fails its second `set_cpu_max` call with EACCES.
#[derive(Debug)]
struct FailSecondWrite {
    inner: V2Backend,
    writes: std::sync::atomic::AtomicU32,
}

impl CgroupBackend for FailSecondWrite {
    fn kind(&self) -> configbot_cgroups::BackendKind {
        self.inner.kind()
    }
    fn node_path(&self, n: &NodeName) -> std::path::PathBuf {
        self.inner.node_path(n)
    }
    fn create(&self, n: &NodeName) -> configbot_cgroups::Result<()> {
        self.inner.create(n)
    }
    fn exists(&self, n: &NodeName) -> bool {
        self.inner.exists(n)
    }
    fn nodes(&self) -> configbot_cgroups::Result<Vec<NodeName>> {
        self.inner.nodes()
    }
    fn add_pid(&self, n: &NodeName, p: u32) -> configbot_cgroups::Result<()> {
        self.inner.add_pid(n, p)
    }
    fn join_files(&self, n: &NodeName) -> Vec<std::path::PathBuf> {
        self.inner.join_files(n)
    }
    fn set_cpu_max(&self, n: &NodeName, m: CpuMax) -> configbot_cgroups::Result<()> {
        if self
            .writes
            .fetch_add(1, std::sync::atomic::Ordering::SeqCst)
            == 1
        {
            return Err(Error::Write {
                path: self.inner.node_path(n).join("cpu.max"),
                value: m.to_v2(),
                source: std::io::Error::from(std::io::ErrorKind::PermissionDenied),
            });
        }
        self.inner.set_cpu_max(n, m)
    }
    fn cpu_max(&self, n: &NodeName) -> configbot_cgroups::Result<CpuMax> {
        self.inner.cpu_max(n)
    }
    fn set_weight(&self, n: &NodeName, w: CpuWeight) -> configbot_cgroups::Result<()> {
        self.inner.set_weight(n, w)
    }
    fn weight(&self, n: &NodeName) -> configbot_cgroups::Result<CpuWeight> {
        self.inner.weight(n)
    }
    fn stats(&self, n: &NodeName) -> configbot_cgroups::Result<configbot_cgroups::CpuStats> {
        self.inner.stats(n)
    }
    fn pids(&self, n: &NodeName) -> configbot_cgroups::Result<Vec<u32>> {
        self.inner.pids(n)
    }
    fn tids(&self, n: &NodeName) -> configbot_cgroups::Result<Vec<u32>> {
        self.inner.tids(n)
    }
    fn remove(&self, n: &NodeName) -> configbot_cgroups::Result<()> {
        self.inner.remove(n)
    }
    fn remove_root(&self) -> configbot_cgroups::Result<()> {
        self.inner.remove_root()
    }
    fn set_root_weight(&self, w: CpuWeight) -> configbot_cgroups::Result<()> {
        self.inner.set_root_weight(w)
    }
    fn root_weight(&self) -> configbot_cgroups::Result<CpuWeight> {
        self.inner.root_weight()
    }
    fn agent_threads(
        &self,
        group: configbot_cgroups::AgentThreads,
    ) -> configbot_cgroups::Result<Option<configbot_cgroups::ThreadPlacement>> {
        self.inner.agent_threads(group)
    }
}

/// Runs on hosts whose cgroup2 root offers the cpu controller; on this
/// hybrid host (cpu bound to v1) it reports that and checks nothing more.
#[test]
fn real_v2_cpu_max_where_available() {
    let layout = configbot_cgroups::Layout::detect().unwrap();
    let Some(unified) = layout.unified else {
        eprintln!("no cgroup2 hierarchy on this host: real v2 test not exercised");
        return;
    };
    let controllers = fs::read_to_string(unified.join("cgroup.controllers")).unwrap_or_default();
    if !controllers.split_whitespace().any(|c| c == "cpu") {
        eprintln!(
            "cgroup2 at {} has no cpu controller: real v2 test not exercised",
            unified.display()
        );
        return;
    }
    let root = format!("configbot-agtest-{}-v2", std::process::id());
    let be = V2Backend::new(unified.clone(), SubtreeRoot::new(&root).unwrap());
    let n = NodeName::new("/v2/node").unwrap();
    be.create(&n).unwrap();
    let res = (|| {
        be.set_cpu_max(&n, CpuLimit::cpus(0.2).to_cpu_max("/v2/node")?)?;
        be.cpu_max(&n)
    })();
    let _ = be.remove(&n);
    let _ = be.remove_root();
    assert_eq!(
        res.unwrap(),
        CpuMax {
            quota_us: Some(20_000),
            period_us: 100_000
        }
    );
}
