//! Shared helpers of the ROS 1 integration tests: skip when ROS is absent
//! (fail under CI: `configbot_test_support::require`), process guards that
//! kill whole process groups and line readers that timestamp a child's
//! stdout. Free ports, condition waits and skips:
//! `configbot_test_support`.

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use configbot_test_support::require;

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

/// A child in its own process group (killed group-wide on drop), its
/// stdout lines timestamped: `configbot_test_support`'s.
pub use configbot_test_support::GroupChild as Proc;

/// What the tests read of a listener's stdout.
pub trait Msgs {
    /// Messages ("msg ..." lines) received in [from, to).
    fn count_between(&self, from: Instant, to: Instant) -> usize;
}

impl Msgs for Proc {
    fn count_between(&self, from: Instant, to: Instant) -> usize {
        self.lines_between(from, to)
            .iter()
            .filter(|l| l.starts_with("msg"))
            .count()
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
