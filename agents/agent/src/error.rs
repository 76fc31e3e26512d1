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
    #[error("state file {path} is corrupt")]
    State {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
}
