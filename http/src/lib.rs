//! ConfigBot's HTTP plumbing, shared by the CLI, the controller's agent
//! client, the agent and the ROS 1 data plane:
//!
//! - [`client`]: the one client transport — one request over a fresh HTTP/1
//!   connection on a Unix socket or TCP, with a connect timeout, an optional
//!   timeout on the whole exchange and a limit on the response body.
//! - `limits` (feature `server`): what clients may send the agent's and the
//!   control plane's axum servers (body size and time, head and idle
//!   timeouts) and the connection loop that enforces them.

pub mod client;
#[cfg(feature = "server")]
pub mod limits;
