//! The agent's error type.

use std::path::PathBuf;

/// Result alias for the agent.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Errors of the node agent.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Cgroup(#[from] configbot_cgroups::Error),
    #[error("io error on {path}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot start {command:?}")]
    Spawn {
        command: String,
        #[source]
        source: std::io::Error,
    },
    #[error("unknown user {0:?}")]
    UnknownUser(String),
    #[error("unknown node {0}")]
    UnknownNode(String),
    #[error("unknown app {0}")]
    UnknownApp(String),
    #[error("invalid stack: {0}")]
    InvalidStack(String),
    #[error("cannot create metrics")]
    Metrics(#[source] prometheus::Error),
    #[error("invalid config: {0}")]
    InvalidConfig(String),
    #[error("invalid measure request: {0}")]
    InvalidMeasure(String),
    #[error("invalid recording: {0}")]
    InvalidRecording(String),
    #[error("{what} needs the ROS data plane, which is disabled")]
    NoDataPlane { what: String },
    #[error("adaptor on edge {topic} -> {subscriber}")]
    Adaptor {
        topic: String,
        subscriber: String,
        #[source]
        source: configbot_dataplane::DataPlaneError,
    },
    #[error("starting the {backend} data plane at {uri}")]
    DataPlane {
        backend: &'static str,
        uri: String,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    #[error("no data-plane backend {name:?} (known: {known})")]
    UnknownDataPlane { name: String, known: String },
    #[error("starting the process monitor")]
    Monitor(#[source] configbot_procmon::MonitorError),
    #[error("stack manifest {source_name} is invalid: {message}")]
    Manifest {
        source_name: String,
        message: String,
    },
    #[error("state file {path} is corrupt")]
    State {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
}
