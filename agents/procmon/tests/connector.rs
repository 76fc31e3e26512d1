//! Netlink proc connector fallback on real processes (needs root / CAP_NET_ADMIN).

mod common;

use std::time::Duration;

use common::{TempDir, is, spawn_true, unique_tag, wait_for};
use configbot_procmon::{MonitorConfig, MonitorKind, Preference, ProcEventKind, ProcessMonitor};

const TIMEOUT: Duration = Duration::from_secs(10);

#[tokio::test]
async fn proc_connector_sees_bin_true_exec_and_exit() {
    let (handle, mut stream) = ProcessMonitor::start(MonitorConfig::with_preference(
        Preference::Only(MonitorKind::ProcConnector),
    ))
    .await
    .expect("proc connector starts (root)");
    assert_eq!(handle.kind(), MonitorKind::ProcConnector);
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
    assert_eq!(exec.source, MonitorKind::ProcConnector);
    assert!(exec.timestamp_ns > 0);
    let exit = wait_for(
        &mut stream,
        TIMEOUT,
        "exit of /bin/true",
        is(ProcEventKind::Exit, pid),
    )
    .await;
    assert_eq!(exit.exit_code, Some(0));
    assert_eq!(exit.ppid, Some(std::process::id()));
    assert!(exit.timestamp_ns >= exec.timestamp_ns);
    assert!(child.0.wait().expect("wait").success());
    handle.stop().await;
}

/// Two connector monitors at once both see the same process.
#[tokio::test]
async fn two_proc_connectors_coexist() {
    let config = MonitorConfig::with_preference(Preference::Only(MonitorKind::ProcConnector));
    let (a, mut sa) = ProcessMonitor::start(config.clone()).await.expect("first");
    let (b, mut sb) = ProcessMonitor::start(config).await.expect("second");
    let tag = unique_tag();
    let dir = TempDir::new(&tag);
    let mut child = spawn_true(&dir, &tag);
    let pid = child.0.id();
    wait_for(
        &mut sa,
        TIMEOUT,
        "exit on first",
        is(ProcEventKind::Exit, pid),
    )
    .await;
    wait_for(
        &mut sb,
        TIMEOUT,
        "exit on second",
        is(ProcEventKind::Exit, pid),
    )
    .await;
    assert!(child.0.wait().expect("wait").success());
    a.stop().await;
    b.stop().await;
}
