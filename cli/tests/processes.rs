//! The `configbot` binary as a real process: the Unix socket refuses other
//! users, and `kill -9` of the server loses nothing that was applied.

mod common;

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use common::{BIN, Kube, Lines, examples, serve};
use configbot_test_support::{ChildGuard, try_wait_until};

/// Runs the CLI against the server in `dir`: (success, stdout and stderr).
fn cli(dir: &Path, args: &[&str]) -> (bool, String) {
    let (ok, out, err) = common::cli(dir, args);
    (ok, out + &err)
}

/// `-f` arguments for the three valid example files (the folder also holds `invalid/`).
fn example_files() -> Vec<String> {
    ["basic-nav", "intermed-nav", "terrain-nav"]
        .iter()
        .flat_map(|n| {
            [
                "-f".to_string(),
                examples().join(format!("{n}.yaml")).display().to_string(),
            ]
        })
        .collect()
}

#[test]
fn kill_9_loses_nothing_applied() {
    let dir = tempfile::tempdir().unwrap();
    let mut server = serve(dir.path());
    let files = example_files();
    let apply: Vec<&str> = std::iter::once("apply")
        .chain(files.iter().map(String::as_str))
        .collect();
    let (ok, out) = cli(dir.path(), &apply);
    assert!(ok, "{out}");
    assert_eq!(out.matches(" created").count(), 6, "{out}");
    // SIGKILL: no shutdown path runs.
    server.0.kill().unwrap();
    server.0.wait().unwrap();
    drop(server);
    let _server = serve(dir.path());
    let (ok, out) = cli(dir.path(), &["get", "rs"]);
    assert!(ok, "{out}");
    for name in ["basic-nav", "intermed-nav", "terrain-nav"] {
        assert!(out.contains(name), "{name} missing after kill -9:\n{out}");
    }
    let (ok, out) = cli(dir.path(), &apply);
    assert!(ok, "{out}");
    assert_eq!(
        out.matches(" unchanged").count(),
        6,
        "re-apply is idempotent:\n{out}"
    );
}

#[test]
fn bad_input_applies_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let _server = serve(dir.path());
    let bad = examples().join("invalid/05-dangling-app.yaml");
    let (ok, out) = cli(
        dir.path(),
        &[
            "apply",
            "-f",
            examples().join("basic-nav.yaml").to_str().unwrap(),
            "-f",
            bad.to_str().unwrap(),
        ],
    );
    assert!(!ok);
    assert!(
        out.contains("spec.metrics[0].app: app \"detector\" is not in RobotStack \"dangling\""),
        "{out}"
    );
    assert!(out.contains("nothing was applied"), "{out}");
    let (_, out) = cli(dir.path(), &["get", "rs"]);
    assert!(out.contains("No robotstacks found"), "{out}");
}

#[test]
fn unix_socket_refuses_other_users() {
    let dir = tempfile::tempdir().unwrap();
    // The temp dir must be traversable for the other user to reach the socket at all.
    std::fs::set_permissions(
        dir.path(),
        std::os::unix::fs::PermissionsExt::from_mode(0o755),
    )
    .unwrap();
    let _server = serve(dir.path());
    let sock = dir.path().join("api.sock");
    let mode = std::fs::metadata(&sock).unwrap();
    assert_eq!(
        std::os::unix::fs::PermissionsExt::mode(&mode.permissions()) & 0o777,
        0o600
    );
    let as_nobody = Command::new("setpriv")
        .args([
            "--reuid=65534",
            "--regid=65534",
            "--clear-groups",
            "/usr/bin/python3",
            "-c",
        ])
        .arg(format!(
            "import socket; s=socket.socket(socket.AF_UNIX); s.connect({:?})",
            sock.to_str().unwrap()
        ))
        .output()
        .unwrap();
    assert!(
        !as_nobody.status.success(),
        "nobody connected to a 0600 root socket"
    );
    assert!(
        String::from_utf8_lossy(&as_nobody.stderr).contains("Permission denied"),
        "{}",
        String::from_utf8_lossy(&as_nobody.stderr)
    );
}

#[test]
fn watch_streams_changes() {
    let dir = tempfile::tempdir().unwrap();
    let _server = serve(dir.path());
    let mut watch = ChildGuard(
        Command::new(BIN)
            .arg("--server")
            .arg(format!("unix://{}", dir.path().join("api.sock").display()))
            .args(["get", "rs", "-w"])
            .stdout(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let mut lines = Lines::of(&mut watch.0);
    let (ok, out) = cli(
        dir.path(),
        &[
            "apply",
            "-f",
            examples().join("basic-nav.yaml").to_str().unwrap(),
        ],
    );
    assert!(ok, "{out}");
    lines.wait_for(
        "the watch to show the stack becoming Accepted",
        Duration::from_secs(20),
        |l| l.contains("basic-nav") && l.contains("Accepted"),
    );
}

/// The real `kubectl` against the HTTPS listener: apply, get, describe, delete.
#[test]
fn stock_kubectl_works() {
    let kube = Kube::start();
    let k = |args: &[&str]| {
        let (ok, out, err) = kube.run(args);
        (ok, out + &err)
    };
    let file = examples().join("basic-nav.yaml");
    let (ok, out) = k(&["apply", "-f", file.to_str().unwrap()]);
    assert!(ok, "{out}");
    assert!(
        out.contains("robotstack.configbot.dev/basic-nav created"),
        "{out}"
    );
    let mut last = String::new();
    let shown = try_wait_until(
        "the stack to show Accepted",
        Duration::from_secs(20),
        Duration::from_millis(100),
        || {
            let (ok, out) = k(&["get", "rs"]);
            assert!(ok, "{out}");
            last = out;
            last.contains("basic-nav") && last.contains("Accepted")
        },
    );
    shown.unwrap_or_else(|e| panic!("{e}:\n{last}"));
    // Validation is on (kubectl reads /openapi/v3 and leaves it to the
    // server): an unknown field is refused and named.
    let bad = kube.dir.path().join("bad.yaml");
    std::fs::write(
        &bad,
        "apiVersion: configbot.dev/v1alpha1\nkind: RobotStack\nmetadata: {name: bad}\n\
         spec:\n  apps:\n    - name: a\n      nodes: [{name: /n, run: {command: x}, colour: red}]\n",
    )
    .unwrap();
    let (ok, out) = k(&["apply", "-f", bad.to_str().unwrap()]);
    assert!(!ok && out.contains("colour"), "{out}");
    let (ok, out) = k(&["get", "pspec", "basic-nav", "-o", "yaml"]);
    assert!(ok && out.contains("stackRef"), "{out}");
    let (ok, out) = k(&["describe", "rs", "basic-nav"]);
    assert!(ok && out.contains("Events:"), "{out}");
    let (ok, out) = k(&["delete", "pspec", "basic-nav"]);
    assert!(ok, "{out}");
    let (_, out) = k(&["get", "pspec"]);
    assert!(out.contains("No resources found"), "{out}");
    // Without the token, nothing.
    let out = Command::new(&kube.kubectl)
        .env("HOME", kube.dir.path())
        .args([
            "--server",
            &format!("https://127.0.0.1:{}", kube.port),
            "--insecure-skip-tls-verify",
            "get",
            "rs",
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
}
