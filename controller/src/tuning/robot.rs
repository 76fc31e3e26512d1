//! The tuning loop's only view of a robot: the node runtime's operations
//! (the agent's [`NodeApi`]: apply a config, measure a window, read the ROS
//! graph, stop/start/freeze an app, record a rosbag, run a stack) with
//! [`RobotError`] as their error, a stream of runtime events, and the clock
//! the loop waits on, injected so tests run on simulated time.
//!
//! The traits are dyn-compatible (boxed futures), so the server holds an
//! `Arc<dyn Robot>`; `crate::robot` implements it for the embedded
//! `NodeRuntime` and the remote `AgentClient`, [`super::sim`] for the
//! simulated robot the tests drive.

use std::time::Duration;

pub use configbot_agent::NodeApi;
pub use configbot_agent::contract::BoxFuture;
use configbot_tuning::monitor::RobotEvent;
use tokio::sync::broadcast;

/// A robot operation failed.
#[derive(Debug, thiserror::Error)]
#[error("robot {op}: {message}")]
pub struct RobotError {
    /// The operation: `apply`, `measure`, `graph`, `stop_app`, `start_app`,
    /// `freeze_app`, `start_recording`, ….
    pub op: &'static str,
    pub message: String,
    #[source]
    pub source: Option<Box<dyn std::error::Error + Send + Sync>>,
}

impl RobotError {
    pub fn new(op: &'static str, message: impl Into<String>) -> RobotError {
        RobotError {
            op,
            message: message.into(),
            source: None,
        }
    }

    /// Wrap any error of the implementation.
    pub fn wrap(op: &'static str, e: impl std::error::Error + Send + Sync + 'static) -> RobotError {
        RobotError {
            op,
            message: e.to_string(),
            source: Some(Box::new(e)),
        }
    }
}

/// A robot as the tuning loop drives it: the node runtime's operations,
/// failing with [`RobotError`], and its events. Every method may be called
/// concurrently from one runner task only; implementations must be cheap to share.
pub trait Robot: NodeApi<Error = RobotError> {
    /// Runtime events from now on.
    fn events(&self) -> broadcast::Receiver<RobotEvent>;
}

/// The time the tuning loop waits on (settling, monitor periods). Real robots
/// use [`SystemClock`]; the simulated robot advances its own time instead.
pub trait Clock: Send + Sync {
    /// Milliseconds since the Unix epoch.
    fn now_ms(&self) -> u64;
    fn sleep(&self, d: Duration) -> BoxFuture<'_, ()>;
}

/// Wall-clock time and tokio timers.
#[derive(Debug, Clone, Copy, Default)]
pub struct SystemClock;

impl Clock for SystemClock {
    fn now_ms(&self) -> u64 {
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_millis() as u64)
    }

    fn sleep(&self, d: Duration) -> BoxFuture<'_, ()> {
        Box::pin(tokio::time::sleep(d))
    }
}
