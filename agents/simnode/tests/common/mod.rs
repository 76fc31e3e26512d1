//! Shared helpers of the simnode integration tests: skip when ROS is absent
//! (fail under CI: `configbot_test_support::require`), masters (Debian's
//! rosmaster or the in-process configbot-ros1 master), child processes in
//! their own process groups (killed on drop) whose stdout lines are
//! timestamped. Free ports, condition waits and skips:
//! `configbot_test_support`.

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use configbot_test_support::{free_port, require, wait_until};

/// How often the tests' condition waits look.
pub const POLL: Duration = Duration::from_millis(50);

/// True when Debian's ROS 1 tools are installed; otherwise says why the
/// test is skipped ([`require`]: a failure under CI).
pub fn ros_available() -> bool {
    let ok = [
        "/usr/bin/rostopic",
        "/usr/bin/rosmaster",
        "/usr/bin/rosnode",
    ]
    .iter()
    .all(|p| Path::new(p).exists())
        && Command::new("/usr/bin/python3")
            .args(["-c", "import rospy, std_msgs.msg"])
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success());
    require(
        "ROS 1 tools or rospy missing; apt-get install -y ros-core python3-rospy python3-rostopic python3-rosnode python3-rosparam python3-roslaunch topic-tools",
        ok,
    )
}

/// A ROS name unique to this process and call.
pub fn unique(prefix: &str) -> String {
    configbot_test_support::unique(prefix, '_')
}

pub fn scripts() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/scripts")
}

/// Which master a test runs against.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MasterKind {
    /// Debian's `rosmaster --core`.
    Rosmaster,
    /// The agent's master (`configbot-ros1`), in this test process.
    Configbot,
}

/// A running master; stopped on drop.
pub struct Master {
    pub env: RosEnv,
    _proc: Option<Proc>,
    _configbot: Option<(tokio::runtime::Runtime, configbot_ros1::Ros1DataPlane)>,
    _dir: tempfile::TempDir,
}

impl std::fmt::Debug for Master {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Master").field("env", &self.env).finish()
    }
}

impl Master {
    /// Sets (or with `None` removes) the configbot master's adaptor on the
    /// edge `topic` → `subscriber`; panics on Debian's rosmaster.
    pub fn set_adaptor(&self, topic: &str, subscriber: &str, rate_hz: Option<f64>) {
        use configbot_dataplane::{AdaptorSetting, DataPlane, EdgeId};
        let (rt, dp) = self
            ._configbot
            .as_ref()
            .expect("adaptors need the configbot master");
        let _guard = rt.enter();
        let edge = EdgeId {
            topic: topic.into(),
            subscriber: subscriber.into(),
        };
        match rate_hz {
            Some(r) => dp.set_adaptor(&edge, AdaptorSetting { rate_hz: Some(r) }),
            None => dp.remove_adaptor(&edge),
        }
        .unwrap();
    }

    pub fn start(kind: MasterKind) -> Master {
        let dir = tempfile::tempdir().unwrap();
        let port = free_port();
        let env = RosEnv {
            master_uri: format!("http://localhost:{port}/"),
            home: dir.path().to_path_buf(),
        };
        let (proc, configbot) = match kind {
            MasterKind::Rosmaster => (
                Some(env.spawn("rosmaster", &["--core", "-p", &port.to_string()])),
                None,
            ),
            MasterKind::Configbot => {
                let rt = tokio::runtime::Runtime::new().unwrap();
                let cfg = configbot_ros1::Ros1Config {
                    master_uri: env.master_uri.clone(),
                    ..configbot_ros1::Ros1Config::default()
                };
                let registry = prometheus::Registry::new();
                let dp = rt
                    .block_on(configbot_ros1::Ros1DataPlane::start(
                        cfg,
                        &dir.path().join("ros1.db"),
                        &registry,
                    ))
                    .unwrap();
                (None, Some((rt, dp)))
            }
        };
        wait_until(
            "the master to answer",
            Duration::from_secs(20),
            POLL,
            || env.try_run("rosnode", &["list"]).is_some(),
        );
        Master {
            env,
            _proc: proc,
            _configbot: configbot,
            _dir: dir,
        }
    }
}

/// Environment for ROS tools against a test master.
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
            .env_remove("ROS_IP")
            .env("ROS_HOME", &self.home)
            .env("ROS_LOG_DIR", self.home.join("log"))
            .env("PATH", path)
            .env("PYTHONUNBUFFERED", "1")
            .stdin(Stdio::null());
        c
    }

    /// Runs a tool to completion; stdout when it succeeded.
    pub fn try_run(&self, program: &str, args: &[&str]) -> Option<String> {
        let out = self
            .command(program)
            .args(args)
            .stderr(Stdio::null())
            .output()
            .ok()?;
        out.status
            .success()
            .then(|| String::from_utf8_lossy(&out.stdout).into_owned())
    }

    pub fn spawn(&self, program: &str, args: &[&str]) -> Proc {
        let mut c = self.command(program);
        c.args(args);
        Proc::spawn(c)
    }

    /// A rospy script from tests/scripts under Debian's python.
    pub fn script(&self, script: &str, args: &[&str]) -> Proc {
        let mut c = self.command("/usr/bin/python3");
        c.arg(scripts().join(script)).args(args);
        Proc::spawn(c)
    }

    /// The simnode binary under test.
    pub fn simnode(&self, args: &[&str]) -> Proc {
        let mut c = self.command(env!("CARGO_BIN_EXE_configbot-simnode"));
        c.args(args);
        Proc::spawn(c)
    }

    pub fn node_list(&self) -> Vec<String> {
        self.try_run("rosnode", &["list"])
            .unwrap_or_default()
            .lines()
            .map(|l| l.trim().to_string())
            .collect()
    }
}

/// A child in its own process group (killed group-wide on drop), its
/// stdout lines timestamped: `configbot_test_support`'s.
pub use configbot_test_support::GroupChild as Proc;

/// What the tests read of a simnode's or a listener's stdout.
pub trait Msgs {
    /// "msg seq latency_ms len" lines received in [from, to).
    fn msgs_between(&self, from: Instant, to: Instant) -> Vec<(u64, f64, usize)>;

    /// Every "msg" line so far.
    fn msg_count(&self) -> usize;
}

impl Msgs for Proc {
    fn msgs_between(&self, from: Instant, to: Instant) -> Vec<(u64, f64, usize)> {
        self.lines_between(from, to)
            .iter()
            .filter_map(|l| parse_msg(l))
            .collect()
    }

    fn msg_count(&self) -> usize {
        self.lines().iter().filter_map(|l| parse_msg(l)).count()
    }
}

/// A "msg seq latency_ms len" line's fields.
fn parse_msg(l: &str) -> Option<(u64, f64, usize)> {
    let mut w = l.strip_prefix("msg ")?.split_whitespace();
    Some((
        w.next()?.parse().ok()?,
        w.next()?.parse().ok()?,
        w.next()?.parse().ok()?,
    ))
}

/// Rate (Hz) of the messages `p` printed over the next `secs` seconds, and
/// those messages.
pub fn rate_over(p: &Proc, secs: f64) -> (f64, Vec<(u64, f64, usize)>) {
    let from = Instant::now();
    std::thread::sleep(Duration::from_secs_f64(secs));
    let to = Instant::now();
    let m = p.msgs_between(from, to);
    (m.len() as f64 / (to - from).as_secs_f64(), m)
}

/// User + system CPU time of process `pid` (from /proc/PID/stat).
pub fn cpu_time(pid: u32) -> Duration {
    let s = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap();
    let rest = &s[s.rfind(')').unwrap() + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    // Fields 14 and 15 of stat (utime, stime) are 11 and 12 after the comm.
    let ticks: u64 = f[11].parse::<u64>().unwrap() + f[12].parse::<u64>().unwrap();
    Duration::from_secs_f64(ticks as f64 / 100.0)
}

/// Number of threads of process `pid` named `name` (its `comm`, as
/// `std::thread::Builder::name` set it, cut to 15 bytes by the kernel).
pub fn threads_named(pid: u32, name: &str) -> usize {
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else {
        panic!("process {pid} is gone");
    };
    tasks
        .filter_map(|t| std::fs::read_to_string(t.ok()?.path().join("comm")).ok())
        .filter(|comm| comm.trim_end() == name)
        .count()
}
