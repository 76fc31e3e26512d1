//! Events the agent streams to the controller (NDJSON on `/v1/events`).

use configbot_api::graph::GraphEvent;
use configbot_cgroups::NodeName;
use serde::{Deserialize, Serialize};

use crate::policy::ExitKind;

/// One agent event.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
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
    AppFrozen { app: String },
    #[serde(rename_all = "camelCase")]
    AppThawed { app: String },
    /// A rosbag recording started (runtime, see `runtime::record`).
    #[serde(rename_all = "camelCase")]
    RecordingStarted {
        name: String,
        path: std::path::PathBuf,
        topics: Vec<String>,
    },
    #[serde(rename_all = "camelCase")]
    RecordingStopped {
        name: String,
        path: std::path::PathBuf,
    },
    #[serde(rename_all = "camelCase")]
    ConfigApplied { nodes: Vec<NodeName> },
    #[serde(rename_all = "camelCase")]
    ConfigRejected { error: String },
    #[serde(rename_all = "camelCase")]
    LimitsLifted {
        nodes: Vec<NodeName>,
        reason: String,
    },
    /// A process exec seen by the process monitor (procmon crate).
    #[serde(rename_all = "camelCase")]
    ProcessExec { pid: u32, comm: Option<String> },
    #[serde(rename_all = "camelCase")]
    StateWriteFailed { error: String },
}

/// One event of the node runtime (`GET /v1/events`, one JSON object per
/// line): process-monitor events with their kernel time stamps, graph
/// changes, and every [`AgentEvent`] (serialized flat, with its own `type`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "camelCase")]
pub enum RuntimeEvent {
    /// A process called `execve`. `at_unix_ms`: when the kernel saw it
    /// (the /proc scan: when the scan noticed it); `seen_unix_ms`: when the
    /// runtime received it. Their difference is the detection latency.
    #[serde(rename_all = "camelCase")]
    ProcessExec {
        pid: u32,
        ppid: Option<u32>,
        comm: Option<String>,
        filename: Option<String>,
        at_unix_ms: u64,
        seen_unix_ms: u64,
    },
    /// A process (its whole thread group) exited.
    #[serde(rename_all = "camelCase")]
    ProcessExit { pid: u32, exit_code: Option<i32> },
    /// The ROS graph changed (nodes, pids, edges).
    #[serde(rename_all = "camelCase")]
    GraphChanged { events: Vec<GraphEvent> },
    /// A slow reader of the stream missed this many events.
    #[serde(rename_all = "camelCase")]
    Lagged { missed: u64 },
    /// An event of the agent core (node started, exited, adopted, ...).
    #[serde(untagged)]
    Agent(AgentEvent),
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

/// The part of a process-monitor event the agent uses; `runtime.rs` maps
/// `configbot_procmon::ProcEvent` onto it field by field.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ProcEvent {
    pub kind: ProcEventKind,
    pub pid: u32,
    pub ppid: Option<u32>,
    pub comm: Option<String>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn runtime_events_round_trip_flat() {
        let evs = vec![
            RuntimeEvent::ProcessExec {
                pid: 7,
                ppid: Some(1),
                comm: Some("true".into()),
                filename: None,
                at_unix_ms: 5,
                seen_unix_ms: 6,
            },
            RuntimeEvent::ProcessExit {
                pid: 7,
                exit_code: Some(0),
            },
            RuntimeEvent::GraphChanged {
                events: vec![GraphEvent::NodeRemoved("/x".into())],
            },
            RuntimeEvent::Agent(AgentEvent::AppStopped { app: "det".into() }),
            RuntimeEvent::Agent(AgentEvent::NodeExited {
                node: NodeName::new("/n").unwrap(),
                pid: 3,
                exit: ExitKind::Signaled(9),
            }),
        ];
        for ev in evs {
            let line = serde_json::to_string(&ev).unwrap();
            assert!(line.starts_with(r#"{"type":""#), "{line}");
            let back: RuntimeEvent = serde_json::from_str(&line).unwrap();
            assert_eq!(back, ev, "{line}");
        }
        let agent = serde_json::to_string(&AgentEvent::AppStopped { app: "a".into() }).unwrap();
        assert_eq!(agent, r#"{"type":"appStopped","app":"a"}"#);
    }
}
