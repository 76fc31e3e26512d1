//! /proc scan fallback on real processes (no privilege needed).

mod common;

use std::time::Duration;

use common::{HeldChild, TempDir, is, unique_tag, wait_for};
use configbot_procmon::{MonitorConfig, MonitorKind, Preference, ProcEventKind, ProcessMonitor};

const TIMEOUT: Duration = Duration::from_secs(10);

#[tokio::test]
async fn proc_scan_sees_bin_true_exec_and_exit() {
    let config = MonitorConfig {
        scan_interval: Duration::from_millis(20),
        ..MonitorConfig::with_preference(Preference::Only(MonitorKind::ProcScan))
    };
    let (handle, mut stream) = ProcessMonitor::start(config).await.expect("scan starts");
    assert_eq!(handle.kind(), MonitorKind::ProcScan);
    let tag = unique_tag();
    let dir = TempDir::new(&tag);
    let mut child = HeldChild::spawn(&dir, &tag);
    let pid = child.pid();
    let exec = wait_for(
        &mut stream,
        TIMEOUT,
        "exec of /bin/true",
        is(ProcEventKind::Exec, pid),
    )
    .await;
    assert_eq!(exec.comm.as_deref(), Some("true"));
    assert!(
        exec.filename
            .as_deref()
            .is_some_and(|f| f.ends_with("/true")),
        "filename {:?}",
        exec.filename
    );
    assert_eq!(exec.ppid, Some(std::process::id()));
    assert_eq!(exec.source, MonitorKind::ProcScan);
    child.release();
    let exit = wait_for(
        &mut stream,
        TIMEOUT,
        "exit of /bin/true",
        is(ProcEventKind::Exit, pid),
    )
    .await;
    assert_eq!(exit.comm.as_deref(), Some("true"));
    assert!(exit.timestamp_ns > exec.timestamp_ns);
    handle.stop().await;
}

#[tokio::test]
async fn proc_scan_on_missing_root_fails_with_path() {
    let config = MonitorConfig {
        proc_root: "/nonexistent/configbot-procmon".into(),
        ..MonitorConfig::with_preference(Preference::Only(MonitorKind::ProcScan))
    };
    let err = ProcessMonitor::start(config)
        .await
        .expect_err("no procfs there");
    assert!(
        err.to_string().contains("/nonexistent/configbot-procmon"),
        "{err}"
    );
}
