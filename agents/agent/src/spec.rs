//! The agent's plain view of a robot stack: apps → nodes → `run` or `match`,
//! plus the agent's own settings. `manifest.rs` maps the RobotStack manifest onto these.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Duration;

use configbot_cgroups::{CpuWeight, NodeName, SubtreeRoot};
use serde::{Deserialize, Serialize};

/// All apps the agent supervises on this robot.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct StackSpec {
    pub apps: Vec<AppSpec>,
}

/// A group of nodes started and stopped together.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct AppSpec {
    pub name: String,
    pub nodes: Vec<NodeSpec>,
    /// Inputs of other apps' nodes this (non-core) app claims: adaptors are
    /// placed on them as on its own inputs (the manifest's `apps[].inputs`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub inputs: Vec<configbot_api::graph::EdgeId>,
}

/// One ROS node: how the agent gets its process.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct NodeSpec {
    pub name: NodeName,
    /// Core nodes never stay throttled by a stale config (see `safety`).
    #[serde(default)]
    pub core: bool,
    #[serde(flatten)]
    pub source: NodeSource,
}

/// `run`: the agent starts the process. `match`: it adopts one that exists.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub enum NodeSource {
    Run(RunSpec),
    Match(MatchSpec),
}

/// How to start a node's process.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct RunSpec {
    pub command: String,
    #[serde(default)]
    pub args: Vec<String>,
    #[serde(default)]
    pub env: BTreeMap<String, String>,
    #[serde(default)]
    pub working_dir: Option<PathBuf>,
    /// A user name from /etc/passwd; `None` keeps the agent's user.
    #[serde(default)]
    pub user: Option<String>,
    #[serde(default)]
    pub restart_policy: RestartPolicy,
}

/// When a `run` node is restarted after it exits.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum RestartPolicy {
    #[default]
    Always,
    OnFailure,
    Never,
}

/// How to find an existing process; all given criteria must match.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct MatchSpec {
    /// Exact `comm` (as in /proc/PID/comm, max 15 bytes).
    #[serde(default)]
    pub process_name: Option<String>,
    /// Regex over the NUL-joined-by-space command line.
    #[serde(default)]
    pub cmdline_regex: Option<String>,
    /// The ROS node name registered with the master: the process is found by
    /// its slave API's `getPid` (needs the ROS data plane, see `runtime`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ros_node: Option<String>,
}

/// The agent's own settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct AgentSettings {
    /// The agent's subtree in the cpu hierarchies.
    pub cgroup_root: SubtreeRoot,
    /// State file (JSON, written atomically).
    pub state_file: PathBuf,
    /// Node log files live here.
    pub log_dir: PathBuf,
    /// A node's log file is rotated beyond this size.
    pub log_max_bytes: u64,
    /// Rotated log files kept per node.
    pub log_keep: u32,
    /// SIGINT → SIGTERM wait, then SIGTERM → SIGKILL wait.
    #[serde(with = "millis")]
    pub stop_timeout: Duration,
    /// First restart delay; doubles per consecutive failure up to `backoff_max`.
    #[serde(with = "millis")]
    pub backoff_initial: Duration,
    #[serde(with = "millis")]
    pub backoff_max: Duration,
    /// How often `match` nodes are looked for and stats sampled.
    #[serde(with = "millis")]
    pub scan_interval: Duration,
    /// Lift every limit when the agent shuts down cleanly.
    pub lift_limits_on_shutdown: bool,
    /// CPU weight of the agent's subtree against the host's other cgroups
    /// (v2 units, 100 = a plain service); `None` leaves the kernel's value.
    #[serde(default)]
    pub subtree_cpu_weight: Option<CpuWeight>,
    /// Largest bag a recording writes, in MB (`rosbag record --size`): rosbag
    /// stops there, keeping the first minutes after an app was paused. 0: no
    /// cap.
    #[serde(default = "default_recording_max_mb")]
    pub recording_max_mb: u64,
}

fn default_recording_max_mb() -> u64 {
    1024
}

impl Default for AgentSettings {
    fn default() -> Self {
        Self {
            cgroup_root: SubtreeRoot::default(),
            state_file: PathBuf::from("/var/lib/configbot/agent-state.json"),
            log_dir: PathBuf::from("/var/log/configbot"),
            log_max_bytes: 10 * 1024 * 1024,
            log_keep: 3,
            stop_timeout: Duration::from_secs(5),
            backoff_initial: Duration::from_millis(800),
            backoff_max: Duration::from_secs(30),
            scan_interval: Duration::from_millis(500),
            lift_limits_on_shutdown: false,
            subtree_cpu_weight: None,
            recording_max_mb: default_recording_max_mb(),
        }
    }
}

mod millis {
    use std::time::Duration;

    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(d: &Duration, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_u64(u64::try_from(d.as_millis()).unwrap_or(u64::MAX))
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Duration, D::Error> {
        Ok(Duration::from_millis(u64::deserialize(d)?))
    }
}

impl StackSpec {
    /// Every node with its app's name.
    pub fn nodes(&self) -> impl Iterator<Item = (&str, &NodeSpec)> {
        self.apps
            .iter()
            .flat_map(|a| a.nodes.iter().map(move |n| (a.name.as_str(), n)))
    }

    /// Node names must be unique across the stack and regexes must compile.
    pub fn validate(&self) -> Result<(), String> {
        let mut seen = std::collections::BTreeSet::new();
        for (_, n) in self.nodes() {
            if !seen.insert(&n.name) {
                return Err(format!("node {} appears twice", n.name));
            }
            if let NodeSource::Match(m) = &n.source {
                if m.process_name.is_none() && m.cmdline_regex.is_none() && m.ros_node.is_none() {
                    return Err(format!(
                        "node {}: match needs processName, cmdlineRegex or rosNode",
                        n.name
                    ));
                }
                if let Some(r) = &m.cmdline_regex {
                    regex::Regex::new(r).map_err(|e| format!("node {}: bad regex: {e}", n.name))?;
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stack_parses_from_json_and_validates() {
        let s: StackSpec = serde_json::from_str(
            r#"{"apps":[{"name":"nav","nodes":[
                {"name":"/nav/planner","core":true,"run":{"command":"/bin/sleep","args":["9"],"restartPolicy":"OnFailure"}},
                {"name":"/cam","match":{"cmdlineRegex":"camera_node"}}]}]}"#,
        )
        .unwrap();
        assert!(s.validate().is_ok());
        let (app, n) = s.nodes().next().unwrap();
        assert_eq!(app, "nav");
        let NodeSource::Run(r) = &n.source else {
            panic!()
        };
        assert_eq!(r.restart_policy, RestartPolicy::OnFailure);

        let bad: StackSpec =
            serde_json::from_str(r#"{"apps":[{"name":"a","nodes":[{"name":"/x","match":{}}]}]}"#)
                .unwrap();
        assert!(bad.validate().is_err());
        assert!(serde_json::from_str::<StackSpec>(
            r#"{"apps":[{"name":"a","nodes":[{"name":"/../etc","match":{"processName":"x"}}]}]}"#
        )
        .is_err());
    }
}
