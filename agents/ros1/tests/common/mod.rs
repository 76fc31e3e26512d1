//! Shared helpers of the ROS 1 integration tests: skip when ROS is absent
//! (fail under CI),
//! free ports, process guards that kill whole process groups, line readers
//! that timestamp a child's stdout, and condition waits with timeouts.

#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// True when Debian's ROS 1 tools are installed; otherwise says why the
/// test is skipped. CI installs them (see the crate README), and there a
/// missing tool fails the test ([`skip`]).
pub fn ros_available() -> bool {
    let ok = Path::new("/usr/bin/rostopic").exists() || which("rostopic");
    if !ok {
        skip(
            "`rostopic` not found; install ros-core python3-rospy python3-rostopic python3-rosnode python3-rosparam python3-roslaunch topic-tools",
        );
    }
    ok
}

/// Says why a test cannot run on this machine and lets it pass, unless
/// `CI=true` or `CONFIGBOT_REQUIRE=1` is set: then a missing prerequisite
/// fails the test instead of skipping it silently.
pub fn skip(why: &str) {
    let required = std::env::var("CI").is_ok_and(|v| v == "true")
        || std::env::var("CONFIGBOT_REQUIRE").is_ok_and(|v| v == "1");
    assert!(
        !required,
        "cannot run: {why} (CI=true or CONFIGBOT_REQUIRE=1 makes a skip a failure)"
    );
    eprintln!("SKIPPED: {why}");
}

fn which(bin: &str) -> bool {
    std::env::var_os("PATH")
        .is_some_and(|p| std::env::split_paths(&p).any(|d| d.join(bin).exists()))
}

/// A free TCP port (never 11311).
pub fn free_port() -> u16 {
    loop {
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let p = l.local_addr().unwrap().port();
        if p != 11311 {
            return p;
        }
    }
}

static COUNTER: AtomicU32 = AtomicU32::new(0);

/// A name unique to this process and call.
pub fn unique(prefix: &str) -> String {
    format!(
        "{prefix}_{}_{}",
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    )
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
        let end = Instant::now() + timeout;
        while Instant::now() < end {
            if matches!(self.child.try_wait(), Ok(Some(_))) {
                return;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        self.kill();
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

/// Waits until `f` holds, panicking with `what` after `timeout`.
pub fn wait_for(what: &str, timeout: Duration, mut f: impl FnMut() -> bool) {
    let end = Instant::now() + timeout;
    while Instant::now() < end {
        if f() {
            return;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    panic!("timed out after {timeout:?} waiting for {what}");
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
