//! The `RobotStack` kind: what a robot runs — apps, their ROS nodes, core or
//! non-core, and how each node is started (`run`) or found (`match`).

use std::collections::BTreeMap;

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::meta::{Condition, ObjectMeta};
use crate::vocab::StackPhase;

/// A robot and the apps it runs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct RobotStack {
    /// Always `configbot.dev/v1alpha1`.
    pub api_version: String,
    /// Always `RobotStack`.
    pub kind: String,
    pub metadata: ObjectMeta,
    pub spec: RobotStackSpec,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub status: Option<RobotStackStatus>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct RobotStackSpec {
    /// Facts about the robot the stack runs on.
    #[serde(default)]
    pub robot: Robot,
    /// The apps of the stack; at least one.
    pub apps: Vec<App>,
}

/// Facts about the robot hardware.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct Robot {
    /// Robot model, e.g. `spot`; configs are shared between robots of one model.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model: Option<String>,
    /// CPUs available to the stack (may be fractional); defaults to the machine's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cpus: Option<f64>,
    /// Labels describing the robot (site, hardware revision, ...).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub labels: BTreeMap<String, String>,
}

/// An app: a set of ROS nodes that is core (its metrics are constraints) or
/// non-core (its metrics are objectives, and it may be throttled or stopped).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct App {
    /// App name: a DNS label (`navigation`, `obj-detector`).
    pub name: String,
    /// Core services must always meet their targets; non-core apps run when resources permit.
    #[serde(default)]
    pub core: bool,
    /// The app's ROS nodes; at least one.
    pub nodes: Vec<Node>,
    /// Subscriptions of another app's node that only this app's work
    /// consumes: the input of this app's nodelets in a nodelet manager it
    /// shares with a core app, or of its callbacks in a shared executor. A
    /// CPU limit on that process would slow the core app too; an adaptor on
    /// such an input throttles only this app. Non-core apps only.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub inputs: Vec<AppInput>,
}

/// One subscription edge, `topic` into `node`, claimed by an app (see [`App::inputs`]).
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct AppInput {
    /// The subscribing ROS node (declared in another app of this stack).
    pub node: String,
    /// The topic it subscribes to, on this app's behalf.
    pub topic: String,
}

/// One ROS node (one Linux process): either started by the agent (`run`) or
/// adopted when found (`match`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct Node {
    /// Absolute ROS node name, e.g. `/navigation` or `/nav/planner`.
    pub name: String,
    /// Start the node as this command (exactly one of `run` and `match`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub run: Option<RunSpec>,
    /// Adopt an already running process (exactly one of `run` and `match`).
    #[serde(rename = "match", default, skip_serializing_if = "Option::is_none")]
    pub match_: Option<MatchSpec>,
}

/// How the agent starts a node.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct RunSpec {
    /// Executable (absolute path or looked up on PATH).
    pub command: String,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub args: Vec<String>,
    /// Extra environment variables.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub env: BTreeMap<String, String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub working_dir: Option<String>,
    /// User name or numeric uid to run as; the agent's user when omitted.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub user: Option<String>,
    #[serde(default)]
    pub restart_policy: RestartPolicy,
}

/// When the agent restarts a node that exited.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
pub enum RestartPolicy {
    /// Always restart, with exponential backoff.
    #[default]
    Always,
    /// Restart only after a non-zero exit or a signal.
    OnFailure,
    /// Never restart.
    Never,
}

/// How the agent finds a node it did not start. Exactly one field is set.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct MatchSpec {
    /// The ROS node name as registered with the master (pid from the slave API).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ros_node: Option<String>,
    /// The process name (`comm`, at most 15 characters as the kernel keeps it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub process_name: Option<String>,
    /// A regular expression matched against the full command line (arguments joined by spaces).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cmdline: Option<String>,
}

/// What the control plane reports about a stack.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct RobotStackStatus {
    /// `Pending` until reconciled, then `Accepted` or `Invalid`.
    #[serde(default)]
    pub phase: StackPhase,
    #[serde(default)]
    pub observed_generation: i64,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub conditions: Vec<Condition>,
    /// Number of apps and nodes declared.
    #[serde(default)]
    pub apps: u32,
    #[serde(default)]
    pub nodes: u32,
}

impl RobotStackSpec {
    /// Every node with the app it belongs to.
    pub fn nodes(&self) -> impl Iterator<Item = (&App, &Node)> {
        self.apps
            .iter()
            .flat_map(|app| app.nodes.iter().map(move |n| (app, n)))
    }

    /// The app called `name`.
    pub fn app(&self, name: &str) -> Option<&App> {
        self.apps.iter().find(|a| a.name == name)
    }
}
