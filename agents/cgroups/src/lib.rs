//! Per-ROS-node CPU cgroups for the ConfigBot node agent.
//!
//! The agent owns one subtree (default `configbot`) in the CPU hierarchies and
//! creates one cgroup per ROS node below it. Everything that touches the
//! filesystem sits behind [`CgroupBackend`], with a v1 ([`V1Backend`]) and a
//! v2 ([`V2Backend`]) implementation; both take their mount points as plain
//! paths, so tests can aim them at a temporary directory. Decisions (name
//! mapping, limit validation, file formats, hierarchy detection) are pure
//! functions in their own modules. [`apply()`] writes a whole configuration
//! atomically: validate all, write all, read back, roll back on failure.
//!
//! **Invariant:** on v1 only the `cpu`, `cpuacct` (and, once a cpuset knob
//! exists, `cpuset`) hierarchies are touched; never `memory` or others.

mod apply;
mod backend;
mod error;
mod fsio;
mod layout;
mod limit;
mod name;
mod stats;
mod threads;
mod v1;
mod v2;

pub use apply::{AppliedNode, CgroupConfig, apply};
pub use backend::{BackendKind, CgroupBackend, open_backend};
pub use error::{Error, Result};
pub use layout::{HierarchyKind, Layout};
pub use limit::{
    CpuLimit, CpuMax, CpuWeight, DEFAULT_PERIOD_US, MAX_PERIOD_US, MIN_PERIOD_US, MIN_QUOTA_US,
};
pub use name::{NodeName, SubtreeRoot};
pub use stats::{CpuStats, Pressure};
pub use threads::{AgentThreads, ThreadPlacement};
pub use v1::V1Backend;
pub use v2::V2Backend;
