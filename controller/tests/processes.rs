//! The `configbot` binary as a real process: the Unix socket refuses other
//! users, and `kill -9` of the server loses nothing that was applied.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_configbot");

struct Server(Child);

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn serve(dir: &Path) -> Server {
    let child = Command::new(BIN)
        .args(["serve", "--db"])
        .arg(dir.join("db"))
        .arg("--socket")
        .arg(dir.join("api.sock"))
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(20);
    while std::os::unix::net::UnixStream::connect(dir.join("api.sock")).is_err() {
        assert!(Instant::now() < deadline, "server did not come up");
        std::thread::sleep(Duration::from_millis(20));
    }
    Server(child)
}

fn cli(dir: &Path, args: &[&str]) -> (bool, String) {
    let out = Command::new(BIN)
        .arg("--server")
        .arg(format!("unix://{}", dir.join("api.sock").display()))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.success(),
        format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        ),
    )
}

fn examples() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../manifests/examples")
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
    let mut watch = Command::new(BIN)
        .arg("--server")
        .arg(format!("unix://{}", dir.path().join("api.sock").display()))
        .args(["get", "rs", "-w"])
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let stdout = watch.stdout.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        use std::io::BufRead;
        for line in std::io::BufReader::new(stdout)
            .lines()
            .map_while(Result::ok)
        {
            let _ = tx.send(line);
        }
    });
    let (ok, out) = cli(
        dir.path(),
        &[
            "apply",
            "-f",
            examples().join("basic-nav.yaml").to_str().unwrap(),
        ],
    );
    assert!(ok, "{out}");
    let deadline = Instant::now() + Duration::from_secs(20);
    let mut seen = Vec::new();
    while !seen
        .iter()
        .any(|l: &String| l.contains("basic-nav") && l.contains("Accepted"))
    {
        let left = deadline.saturating_duration_since(Instant::now());
        assert!(
            !left.is_zero(),
            "watch did not show the stack becoming Accepted: {seen:?}"
        );
        if let Ok(l) = rx.recv_timeout(left) {
            seen.push(l);
        }
    }
    let _ = watch.kill();
    let _ = watch.wait();
}

/// The real `kubectl` against the HTTPS listener: apply, get, describe, delete.
#[test]
fn stock_kubectl_works() {
    let Ok(kubectl) = which("kubectl") else {
        panic!("kubectl is not installed; `./x deps` installs it");
    };
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("token"), "t0ken-for-test\n").unwrap();
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let child = Command::new(BIN)
        .args(["serve", "--db"])
        .arg(dir.path().join("db"))
        .arg("--socket")
        .arg(dir.path().join("api.sock"))
        .args(["--listen", &format!("127.0.0.1:{port}"), "--token-file"])
        .arg(dir.path().join("token"))
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let _server = Server(child);
    let deadline = Instant::now() + Duration::from_secs(20);
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(Instant::now() < deadline, "https listener did not come up");
        std::thread::sleep(Duration::from_millis(20));
    }
    let k = |args: &[&str]| {
        let out = Command::new(&kubectl)
            .env("KUBECONFIG", dir.path().join("kubeconfig"))
            .env("HOME", dir.path())
            .args([
                "--server",
                &format!("https://127.0.0.1:{port}"),
                "--token",
                "t0ken-for-test",
                "--certificate-authority",
            ])
            .arg(dir.path().join("tls.crt"))
            .args(args)
            .output()
            .unwrap();
        (
            out.status.success(),
            format!(
                "{}{}",
                String::from_utf8_lossy(&out.stdout),
                String::from_utf8_lossy(&out.stderr)
            ),
        )
    };
    let file = examples().join("basic-nav.yaml");
    let (ok, out) = k(&["apply", "-f", file.to_str().unwrap()]);
    assert!(ok, "{out}");
    assert!(
        out.contains("robotstack.configbot.dev/basic-nav created"),
        "{out}"
    );
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let (ok, out) = k(&["get", "rs"]);
        assert!(ok, "{out}");
        if out.contains("basic-nav") && out.contains("Accepted") {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "stack never showed Accepted:\n{out}"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    // Validation is on (kubectl reads /openapi/v3 and leaves it to the
    // server): an unknown field is refused and named.
    let bad = dir.path().join("bad.yaml");
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
    let out = Command::new(&kubectl)
        .env("HOME", dir.path())
        .args([
            "--server",
            &format!("https://127.0.0.1:{port}"),
            "--insecure-skip-tls-verify",
            "get",
            "rs",
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
}

fn which(name: &str) -> Result<PathBuf, ()> {
    std::env::var_os("PATH")
        .into_iter()
        .flat_map(|p| std::env::split_paths(&p).collect::<Vec<_>>())
        .map(|d| d.join(name))
        .find(|p| p.is_file())
        .ok_or(())
}
