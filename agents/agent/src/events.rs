//! Events the agent streams to the controller (NDJSON on `/v1/events`).

use configbot_cgroups::NodeName;
use serde::Serialize;

use crate::policy::ExitKind;

/// One agent event.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "type", rename_all = "camelCase")]
pub enum AgentEvent {
    #[serde(rename_all = "camelCase")]
    NodeStarted { node: NodeName, pid: u32 },
    #[serde(rename_all = "camelCase")]
    NodeReattached { node: NodeName, pid: u32 },
    #[serde(rename_all = "camelCase")]
    NodeExited {
        node: NodeName,
        pid: u32,
        exit: ExitKind,
    },
    #[serde(rename_all = "camelCase")]
    NodeRestarting {
        node: NodeName,
        attempt: u32,
        delay_ms: u64,
    },
    #[serde(rename_all = "camelCase")]
    NodeSpawnFailed { node: NodeName, error: String },
    #[serde(rename_all = "camelCase")]
    NodeAdopted { node: NodeName, pids: Vec<u32> },
    #[serde(rename_all = "camelCase")]
    NodeStopped { node: NodeName },
    #[serde(rename_all = "camelCase")]
    AppStopped { app: String },
    #[serde(rename_all = "camelCase")]
    AppStarted { app: String },
    #[serde(rename_all = "camelCase")]
    ConfigApplied { nodes: Vec<NodeName> },
    #[serde(rename_all = "camelCase")]
    ConfigRejected { error: String },
    #[serde(rename_all = "camelCase")]
    LimitsLifted {
        nodes: Vec<NodeName>,
        reason: &'static str,
    },
    /// A process exec seen by the process monitor (procmon crate).
    #[serde(rename_all = "camelCase")]
    ProcessExec { pid: u32, comm: Option<String> },
    #[serde(rename_all = "camelCase")]
    StateWriteFailed { error: String },
}

/// Exec or exit, as in `configbot_procmon::ProcEventKind`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProcEventKind {
    Exec,
    Exit,
}

impl ProcEventKind {
    /// Label value of the `monitor_events` metric.
    pub fn label(self) -> &'static str {
        match self {
            Self::Exec => "exec",
            Self::Exit => "exit",
        }
    }
}

/// The part of a process-monitor event the agent uses; the lead maps
/// `configbot_procmon::ProcEvent` onto it field by field.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ProcEvent {
    pub kind: ProcEventKind,
    pub pid: u32,
    pub ppid: Option<u32>,
    pub comm: Option<String>,
}
