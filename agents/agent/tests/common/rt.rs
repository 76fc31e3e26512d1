//! Helpers of the node-runtime tests: a guard that owns a runtime, its
//! cgroup subtree, temp dir and outside processes (all cleaned up on drop,
//! also on failure), ROS environment, timestamped child output.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use configbot_agent::runtime::{DEFAULT_BACKEND, DataPlaneOptions, NodeRuntime, RuntimeOptions};
use configbot_agent::{AgentSettings, StackSpec};
use configbot_api::policy::PolicyConfig;
use configbot_cgroups::CgroupBackend;
use configbot_manifests::{Manifest, RobotStack};
use configbot_procmon::Preference;

use configbot_test_support::{free_port, require};

use super::{nuke, unique_root, v1_backend};

/// True when Debian's ROS 1 is installed; otherwise says why the test skips
/// (fails under CI: [`require`]).
pub fn ros_available() -> bool {
    require(
        "/usr/bin/rostopic not found; apt-get install ros-core python3-rospy python3-rostopic",
        Path::new("/usr/bin/rostopic").exists(),
    )
}

/// How often the runtime tests' condition waits look.
pub const RT_POLL: Duration = Duration::from_millis(50);

pub fn script(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/scripts")
        .join(name)
        .to_string_lossy()
        .into_owned()
}

/// A child in its own process group (killed group-wide on drop), its
/// stdout lines timestamped: `configbot_test_support`'s.
pub use configbot_test_support::GroupChild as Proc;

/// "msg" lines that `p` printed in [from, to).
pub fn count_between(p: &Proc, from: Instant, to: Instant) -> usize {
    p.lines_between(from, to)
        .iter()
        .filter(|l| *l == "msg")
        .count()
}

/// The bag size cap of the runtimes under test, in MB.
pub const RECORDING_MAX_MB: u64 = 2;

/// Whether `e` or any error under it is an `AddrInUse` I/O error.
fn addr_in_use(e: &(dyn std::error::Error + 'static)) -> bool {
    let mut cur = Some(e);
    while let Some(err) = cur {
        if err
            .downcast_ref::<std::io::Error>()
            .is_some_and(|io| io.kind() == std::io::ErrorKind::AddrInUse)
        {
            return true;
        }
        cur = err.source();
    }
    false
}

/// Owns one runtime under test with everything it created.
pub struct RtEnv {
    pub root: String,
    pub dir: tempfile::TempDir,
    pub master_uri: String,
    pub rt: Option<NodeRuntime>,
    pub procs: Vec<Proc>,
}

impl RtEnv {
    pub fn new() -> Self {
        Self {
            root: unique_root(),
            dir: tempfile::tempdir().unwrap(),
            master_uri: format!("http://localhost:{}/", free_port()),
            rt: None,
            procs: Vec::new(),
        }
    }

    pub fn path(&self, name: &str) -> PathBuf {
        self.dir.path().join(name)
    }

    pub fn settings(&self) -> AgentSettings {
        AgentSettings {
            cgroup_root: configbot_cgroups::SubtreeRoot::new(&self.root).unwrap(),
            state_file: self.path("state.json"),
            log_dir: self.path("logs"),
            stop_timeout: Duration::from_millis(1500),
            backoff_initial: Duration::from_millis(100),
            backoff_max: Duration::from_millis(1000),
            scan_interval: Duration::from_millis(200),
            recording_max_mb: RECORDING_MAX_MB,
            ..AgentSettings::default()
        }
    }

    pub fn ros_options(&self) -> DataPlaneOptions {
        DataPlaneOptions {
            backend: DEFAULT_BACKEND.into(),
            uri: self.master_uri.clone(),
            bind_host: "127.0.0.1".into(),
            adaptor_bind_host: configbot_ros1::DEFAULT_ADAPTOR_BIND.into(),
            db_path: self.path("ros1.db"),
            policy: PolicyConfig::default(),
            refresh_period: Some(Duration::from_secs(5)),
        }
    }

    /// A new env and its runtime with the ROS data plane, `monitor` and an
    /// empty stack; `None` (having said SKIPPED) when ROS is not installed.
    pub async fn start_with_ros(monitor: Option<Preference>) -> Option<(RtEnv, NodeRuntime)> {
        if !ros_available() {
            return None;
        }
        let mut env = RtEnv::new();
        let rt = env.start(true, monitor, StackSpec::default()).await;
        Some((env, rt))
    }

    pub async fn start(
        &mut self,
        ros: bool,
        monitor: Option<Preference>,
        stack: StackSpec,
    ) -> NodeRuntime {
        // `free_port` probed the master's port a moment ago; whatever else
        // runs on the machine may have bound it since. Such a start is
        // tried again on a new port (a few times), any other error fails.
        let mut tries = 0;
        let rt = loop {
            let opts = RuntimeOptions {
                settings: self.settings(),
                data_plane: ros.then(|| self.ros_options()),
                monitor: monitor.clone(),
            };
            match NodeRuntime::start(Box::new(v1_backend(&self.root)), opts, stack.clone()).await {
                Ok(rt) => break rt,
                Err(e) if ros && tries < 3 && addr_in_use(&e) => {
                    tries += 1;
                    eprintln!("{} was taken ({e}); trying a new port", self.master_uri);
                    self.master_uri = format!("http://localhost:{}/", free_port());
                }
                Err(e) => panic!("the runtime did not start: {e:?}"),
            }
        };
        self.rt = Some(rt.clone());
        rt
    }

    /// A ROS tool or script against this runtime's master.
    pub fn ros_command(&self, program: &str) -> Command {
        let mut c = Command::new(program);
        c.env("ROS_MASTER_URI", &self.master_uri)
            .env("ROS_HOSTNAME", "localhost")
            .env("ROS_HOME", self.path("ros"))
            .env("ROS_LOG_DIR", self.path("ros/log"))
            .env("PYTHONUNBUFFERED", "1");
        c
    }

    /// Starts a rospy script outside the agent (e.g. a node to adopt).
    pub fn script(&mut self, name: &str, args: &[&str]) -> usize {
        let mut c = self.ros_command("/usr/bin/python3");
        c.arg(script(name)).args(args);
        self.procs.push(Proc::spawn(c));
        self.procs.len() - 1
    }

    /// Env for `run` nodes that are rospy scripts (the master URI is injected
    /// by the runtime).
    pub fn ros_env_yaml(&self) -> String {
        format!(
            "{{ROS_HOSTNAME: localhost, ROS_HOME: {0}, ROS_LOG_DIR: {0}/log, PYTHONUNBUFFERED: '1'}}",
            self.path("ros").display()
        )
    }

    /// The `spec.apps` entry (for [`stack_yaml`]) of a core app whose nodes
    /// run rospy scripts from tests/scripts under Debian's python, each
    /// given as (ROS name, script, the script's arguments).
    pub fn rospy_core_app(&self, app: &str, nodes: &[(&str, &str, &[&str])]) -> String {
        let mut yaml = format!("    - name: {app}\n      core: true\n      nodes:\n");
        for (name, file, args) in nodes {
            let args: Vec<String> = std::iter::once(script(file))
                .chain(args.iter().map(|a| a.to_string()))
                .map(|a| format!("\"{a}\""))
                .collect();
            yaml += &format!(
                "        - name: {name}\n          run:\n            command: /usr/bin/python3\n            args: [{}]\n            env: {}\n",
                args.join(", "),
                self.ros_env_yaml()
            );
        }
        yaml
    }
}

impl Drop for RtEnv {
    fn drop(&mut self) {
        if let Some(rt) = self.rt.take() {
            rt.detach();
        }
        self.procs.clear();
        nuke(&self.root);
        if !std::thread::panicking() {
            assert!(
                v1_backend(&self.root).nodes().unwrap().is_empty(),
                "cgroups left behind under {}",
                self.root
            );
        }
    }
}

/// A RobotStack manifest named `bot` whose `spec.apps` are `apps`: YAML
/// list entries indented four spaces.
pub fn stack_yaml(apps: &str) -> String {
    format!(
        "apiVersion: configbot.dev/v1alpha1\nkind: RobotStack\nmetadata: {{name: bot}}\nspec:\n  apps:\n{apps}"
    )
}

/// The pid the runtime's ROS graph has for node `name`, if any.
pub fn graph_pid(rt: &NodeRuntime, name: &str) -> Option<u32> {
    rt.data_plane()?.graph().nodes.get(name)?.pid
}

/// Parses one RobotStack manifest.
pub fn robot_stack(yaml: &str) -> RobotStack {
    let docs = configbot_manifests::load("test.yaml", yaml).unwrap_or_else(|e| panic!("{e}"));
    match &docs[0].manifest {
        Manifest::RobotStack(s) => s.clone(),
        _ => panic!("not a RobotStack"),
    }
}
