//! ConfigBot node agent: runs and adopts ROS node processes inside per-node
//! cgroups, applies CPU configs from the controller atomically, survives its
//! own restarts, and serves an HTTP API with Prometheus metrics.
//! [`runtime::NodeRuntime`] joins the agent, the process monitor and a data
//! plane into the one object the controller drives, in process or through
//! the API; [`contract`] states each API operation once, for the router and
//! for [`client`], the remote agent's client.
//!
//! Pure decisions live in [`policy`] (restart), [`state`] (startup
//! safety) and [`procfs`] parsers; `supervise` is the restart loop over a
//! narrow interface (tested without processes); IO is in [`spawn`],
//! [`agent`] (with `agent::process`, the processes the loop drives) and
//! [`api`]. Cgroup access goes through
//! [`configbot_cgroups::CgroupBackend`].

pub mod agent;
pub mod api;
#[cfg(feature = "cli")]
pub mod cli;
pub mod client;
pub mod contract;
pub mod error;
pub mod events;
pub mod limits;
pub mod manifest;
pub mod metrics;
pub mod policy;
pub mod procfs;
pub mod runtime;
pub mod spawn;
pub mod spec;
pub mod state;
mod supervise;

pub use agent::process::send_signal;
pub use agent::stack::{StackDiff, diff_stacks};
pub use agent::{Agent, ConfigUpdate, NodeStatus};
pub use contract::NodeApi;
pub use error::{Error, Result};
pub use events::{AgentEvent, ProcEvent, ProcEventKind, RuntimeEvent};
pub use runtime::{DataPlaneOptions, NodeRuntime, RuntimeOptions};
pub use spec::{
    AgentSettings, AppSpec, MatchSpec, NodeSource, NodeSpec, RestartPolicy, RunSpec, StackSpec,
};
