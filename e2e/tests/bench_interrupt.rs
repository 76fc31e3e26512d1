//! Ctrl-C on `configbot bench`: the bench stops its current robot's nodes,
//! removes its cgroup subtree (`configbot-demo-<its pid>`) and exits
//! non-zero saying it was interrupted. Real processes and cgroups: the test
//! waits until the bench's robot runs nodes, sends SIGINT, and checks that
//! the process exits, the subtree is gone in every v1 hierarchy and the
//! nodes' processes are gone; interrupted after its first stack, its
//! `bench.json` keeps that stack's rows, marked incomplete. The guard kills
//! the bench and removes what it left if the test fails.

mod common;

use std::process::{Child, Command, ExitStatus};
use std::time::{Duration, Instant};

use configbot_test_support::try_wait_until;

/// How often the waits for the bench and its nodes look.
const POLL: Duration = Duration::from_millis(50);

/// The bench process; killed, and its cgroups and nodes removed, on drop.
struct Bench {
    child: Child,
}

impl Bench {
    fn root(&self) -> String {
        format!("configbot-demo-{}", self.child.id())
    }

    fn wait_exit(&mut self, timeout: Duration) -> Option<ExitStatus> {
        try_wait_until("the bench to exit", timeout, POLL, || {
            self.child.try_wait().ok().flatten()
        })
        .ok()
    }
}

impl Drop for Bench {
    fn drop(&mut self) {
        let root = self.root();
        common::kill_and_remove(&mut self.child, &root);
    }
}

/// Every pid in a cgroup directory and its descendants.
fn pids_below(dir: &std::path::Path) -> Vec<u32> {
    let mut out: Vec<u32> = std::fs::read_to_string(dir.join("cgroup.procs"))
        .unwrap_or_default()
        .lines()
        .filter_map(|l| l.trim().parse().ok())
        .collect();
    for e in std::fs::read_dir(dir).into_iter().flatten().flatten() {
        if e.file_type().is_ok_and(|t| t.is_dir()) {
            out.extend(pids_below(&e.path()));
        }
    }
    out
}

/// Whether `pid` is a live process (not gone, not a zombie).
fn alive(pid: u32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat"))
        .ok()
        .and_then(|s| {
            s.rsplit_once(')')
                .map(|(_, rest)| rest.trim_start().to_string())
        })
        .is_some_and(|rest| !rest.starts_with('Z'))
}

/// Starts `configbot bench --quick`, waits (at most `wait`) until `ready`
/// holds for the node pids in its subtree and its stdout, sends `signal`,
/// and checks the bench exits 130 saying it was interrupted, with its
/// subtree and node processes gone. Returns the bench's output folder
/// (`None` when the machine has no cgroup v1 cpu hierarchy).
fn interrupt_when(
    signal: libc::c_int,
    wait: Duration,
    what: &str,
    ready: impl Fn(&[u32], &str) -> bool,
) -> Option<tempfile::TempDir> {
    let Some(cpu) = configbot_cgroups::Layout::detect()
        .ok()
        .and_then(|l| l.v1_cpu)
    else {
        configbot_test_support::skip("no cgroup v1 cpu hierarchy");
        return None;
    };
    let _serial = common::serial();
    let dir = tempfile::tempdir().expect("temp dir");
    let (out_log, err_log) = (dir.path().join("stdout"), dir.path().join("stderr"));
    let child = Command::new(common::configbot_bin())
        .args(["bench", "--quick", "--out"])
        .arg(dir.path().join("out"))
        .env("ROS_HOSTNAME", "localhost")
        .stdout(std::fs::File::create(&out_log).expect("stdout log"))
        .stderr(std::fs::File::create(&err_log).expect("stderr log"))
        .spawn()
        .expect("start configbot bench");
    let mut bench = Bench { child };
    let subtree = cpu.join(bench.root());
    let stdout = || std::fs::read_to_string(&out_log).unwrap_or_default();
    let logs = || {
        format!(
            "stdout:\n{}\nstderr:\n{}",
            stdout(),
            std::fs::read_to_string(&err_log).unwrap_or_default()
        )
    };

    let started = Instant::now();
    let found = try_wait_until(what, wait, Duration::from_millis(100), || {
        let pids = pids_below(&subtree);
        if ready(&pids, &stdout()) {
            return Some(pids);
        }
        if let Ok(Some(s)) = bench.child.try_wait() {
            panic!("the bench exited ({s}) before {what}: {}", logs());
        }
        None
    });
    let nodes =
        found.unwrap_or_else(|_| panic!("not {what} within {} s: {}", wait.as_secs(), logs()));
    assert!(nodes.iter().all(|&p| alive(p)));

    let pid = libc::pid_t::try_from(bench.child.id()).expect("pid");
    #[allow(unsafe_code)]
    // SAFETY: kill(2) on the child this test started and still owns (not reaped).
    let rc = unsafe { libc::kill(pid, signal) };
    assert_eq!(rc, 0, "send signal {signal}");
    let sent = Instant::now();
    let status = bench.wait_exit(Duration::from_secs(60)).unwrap_or_else(|| {
        panic!(
            "the bench did not exit within 60 s of signal {signal}: {}",
            logs()
        )
    });
    let took = sent.elapsed();
    assert!(!status.success(), "exit status {status}: {}", logs());
    assert_eq!(status.code(), Some(130), "{}", logs());
    let err = std::fs::read_to_string(&err_log).unwrap_or_default();
    assert!(err.contains("interrupted"), "{}", logs());

    // The subtree is gone in every hierarchy, and so are the nodes.
    let left = common::cgroup_dirs(&bench.root());
    assert!(left.is_empty(), "left behind: {left:?}: {}", logs());
    let mut running: Vec<u32> = nodes.clone();
    let gone = try_wait_until("the nodes to end", Duration::from_secs(5), POLL, || {
        running.retain(|&p| alive(p));
        running.is_empty()
    });
    gone.unwrap_or_else(|e| panic!("{e}: nodes still running: {running:?}"));
    eprintln!(
        "bench interrupted (signal {signal}) {:.1} s after start, {what}, with {} node processes: exited {status} {:.1} s later, subtree and nodes gone",
        sent.duration_since(started).as_secs_f64(),
        nodes.len(),
        took.as_secs_f64()
    );
    Some(dir)
}

#[test]
fn ctrl_c_stops_the_bench_robot_and_removes_its_cgroups() {
    // As soon as the first robot runs a few nodes.
    interrupt_when(
        libc::SIGINT,
        Duration::from_secs(120),
        "the first robot's nodes ran",
        |pids, _| pids.len() >= 2,
    );
}

#[test]
fn an_interrupted_bench_keeps_the_stacks_it_finished_in_bench_json() {
    // Once basic-nav's table is printed, while the cross-evaluation or the
    // timeline runs a robot: bench.json holds basic-nav's rows, marked
    // incomplete.
    let Some(dir) = interrupt_when(
        libc::SIGINT,
        Duration::from_secs(420),
        "basic-nav's rows were measured and a later step ran a robot",
        |pids, out| pids.len() >= 2 && out.contains("SETTLED S"),
    ) else {
        return;
    };
    let path = dir.path().join("out").join("bench.json");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let json: serde_json::Value = serde_json::from_str(&text).expect("bench.json is JSON");
    assert_eq!(json["complete"], false, "{text}");
    let methods: Vec<&str> = json["results"]
        .as_array()
        .expect("results")
        .iter()
        .filter(|r| r["stack"] == "basic-nav")
        .filter_map(|r| r["method"].as_str())
        .collect();
    for m in ["default", "cgroup-only", "configbot"] {
        assert!(methods.contains(&m), "no basic-nav {m} row in {methods:?}");
    }
}

#[test]
fn sigterm_mid_tuning_stops_the_robot_and_removes_its_cgroups() {
    // While the cgroup-only run tunes (its spec applied on its own robot).
    interrupt_when(
        libc::SIGTERM,
        Duration::from_secs(240),
        "the cgroup-only run was tuning",
        |pids, out| {
            pids.len() >= 2
                && out
                    .split("==> basic-nav: cgroup-only")
                    .nth(1)
                    .is_some_and(|after| after.contains("trial"))
        },
    );
}
