//! Without privilege eBPF cannot load: the monitor falls back and says why.
//! Runs `configbot-procmon-bench --status` as uid/gid 65534 with no
//! capabilities (via util-linux `setpriv`; directly if not root already).

use std::process::Command;

#[test]
fn unprivileged_start_falls_back_from_ebpf_and_reports_why() {
    let bin = env!("CARGO_BIN_EXE_configbot-procmon-bench");
    let is_root = std::fs::read_to_string("/proc/self/status")
        .expect("status")
        .lines()
        .any(|l| l.starts_with("Uid:") && l.split_whitespace().nth(1) == Some("0"));
    let output = if is_root {
        Command::new("setpriv")
            .args([
                "--reuid=65534",
                "--regid=65534",
                "--clear-groups",
                "--inh-caps=-all",
            ])
            .args([bin, "--status"])
            .output()
            .expect("run setpriv (util-linux)")
    } else {
        Command::new(bin)
            .arg("--status")
            .output()
            .expect("run bench")
    };
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success(),
        "status run failed ({}), stderr: {} (is {bin} reachable by uid 65534?)",
        output.status,
        String::from_utf8_lossy(&output.stderr)
    );
    let status: serde_json::Value = serde_json::from_str(stdout.trim()).expect("status JSON");
    assert_ne!(status["active"], "ebpf", "{status}");
    assert_eq!(status["failed"][0]["kind"], "ebpf", "{status}");
    let reason = status["failed"][0]["reason"].as_str().expect("reason");
    assert!(reason.contains("not permitted"), "{reason}");
    assert!(
        status["summary"]
            .as_str()
            .expect("summary")
            .contains("ebpf failed: "),
        "{status}"
    );
}
