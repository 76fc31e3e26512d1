//! ConfigBot's wire types: the plain data the controller and the node agents
//! exchange, with no IO and no async runtime, so the pure tuning core
//! (`configbot-tuning`) can depend on them without pulling in the agent.
//!
//! - [`measure`]: what the controller asks a node to measure and what it
//!   gets back (`POST /v1/measure`).
//! - [`graph`]: the ROS graph, graph events, topic statistics and adapted
//!   edges (`GET /v1/graph`, the vocabulary of `configbot_dataplane::DataPlane`).
//! - [`policy`]: the adaptor placement rule the agent and the controller's
//!   knob space both apply.
//! - [`backoff`]: the one retry backoff (exponential, capped, optionally
//!   jittered) of the reconciler, the tuning runner, the agent's restarts and
//!   the ROS 1 data plane's retries.

pub mod backoff;
pub mod graph;
pub mod measure;
pub mod policy;
