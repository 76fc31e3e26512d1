//! Stopping an eBPF monitor releases its BPF programs, links and maps.
//! Alone in its test binary so no other test's BPF objects are counted.

use configbot_procmon::{MonitorConfig, MonitorKind, Preference, ProcessMonitor};

/// Open fds of this process that are BPF objects (programs, links, maps).
fn bpf_fds() -> usize {
    std::fs::read_dir("/proc/self/fd")
        .expect("list fds")
        .flatten()
        .filter(|e| {
            std::fs::read_link(e.path())
                .map(|t| t.to_string_lossy().starts_with("anon_inode:bpf"))
                .unwrap_or(false)
        })
        .count()
}

#[tokio::test]
async fn stop_releases_bpf_objects() {
    let before = bpf_fds();
    let (handle, _stream) = ProcessMonitor::start(MonitorConfig::with_preference(
        Preference::Only(MonitorKind::Ebpf),
    ))
    .await
    .expect("eBPF monitor starts");
    let running = bpf_fds();
    assert!(
        running >= before + 4,
        "programs, links and maps open: {before} -> {running}"
    );
    handle.stop().await;
    assert_eq!(bpf_fds(), before);
}
