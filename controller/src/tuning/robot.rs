//! The tuning loop's only view of a robot: the operations of the node
//! runtime — apply a config, measure a window, read the ROS graph,
//! stop/start/freeze an app, record a rosbag, and a stream of runtime events
//! — plus the clock the loop waits on, injected so tests run on simulated
//! time.
//!
//! The trait is dyn-compatible (boxed futures), so the server holds an
//! `Arc<dyn Robot>`; `crate::robot` implements it for the embedded
//! `NodeRuntime` and the remote `AgentClient`, [`super::sim`] for the
//! simulated robot the tests drive.

use std::future::Future;
use std::pin::Pin;
use std::time::Duration;

use configbot_api::graph::Graph;
use configbot_api::measure::{MeasureReport, MeasureRequest};
use configbot_manifests::ResourceConfig;
use configbot_tuning::monitor::RobotEvent;
use tokio::sync::broadcast;

/// A boxed, sendable future (keeps [`Robot`] dyn-compatible).
pub type BoxFuture<'a, T> = Pin<Box<dyn Future<Output = T> + Send + 'a>>;

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

/// A robot as the tuning loop drives it. Every method may be called
/// concurrently from one runner task only; implementations must be cheap to share.
pub trait Robot: Send + Sync {
    /// Apply CPU limits (atomically) then adaptor rates; nodes and edges not
    /// listed become unlimited.
    fn apply<'a>(&'a self, cfg: &'a ResourceConfig) -> BoxFuture<'a, Result<(), RobotError>>;
    /// Measure `req.probes` over `req.duration_ms` (blocks for the window).
    fn measure<'a>(
        &'a self,
        req: &'a MeasureRequest,
    ) -> BoxFuture<'a, Result<MeasureReport, RobotError>>;
    /// The current ROS graph.
    fn graph(&self) -> BoxFuture<'_, Result<Graph, RobotError>>;
    /// Stop every node of `app` (remediation).
    fn stop_app<'a>(&'a self, app: &'a str) -> BoxFuture<'a, Result<(), RobotError>>;
    /// Start every node of `app` again.
    fn start_app<'a>(&'a self, app: &'a str) -> BoxFuture<'a, Result<(), RobotError>>;
    /// Freeze (SIGSTOP) every node of `app`.
    fn freeze_app<'a>(&'a self, app: &'a str) -> BoxFuture<'a, Result<(), RobotError>>;
    /// Thaw (SIGCONT) every node of `app`.
    fn thaw_app<'a>(&'a self, app: &'a str) -> BoxFuture<'a, Result<(), RobotError>>;
    /// Start a rosbag recording of `topics` named `name`: the bag's path,
    /// `None` when the robot cannot record (no rosbag) or `topics` is empty.
    fn start_recording<'a>(
        &'a self,
        name: &'a str,
        topics: &'a [String],
    ) -> BoxFuture<'a, Result<Option<String>, RobotError>>;
    /// Stop the recording `name`: the finished bag's path, if one was running.
    fn stop_recording<'a>(
        &'a self,
        name: &'a str,
    ) -> BoxFuture<'a, Result<Option<String>, RobotError>>;
    /// Runtime events from now on.
    fn events(&self) -> broadcast::Receiver<RobotEvent>;
    /// Run `stack` (`None`: no stack, stop every node). Robots whose stack
    /// is fixed (simulations) keep the default, which does nothing.
    fn set_stack<'a>(
        &'a self,
        stack: Option<&'a configbot_manifests::RobotStack>,
    ) -> BoxFuture<'a, Result<(), RobotError>> {
        let _ = stack;
        Box::pin(async { Ok(()) })
    }
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
