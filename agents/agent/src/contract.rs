//! The agent's API contract, each operation stated once.
//!
//! - [`Route`]: one zero-sized type per HTTP operation, holding its method,
//!   path template, path parameter, request body and answer. The agent's
//!   router ([`crate::api`]) registers each route from it, and
//!   [`crate::client::AgentClient::call`] sends it, so a route and its client
//!   path cannot drift apart.
//! - [`NodeApi`]: the operations the controller drives, implemented by the
//!   in-process [`crate::NodeRuntime`] and the remote
//!   [`crate::client::AgentClient`] (and the controller's simulated robot).
//!
//! The table lives in the agent crate, not in `configbot-api`: several of its
//! types (`NodeStatus`, `StackSpec`, `RuntimeEvent`) carry cgroups types and
//! the agent's own vocabulary. It names no transport: [`Verb`] is mapped
//! onto axum's method filter by the router and onto an HTTP method by the
//! client.

use std::future::Future;
use std::path::PathBuf;
use std::pin::Pin;

use configbot_api::graph::Graph;
use configbot_api::measure::{MeasureReport, MeasureRequest};
use configbot_manifests::{ResourceConfig, RobotStack};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use crate::agent::NodeStatus;
use crate::agent::stack::StackDiff;
use crate::events::RuntimeEvent;
use crate::spec::StackSpec;

/// The HTTP methods the API uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verb {
    Get,
    Put,
    Post,
    Delete,
}

/// One operation of the agent's HTTP API.
pub trait Route {
    const METHOD: Verb;
    /// The path, in the router's template syntax: a `{name}` segment is
    /// filled from [`Route::Param`].
    const PATH: &'static str;
    /// The path parameter: `()` or a name (an app, a recording).
    type Param: PathParam;
    /// The request body: JSON, or [`NoBody`].
    type Request: RequestBody;
    /// The answer's JSON (for [`Events`], one line of the stream).
    type Response: Serialize + DeserializeOwned;
}

/// Fills a route's path template with its parameter.
pub trait PathParam {
    fn fill(&self, template: &str) -> String;
}

impl PathParam for () {
    fn fill(&self, template: &str) -> String {
        template.to_owned()
    }
}

/// A name in a path: it replaces the template's one `{…}` segment,
/// percent-encoded.
impl PathParam for String {
    fn fill(&self, template: &str) -> String {
        match (template.find('{'), template.find('}')) {
            (Some(a), Some(b)) if a < b => {
                format!(
                    "{}{}{}",
                    &template[..a],
                    path_segment(self),
                    &template[b + 1..]
                )
            }
            _ => template.to_owned(),
        }
    }
}

/// App names are DNS labels; anything else is percent-encoded.
fn path_segment(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for b in s.bytes() {
        if b.is_ascii_alphanumeric() || b == b'-' || b == b'_' || b == b'.' {
            out.push(char::from(b));
        } else {
            out.push_str(&format!("%{b:02X}"));
        }
    }
    out
}

/// A request body as the client sends it.
pub trait RequestBody {
    /// The JSON bytes; `None`: the request has no body.
    fn encode(&self) -> Option<serde_json::Result<Vec<u8>>>;
}

impl<T: Serialize> RequestBody for T {
    fn encode(&self) -> Option<serde_json::Result<Vec<u8>>> {
        Some(serde_json::to_vec(self))
    }
}

/// The request of a route without a body.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoBody;

impl RequestBody for NoBody {
    fn encode(&self) -> Option<serde_json::Result<Vec<u8>>> {
        None
    }
}

/// Body of [`PutStack`]: a `RobotStack` manifest (the agent validates it) or
/// a plain [`StackSpec`].
#[derive(Debug, Clone, Serialize)]
#[serde(untagged)]
pub enum StackBody {
    Manifest(Box<RobotStack>),
    Spec(StackSpec),
}

/// Body of [`StartRecording`].
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecordingRequest {
    pub topics: Vec<String>,
}

/// Answer of the recording routes: the bag's path (`None`: no bag).
#[derive(Debug, Serialize, Deserialize)]
pub struct RecordingReply {
    pub path: Option<PathBuf>,
}

/// Answer of the app routes.
#[derive(Debug, Serialize, Deserialize)]
pub struct AppReply {
    pub app: String,
    /// The action done: `stop`, `start`, `freeze` or `thaw`.
    pub done: String,
}

/// `GET /v1/nodes`: the node inventory.
#[derive(Debug)]
pub struct Nodes;
impl Route for Nodes {
    const METHOD: Verb = Verb::Get;
    const PATH: &'static str = "/v1/nodes";
    type Param = ();
    type Request = NoBody;
    type Response = Vec<NodeStatus>;
}

/// `PUT /v1/stack`: replaces the stack at run time.
#[derive(Debug)]
pub struct PutStack;
impl Route for PutStack {
    const METHOD: Verb = Verb::Put;
    const PATH: &'static str = "/v1/stack";
    type Param = ();
    type Request = StackBody;
    type Response = StackDiff;
}

/// `PUT /v1/config`: CPU limits per node, adaptor rates per edge; answers
/// `{"applied": true, "committed": …}`.
#[derive(Debug)]
pub struct PutConfig;
impl Route for PutConfig {
    const METHOD: Verb = Verb::Put;
    const PATH: &'static str = "/v1/config";
    type Param = ();
    type Request = ResourceConfig;
    type Response = serde_json::Value;
}

/// `POST /v1/measure`: blocks for the window.
#[derive(Debug)]
pub struct Measure;
impl Route for Measure {
    const METHOD: Verb = Verb::Post;
    const PATH: &'static str = "/v1/measure";
    type Param = ();
    type Request = MeasureRequest;
    type Response = MeasureReport;
}

/// `GET /v1/graph`: the ROS graph.
#[derive(Debug)]
pub struct GetGraph;
impl Route for GetGraph {
    const METHOD: Verb = Verb::Get;
    const PATH: &'static str = "/v1/graph";
    type Param = ();
    type Request = NoBody;
    type Response = Graph;
}

/// `POST /v1/apps/{app}/stop`: graceful stop of an app.
#[derive(Debug)]
pub struct StopApp;
impl Route for StopApp {
    const METHOD: Verb = Verb::Post;
    const PATH: &'static str = "/v1/apps/{app}/stop";
    type Param = String;
    type Request = NoBody;
    type Response = AppReply;
}

/// `POST /v1/apps/{app}/start`: starts an app again.
#[derive(Debug)]
pub struct StartApp;
impl Route for StartApp {
    const METHOD: Verb = Verb::Post;
    const PATH: &'static str = "/v1/apps/{app}/start";
    type Param = String;
    type Request = NoBody;
    type Response = AppReply;
}

/// `POST /v1/apps/{app}/freeze`: SIGSTOP an app's processes.
#[derive(Debug)]
pub struct FreezeApp;
impl Route for FreezeApp {
    const METHOD: Verb = Verb::Post;
    const PATH: &'static str = "/v1/apps/{app}/freeze";
    type Param = String;
    type Request = NoBody;
    type Response = AppReply;
}

/// `POST /v1/apps/{app}/thaw`: SIGCONT an app's processes.
#[derive(Debug)]
pub struct ThawApp;
impl Route for ThawApp {
    const METHOD: Verb = Verb::Post;
    const PATH: &'static str = "/v1/apps/{app}/thaw";
    type Param = String;
    type Request = NoBody;
    type Response = AppReply;
}

/// `PUT /v1/recordings/{name}`: starts a rosbag recording.
#[derive(Debug)]
pub struct StartRecording;
impl Route for StartRecording {
    const METHOD: Verb = Verb::Put;
    const PATH: &'static str = "/v1/recordings/{name}";
    type Param = String;
    type Request = RecordingRequest;
    type Response = RecordingReply;
}

/// `DELETE /v1/recordings/{name}`: stops it (path `null`: none was running).
#[derive(Debug)]
pub struct StopRecording;
impl Route for StopRecording {
    const METHOD: Verb = Verb::Delete;
    const PATH: &'static str = "/v1/recordings/{name}";
    type Param = String;
    type Request = NoBody;
    type Response = RecordingReply;
}

/// `GET /v1/events`: an NDJSON stream, one [`RuntimeEvent`] a line.
#[derive(Debug)]
pub struct Events;
impl Route for Events {
    const METHOD: Verb = Verb::Get;
    const PATH: &'static str = "/v1/events";
    type Param = ();
    type Request = NoBody;
    type Response = RuntimeEvent;
}

/// A boxed, sendable future (keeps [`NodeApi`] dyn-compatible).
pub type BoxFuture<'a, T> = Pin<Box<dyn Future<Output = T> + Send + 'a>>;

/// The node runtime's operations as the controller drives them: the one
/// method set of the embedded [`crate::NodeRuntime`], the remote
/// [`crate::client::AgentClient`] and the controller's simulated robot.
/// Dyn-compatible (boxed futures), so the controller holds a `dyn` robot.
pub trait NodeApi: Send + Sync {
    type Error: std::error::Error + Send + Sync + 'static;
    /// Apply CPU limits (atomically) then adaptor rates; nodes and edges not
    /// listed become unlimited.
    fn apply<'a>(&'a self, cfg: &'a ResourceConfig) -> BoxFuture<'a, Result<(), Self::Error>>;
    /// Measure `req.probes` over `req.duration_ms` (blocks for the window).
    fn measure<'a>(
        &'a self,
        req: &'a MeasureRequest,
    ) -> BoxFuture<'a, Result<MeasureReport, Self::Error>>;
    /// The current ROS graph (empty without ROS).
    fn graph(&self) -> BoxFuture<'_, Result<Graph, Self::Error>>;
    /// Stop every node of `app` and keep it stopped (remediation).
    fn stop_app<'a>(&'a self, app: &'a str) -> BoxFuture<'a, Result<(), Self::Error>>;
    /// Start every node of `app` again.
    fn start_app<'a>(&'a self, app: &'a str) -> BoxFuture<'a, Result<(), Self::Error>>;
    /// Freeze (SIGSTOP) every node of `app`.
    fn freeze_app<'a>(&'a self, app: &'a str) -> BoxFuture<'a, Result<(), Self::Error>>;
    /// Thaw (SIGCONT) every node of `app`.
    fn thaw_app<'a>(&'a self, app: &'a str) -> BoxFuture<'a, Result<(), Self::Error>>;
    /// Start a rosbag recording of `topics` named `name`: the bag's path,
    /// `None` when the robot cannot record (no rosbag) or `topics` is empty.
    fn start_recording<'a>(
        &'a self,
        name: &'a str,
        topics: &'a [String],
    ) -> BoxFuture<'a, Result<Option<PathBuf>, Self::Error>>;
    /// Stop the recording `name`: the finished bag's path, if one was running.
    fn stop_recording<'a>(
        &'a self,
        name: &'a str,
    ) -> BoxFuture<'a, Result<Option<PathBuf>, Self::Error>>;
    /// Run `stack` (`None`: no stack, stop every node).
    fn set_stack<'a>(
        &'a self,
        stack: Option<&'a RobotStack>,
    ) -> BoxFuture<'a, Result<(), Self::Error>>;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_fill_the_path_escaped() {
        assert_eq!(
            "obj-detector".to_owned().fill(StopApp::PATH),
            "/v1/apps/obj-detector/stop"
        );
        assert_eq!(
            "a/b c".to_owned().fill(StartRecording::PATH),
            "/v1/recordings/a%2Fb%20c"
        );
        assert_eq!(().fill(Nodes::PATH), "/v1/nodes");
    }
}
