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
