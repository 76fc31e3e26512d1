//! eBPF monitor on real processes (needs root and a kernel with BTF).

mod common;

use std::time::Duration;

use common::{TempDir, is, spawn_true, unique_tag, wait_for};
use configbot_procmon::{MonitorConfig, MonitorKind, Preference, ProcEventKind, ProcessMonitor};

const TIMEOUT: Duration = Duration::from_secs(10);

fn is_root() -> bool {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("Uid:"))
                .map(|l| l.split_whitespace().nth(2) == Some("0"))
        })
        .unwrap_or(false)
}

#[tokio::test]
async fn ebpf_sees_bin_true_exec_and_exit() {
    let (handle, mut stream) = ProcessMonitor::start(MonitorConfig::with_preference(
        Preference::Only(MonitorKind::Ebpf),
    ))
    .await
    .expect("eBPF monitor starts (root, BTF)");
    assert_eq!(handle.kind(), MonitorKind::Ebpf);
    let tag = unique_tag();
    let dir = TempDir::new(&tag);
    let mut child = spawn_true(&dir, &tag);
    let pid = child.0.id();
    let exec = wait_for(
        &mut stream,
        TIMEOUT,
        "exec of /bin/true",
        is(ProcEventKind::Exec, pid),
    )
    .await;
    assert_eq!(exec.filename.as_deref(), Some("/bin/true"));
    assert_eq!(exec.comm.as_deref(), Some("true"));
    assert_eq!(exec.ppid, Some(std::process::id()));
    assert_eq!(exec.source, MonitorKind::Ebpf);
    assert!(exec.cgroup_id.is_some_and(|id| id > 0));
    let exit = wait_for(
        &mut stream,
        TIMEOUT,
        "exit of /bin/true",
        is(ProcEventKind::Exit, pid),
    )
    .await;
    assert_eq!(exit.exit_code, Some(0));
    assert!(exit.timestamp_ns >= exec.timestamp_ns);
    assert!(child.0.wait().expect("wait").success());
    handle.stop().await;
}

#[tokio::test]
async fn auto_picks_ebpf_when_root() {
    let (handle, _stream) = ProcessMonitor::start(MonitorConfig::default())
        .await
        .expect("some monitor starts");
    if is_root() {
        assert_eq!(
            handle.kind(),
            MonitorKind::Ebpf,
            "{}",
            handle.status().summary()
        );
        assert!(handle.status().failed.is_empty());
    } else {
        assert_ne!(handle.kind(), MonitorKind::Ebpf);
        assert_eq!(handle.status().failed[0].kind, MonitorKind::Ebpf);
    }
    assert_eq!(handle.label(), handle.kind().label());
}

/// Several eBPF monitors at once each get every event.
#[tokio::test]
async fn two_ebpf_monitors_coexist() {
    let config = MonitorConfig::with_preference(Preference::Only(MonitorKind::Ebpf));
    let (a, mut sa) = ProcessMonitor::start(config.clone()).await.expect("first");
    let (b, mut sb) = ProcessMonitor::start(config).await.expect("second");
    let tag = unique_tag();
    let dir = TempDir::new(&tag);
    let mut child = spawn_true(&dir, &tag);
    let pid = child.0.id();
    for stream in [&mut sa, &mut sb] {
        wait_for(stream, TIMEOUT, "exec", is(ProcEventKind::Exec, pid)).await;
        wait_for(stream, TIMEOUT, "exit", is(ProcEventKind::Exit, pid)).await;
    }
    assert!(child.0.wait().expect("wait").success());
    assert_eq!(a.lost_events(), 0);
    a.stop().await;
    b.stop().await;
}

/// A process held alive at its first instruction: the exec event carries the
/// cgroup path (read from /proc on receipt), which is the test's own.
#[tokio::test]
async fn ebpf_exec_event_carries_cgroup_path() {
    let (handle, mut stream) = ProcessMonitor::start(MonitorConfig::with_preference(
        Preference::Only(MonitorKind::Ebpf),
    ))
    .await
    .expect("eBPF monitor starts");
    let tag = unique_tag();
    let dir = TempDir::new(&tag);
    let mut child = common::HeldChild::spawn(&dir, &tag);
    let pid = child.pid();
    let exec = wait_for(&mut stream, TIMEOUT, "exec", is(ProcEventKind::Exec, pid)).await;
    let own = configbot_procmon::parse_proc_cgroup(
        &std::fs::read_to_string("/proc/self/cgroup").expect("own cgroup"),
    );
    assert!(own.is_some());
    assert_eq!(exec.cgroup, own);
    child.release();
    let exit = wait_for(&mut stream, TIMEOUT, "exit", is(ProcEventKind::Exit, pid)).await;
    assert_eq!(exit.exit_code, Some(0));
    handle.stop().await;
}

/// A non-zero exit status comes through as the raw wait status.
#[tokio::test]
async fn ebpf_reports_exit_status() {
    let (handle, mut stream) = ProcessMonitor::start(MonitorConfig::with_preference(
        Preference::Only(MonitorKind::Ebpf),
    ))
    .await
    .expect("eBPF monitor starts");
    let mut child = common::ChildGuard(
        std::process::Command::new("/bin/false")
            .arg(unique_tag())
            .spawn()
            .expect("spawn /bin/false"),
    );
    let pid = child.0.id();
    let exit = wait_for(&mut stream, TIMEOUT, "exit", is(ProcEventKind::Exit, pid)).await;
    assert_eq!(exit.exit_code, Some(1 << 8));
    assert_eq!(exit.comm.as_deref(), Some("false"));
    assert_eq!(child.0.wait().expect("wait").code(), Some(1));
    handle.stop().await;
}

const THREADED_CHILD_ENV: &str = "CONFIGBOT_PROCMON_THREADED_CHILD";

/// Not a check by itself: when re-run as a child by
/// `ebpf_reports_one_exit_for_a_multithreaded_process`, exits with live threads.
#[test]
fn threaded_child_helper() {
    if std::env::var_os(THREADED_CHILD_ENV).is_none() {
        return;
    }
    let threads: Vec<_> = (0..4)
        .map(|_| std::thread::spawn(|| std::thread::sleep(Duration::from_millis(50))))
        .collect();
    for t in threads {
        t.join().expect("join");
    }
}

/// Every thread fires sched_process_exit; only the last one is reported.
#[tokio::test]
async fn ebpf_reports_one_exit_for_a_multithreaded_process() {
    let (handle, mut stream) = ProcessMonitor::start(MonitorConfig::with_preference(
        Preference::Only(MonitorKind::Ebpf),
    ))
    .await
    .expect("eBPF monitor starts");
    let mut child = common::ChildGuard(
        std::process::Command::new(std::env::current_exe().expect("own exe"))
            .args(["--exact", "threaded_child_helper", "--quiet"])
            .env(THREADED_CHILD_ENV, "1")
            .stdout(std::process::Stdio::null())
            .spawn()
            .expect("spawn threaded child"),
    );
    let pid = child.0.id();
    assert!(child.0.wait().expect("wait").success());
    // A marker process started after the child is gone: once its exit is in
    // the stream, any duplicate exit of `pid` would have been seen before.
    let tag = unique_tag();
    let dir = TempDir::new(&tag);
    let mut marker = spawn_true(&dir, &tag);
    let marker_pid = marker.0.id();
    let mut exits = 0;
    wait_for(&mut stream, TIMEOUT, "marker exit", |e| {
        if e.kind == ProcEventKind::Exit && e.pid == pid {
            exits += 1;
        }
        e.kind == ProcEventKind::Exit && e.pid == marker_pid
    })
    .await;
    assert!(marker.0.wait().expect("wait").success());
    assert_eq!(exits, 1, "exit events for the multithreaded child");
    handle.stop().await;
}
