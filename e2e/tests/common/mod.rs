#![allow(dead_code)]
//! Harness for end-to-end scenarios: a private ConfigBot (`configbot serve
//! --agent`, the program users run) in a temp dir with its own cgroup subtree
//! and ROS master port, driven through the `configbot` CLI. Dropping a
//! [`Robot`] kills the server and every process in its cgroup subtree and
//! removes the subtree, even when the test failed.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

use configbot_cgroups::{CgroupBackend, Layout, SubtreeRoot, V1Backend};
use serde_json::Value;

/// The `configbot` program built for these tests.
pub fn configbot_bin() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_configbot-e2e"))
}

/// The repository's `manifests/examples` folder.
pub fn examples() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../manifests/examples")
}

static COUNTER: AtomicU32 = AtomicU32::new(0);

/// `configbot-e2e-<pid>-<n>`: unique per test, parsed back by the leftover check.
pub fn unique_root() -> String {
    format!(
        "configbot-e2e-{}-{}",
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    )
}

/// A free TCP port on localhost (never ROS's 11311).
pub fn free_port() -> u16 {
    loop {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .map(|a| a.port())
            .unwrap_or(0);
        if port != 0 && port != 11311 {
            return port;
        }
    }
}

/// A private ConfigBot with its embedded agent.
pub struct Robot {
    pub dir: tempfile::TempDir,
    pub root: String,
    pub ros_port: u16,
    server: Option<Child>,
}

impl Robot {
    /// Starts `configbot serve --agent` and waits for its API socket.
    pub fn start() -> Robot {
        let mut r = Robot {
            dir: tempfile::tempdir().expect("temp dir"),
            root: unique_root(),
            ros_port: free_port(),
            server: None,
        };
        r.spawn_server();
        r
    }

    pub fn socket(&self) -> PathBuf {
        self.dir.path().join("api.sock")
    }

    pub fn master_uri(&self) -> String {
        format!("http://localhost:{}/", self.ros_port)
    }

    fn spawn_server(&mut self) {
        let _ = std::fs::remove_file(self.socket());
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(self.dir.path().join("server.log"))
            .expect("server log");
        let child = Command::new(configbot_bin())
            .arg("serve")
            .arg("--db")
            .arg(self.dir.path().join("configbot.db"))
            .arg("--socket")
            .arg(self.socket())
            .args(["--agent", "--cgroup-root", &self.root])
            .args(["--ros-master-uri", &self.master_uri()])
            .env("ROS_HOSTNAME", "localhost")
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .expect("spawn configbot serve");
        self.server = Some(child);
        let deadline = Instant::now() + Duration::from_secs(30);
        while std::os::unix::net::UnixStream::connect(self.socket()).is_err() {
            if let Some(Ok(Some(status))) = self.server.as_mut().map(|c| c.try_wait()) {
                panic!("configbot serve exited ({status}):\n{}", self.server_log());
            }
            assert!(
                Instant::now() < deadline,
                "configbot serve did not come up within 30 s:\n{}",
                self.server_log()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// The server's stderr so far.
    pub fn server_log(&self) -> String {
        std::fs::read_to_string(self.dir.path().join("server.log")).unwrap_or_default()
    }

    /// `kill -9` of the server (its nodes keep running), then a new server on
    /// the same database, subtree and ROS port.
    pub fn kill9_and_restart(&mut self) {
        if let Some(mut c) = self.server.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
        self.spawn_server();
    }

    /// Runs `configbot ARGS` against this robot's control plane.
    pub fn cli(&self, args: &[&str]) -> Output {
        Command::new(configbot_bin())
            .arg("--server")
            .arg(format!("unix://{}", self.socket().display()))
            .args(args)
            .output()
            .expect("run configbot")
    }

    /// `configbot apply -f` of `yaml` (written to a file first); panics on failure.
    pub fn apply(&self, yaml: &str) {
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let file = self.dir.path().join(format!("apply-{n}.yaml"));
        std::fs::write(&file, yaml).expect("write manifest");
        let out = self.cli(&["apply", "-f", file.to_str().expect("utf-8 path")]);
        assert!(
            out.status.success(),
            "apply failed:\n{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    }

    /// An object as JSON (`configbot get KIND NAME -o json`), if it exists.
    pub fn get(&self, kind: &str, name: &str) -> Option<Value> {
        let out = self.cli(&["get", kind, name, "-o", "json"]);
        if !out.status.success() {
            return None;
        }
        serde_json::from_slice(&out.stdout).ok()
    }

    /// Polls `get KIND NAME` until `cond` holds; panics with the last object
    /// and the server log after `timeout`.
    pub fn wait_for(
        &self,
        kind: &str,
        name: &str,
        timeout: Duration,
        what: &str,
        cond: impl Fn(&Value) -> bool,
    ) -> Value {
        let deadline = Instant::now() + timeout;
        loop {
            let obj = self.get(kind, name);
            if let Some(o) = &obj
                && cond(o)
            {
                return o.clone();
            }
            if Instant::now() > deadline {
                panic!(
                    "timed out after {timeout:?} waiting for {kind}/{name}: {what}\nlast: {}\nserver log:\n{}",
                    obj.map(|o| serde_json::to_string_pretty(&o).unwrap_or_default())
                        .unwrap_or_else(|| "(none)".into()),
                    self.server_log()
                );
            }
            std::thread::sleep(Duration::from_millis(250));
        }
    }

    /// Pids in node cgroups of this robot's subtree.
    pub fn pids(&self) -> Vec<u32> {
        let Some(b) = v1_backend(&self.root) else {
            return Vec::new();
        };
        let mut out = Vec::new();
        for n in b.nodes().unwrap_or_default() {
            out.extend(b.pids(&n).unwrap_or_default());
        }
        out
    }
}

impl Drop for Robot {
    fn drop(&mut self) {
        if let Some(mut c) = self.server.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
        nuke(&self.root);
    }
}

/// A manifest from `manifests/examples` with `command: configbot` pointed at
/// the program built for the tests.
pub fn example(name: &str) -> String {
    let text = std::fs::read_to_string(examples().join(name)).expect("example exists");
    text.replace(
        "command: configbot\n",
        &format!("command: {}\n", configbot_bin().display()),
    )
}

fn v1_backend(root: &str) -> Option<V1Backend> {
    let l = Layout::detect().ok()?;
    Some(V1Backend::new(
        l.v1_cpu?,
        l.v1_cpuacct?,
        SubtreeRoot::new(root).ok()?,
    ))
}

/// Kills every process in every node cgroup below `root`, then removes them.
pub fn nuke(root: &str) {
    let Some(b) = v1_backend(root) else { return };
    for n in b.nodes().unwrap_or_default() {
        let deadline = Instant::now() + Duration::from_secs(10);
        loop {
            let pids = b.pids(&n).unwrap_or_default();
            if pids.is_empty() && b.remove(&n).is_ok() {
                break;
            }
            for p in pids {
                kill9(p);
            }
            if Instant::now() > deadline {
                eprintln!("e2e: cannot empty the cgroup of {n}");
                break;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
    let _ = b.remove_root();
}

fn kill9(pid: u32) {
    let Ok(pid) = libc::pid_t::try_from(pid) else {
        return;
    };
    #[allow(unsafe_code)]
    // SAFETY: kill(2) with a pid read from the test's own cgroup and a valid signal.
    unsafe {
        libc::kill(pid, libc::SIGKILL);
    }
}
