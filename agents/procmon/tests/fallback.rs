//! Fallback order and status reporting with real failures.

use configbot_procmon::{MonitorConfig, MonitorKind, Preference, ProcessMonitor};

/// The scan fails for real (no procfs at the injected root), so the next
/// monitor in the order is used and the status says why the scan failed.
#[tokio::test]
async fn falls_back_to_next_kind_and_reports_why() {
    let config = MonitorConfig {
        proc_root: "/nonexistent/configbot-procmon-fallback".into(),
        ..MonitorConfig::with_preference(Preference::Order(vec![
            MonitorKind::ProcScan,
            MonitorKind::ProcConnector,
        ]))
    };
    let (handle, _stream) = ProcessMonitor::start(config)
        .await
        .expect("connector starts (root)");
    assert_eq!(handle.kind(), MonitorKind::ProcConnector);
    assert_eq!(handle.label(), "proc_connector");
    let failed = &handle.status().failed;
    assert_eq!(failed.len(), 1);
    assert_eq!(failed[0].kind, MonitorKind::ProcScan);
    assert!(
        failed[0]
            .reason
            .contains("/nonexistent/configbot-procmon-fallback")
    );
    let summary = handle.status().summary();
    assert!(
        summary.starts_with("process monitor: proc_connector (proc_scan failed: "),
        "{summary}"
    );
}

#[tokio::test]
async fn all_failing_is_an_error_naming_each() {
    let config = MonitorConfig {
        proc_root: "/nonexistent/configbot-procmon-none".into(),
        ..MonitorConfig::with_preference(Preference::Order(vec![MonitorKind::ProcScan]))
    };
    let err = ProcessMonitor::start(config)
        .await
        .expect_err("nothing works");
    assert!(
        err.to_string()
            .starts_with("no process monitor could be started: proc_scan: "),
        "{err}"
    );
}
