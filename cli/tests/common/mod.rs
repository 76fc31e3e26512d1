//! Helpers of the tests that run the `configbot` binary as a real process
//! (`cli.rs`, `kubectl.rs`, `processes.rs`): a private server on a temp
//! dir's Unix socket, optionally with an HTTPS listener and a token, the
//! CLI against it, stock kubectl, a child's stdout lines to wait for, and
//! the example manifests. Waits and guards: `configbot_test_support`.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::Receiver;
use std::time::Duration;

use configbot_test_support::{ChildGuard, free_port, try_wait_until, wait_until, which};

/// The `configbot` binary under test.
pub const BIN: &str = env!("CARGO_BIN_EXE_configbot");

/// How long a server may take to come up.
const UP: Duration = Duration::from_secs(20);

/// The repository's `manifests/examples` folder.
pub fn examples() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../manifests/examples")
}

/// The file of example `name` (e.g. `basic-nav`), as an argument.
pub fn example(name: &str) -> String {
    examples()
        .join(format!("{name}.yaml"))
        .display()
        .to_string()
}

fn server_command(dir: &Path) -> Command {
    let mut c = Command::new(BIN);
    c.args(["serve", "--db"])
        .arg(dir.join("db"))
        .arg("--socket")
        .arg(dir.join("api.sock"))
        .stderr(Stdio::null());
    c
}

/// `configbot serve` on `dir/db` and the socket `dir/api.sock`, once the
/// socket accepts; killed on drop.
pub fn serve(dir: &Path) -> ChildGuard {
    let server = ChildGuard(server_command(dir).spawn().unwrap());
    wait_until("the server's socket", UP, Duration::from_millis(20), || {
        std::os::unix::net::UnixStream::connect(dir.join("api.sock")).is_ok()
    });
    server
}

/// [`serve`] with an HTTPS listener on a free port of 127.0.0.1 that takes
/// `token` (written to `dir/token`), once that port accepts; the server
/// and the port. It writes its CA to `dir/tls.crt`.
pub fn serve_https(dir: &Path, token: &str) -> (ChildGuard, u16) {
    std::fs::write(dir.join("token"), format!("{token}\n")).unwrap();
    let port = free_port();
    let server = server_command(dir)
        .args(["--listen", &format!("127.0.0.1:{port}"), "--token-file"])
        .arg(dir.join("token"))
        .spawn()
        .unwrap();
    let server = ChildGuard(server);
    wait_until("the https listener", UP, Duration::from_millis(20), || {
        std::net::TcpStream::connect(("127.0.0.1", port)).is_ok()
    });
    (server, port)
}

/// Runs `configbot --server unix://DIR/api.sock ARGS`: (success, stdout, stderr).
pub fn cli(dir: &Path, args: &[&str]) -> (bool, String, String) {
    let out = Command::new(BIN)
        .arg("--server")
        .arg(format!("unix://{}", dir.join("api.sock").display()))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Stock kubectl; the tests fail (not skip) without it.
pub fn kubectl() -> PathBuf {
    which("kubectl").expect("kubectl is not installed; `./x deps` installs it")
}

/// The token of [`Kube`]'s server.
pub const TOKEN: &str = "t0ken-for-kubectl-tests";

/// A private server with an HTTPS listener ([`serve_https`]), and kubectl
/// aimed at it.
pub struct Kube {
    pub dir: tempfile::TempDir,
    pub port: u16,
    pub kubectl: PathBuf,
    pub server: ChildGuard,
}

impl Kube {
    pub fn start() -> Kube {
        let kubectl = kubectl();
        let dir = tempfile::tempdir().unwrap();
        let (server, port) = serve_https(dir.path(), TOKEN);
        Kube {
            dir,
            port,
            kubectl,
            server,
        }
    }

    /// kubectl's flags for this server: address, token and CA.
    pub fn flags(&self) -> Vec<String> {
        vec![
            "--server".into(),
            format!("https://127.0.0.1:{}", self.port),
            "--token".into(),
            TOKEN.into(),
            "--certificate-authority".into(),
            self.dir.path().join("tls.crt").display().to_string(),
        ]
    }

    /// kubectl with this server's flags, its config and home in the temp dir.
    pub fn command(&self) -> Command {
        let mut c = Command::new(&self.kubectl);
        c.env("KUBECONFIG", self.dir.path().join("kubeconfig"))
            .env("HOME", self.dir.path())
            .args(self.flags());
        c
    }

    /// Runs kubectl; (success, stdout, stderr).
    pub fn run(&self, args: &[&str]) -> (bool, String, String) {
        let out = self.command().args(args).output().unwrap();
        (
            out.status.success(),
            String::from_utf8_lossy(&out.stdout).into_owned(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    }

    /// Runs kubectl and requires success; its standard output.
    pub fn ok(&self, args: &[&str]) -> String {
        let (ok, out, err) = self.run(args);
        assert!(ok, "kubectl {args:?} failed:\n{out}{err}");
        out
    }

    /// An object as JSON, or None when the server has no such object.
    pub fn object(&self, kind: &str, name: &str) -> Option<serde_json::Value> {
        let (ok, out, err) = self.run(&["get", kind, name, "-o", "json"]);
        if !ok {
            assert!(
                err.contains("NotFound") || err.contains("not found"),
                "{err}"
            );
            return None;
        }
        Some(serde_json::from_str(&out).unwrap())
    }
}

/// A child's stdout lines, read on a thread as they come.
pub struct Lines {
    rx: Receiver<String>,
    /// The lines read so far that no wait took.
    pub seen: Vec<String>,
}

impl Lines {
    /// Takes `child`'s stdout (which must be piped).
    pub fn of(child: &mut Child) -> Lines {
        let stdout = child.stdout.take().expect("a piped stdout");
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
        Lines {
            rx,
            seen: Vec::new(),
        }
    }

    /// Waits up to `timeout` for a line that `f` accepts and returns it;
    /// the lines before it are kept in `seen`. Panics naming `what` and
    /// the lines seen.
    pub fn wait_for(&mut self, what: &str, timeout: Duration, f: impl Fn(&str) -> bool) -> String {
        let (rx, seen) = (&self.rx, &mut self.seen);
        try_wait_until(what, timeout, Duration::from_millis(20), || {
            for l in rx.try_iter() {
                if f(&l) {
                    return Some(l);
                }
                seen.push(l);
            }
            None
        })
        .unwrap_or_else(|e| panic!("{e}; seen:\n{}", self.seen.join("\n")))
    }
}
