//! Shared helpers of the ROS 1 integration tests: skip when ROS is absent
//! (fail under CI: `configbot_test_support::require`), process guards that
//! kill whole process groups and line readers that timestamp a child's
//! stdout. Free ports, condition waits and skips:
//! `configbot_test_support`.

#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use configbot_test_support::{require, try_wait_until};

/// How often the tests' condition waits look.
pub const POLL: Duration = Duration::from_millis(50);

/// True when Debian's ROS 1 tools are installed; otherwise says why the
/// test is skipped. CI installs them (see the crate README), and there a
/// missing tool fails the test ([`require`]).
pub fn ros_available() -> bool {
    require(
        "`rostopic` not found; install ros-core python3-rospy python3-rostopic python3-rosnode python3-rosparam python3-roslaunch topic-tools",
        Path::new("/usr/bin/rostopic").exists()
            || configbot_test_support::which("rostopic").is_some(),
    )
}

/// A name unique to this process and call (a valid ROS name part).
pub fn unique(prefix: &str) -> String {
    configbot_test_support::unique(prefix, '_')
}

pub fn scripts() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/scripts")
}

/// Environment for ROS tools against the test master.
#[derive(Debug, Clone)]
pub struct RosEnv {
    pub master_uri: String,
    pub home: PathBuf,
}

impl RosEnv {
    pub fn command(&self, program: &str) -> Command {
        let mut c = Command::new(program);
        let path = format!(
            "/usr/bin:/bin:{}",
            std::env::var("PATH").unwrap_or_default()
        );
        c.env("ROS_MASTER_URI", &self.master_uri)
            .env("ROS_HOSTNAME", "localhost")
            .env("ROS_HOME", &self.home)
            .env("ROS_LOG_DIR", self.home.join("log"))
            .env("PATH", path)
            .env("PYTHONUNBUFFERED", "1")
            .stdin(Stdio::null());
        c
    }

    /// Runs a tool to completion and returns stdout (panics with context).
    pub fn run(&self, program: &str, args: &[&str]) -> String {
        let out = self
            .command(program)
            .args(args)
            .output()
            .unwrap_or_else(|e| panic!("running {program}: {e}"));
        assert!(
            out.status.success(),
            "{program} {args:?} failed: {}\n{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).into_owned()
    }

    /// Starts a rospy script under Debian's python.
    pub fn script(&self, script: &str, args: &[&str]) -> Proc {
        let mut c = self.command("/usr/bin/python3");
        c.arg(scripts().join(script)).args(args);
        Proc::spawn(c)
    }

    pub fn spawn(&self, program: &str, args: &[&str]) -> Proc {
        let mut c = self.command(program);
        c.args(args);
        Proc::spawn(c)
    }
}

/// A child in its own process group; killed (group-wide) on drop. Its
/// stdout lines are collected with arrival times.
#[derive(Debug)]
pub struct Proc {
    pub child: Child,
    pub lines: Arc<Mutex<Vec<(Instant, String)>>>,
}

impl Proc {
    pub fn spawn(mut c: Command) -> Proc {
        c.stdout(Stdio::piped())
            .stderr(Stdio::null())
            .process_group(0);
        let mut child = c.spawn().unwrap_or_else(|e| panic!("spawning {c:?}: {e}"));
        let lines = Arc::new(Mutex::new(Vec::new()));
        let out = child.stdout.take().unwrap();
        let l = lines.clone();
        std::thread::spawn(move || {
            for line in BufReader::new(out).lines().map_while(Result::ok) {
                l.lock().unwrap().push((Instant::now(), line));
            }
        });
        Proc { child, lines }
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    pub fn has_line(&self, s: &str) -> bool {
        self.lines
            .lock()
            .unwrap()
            .iter()
            .any(|(_, l)| l.contains(s))
    }

    /// Messages ("msg ..." lines) received in [from, to).
    pub fn count_between(&self, from: Instant, to: Instant) -> usize {
        self.lines
            .lock()
            .unwrap()
            .iter()
            .filter(|(t, l)| l.starts_with("msg") && *t >= from && *t < to)
            .count()
    }

    /// SIGINT (roslaunch then stops the nodes it started in their own
    /// sessions), wait up to `timeout`, then kill.
    pub fn interrupt(&mut self, timeout: Duration) {
        let _ = Command::new("kill")
            .args(["-INT", &self.child.id().to_string()])
            .stderr(Stdio::null())
            .status();
        let exited = try_wait_until("the child to exit", timeout, POLL, || {
            matches!(self.child.try_wait(), Ok(Some(_)))
        });
        if exited.is_err() {
            self.kill();
        }
    }

    /// Sends `signal` (e.g. `STOP`, `CONT`) to the child's process group.
    pub fn signal(&self, signal: &str) {
        let ok = Command::new("kill")
            .args([
                &format!("-{signal}"),
                "--",
                &format!("-{}", self.child.id()),
            ])
            .status()
            .is_ok_and(|s| s.success());
        assert!(ok, "kill -{signal} {}", self.child.id());
    }

    pub fn kill(&mut self) {
        let _ = Command::new("kill")
            .args(["-KILL", "--", &format!("-{}", self.child.id())])
            .stderr(Stdio::null())
            .status();
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        self.kill();
    }
}

/// Rate a listener sees over `secs` seconds from now.
pub fn measure_rate(p: &Proc, secs: f64) -> f64 {
    let from = Instant::now();
    std::thread::sleep(Duration::from_secs_f64(secs));
    p.count_between(from, Instant::now()) as f64 / secs
}

/// Kills a process we did not spawn directly (e.g. a node roslaunch started
/// in its own session) on drop.
#[derive(Debug)]
pub struct PidGuard(pub Option<u32>);

impl Drop for PidGuard {
    fn drop(&mut self) {
        if let Some(pid) = self.0 {
            let _ = Command::new("kill")
                .args(["-KILL", &pid.to_string()])
                .stderr(Stdio::null())
                .status();
        }
    }
}
