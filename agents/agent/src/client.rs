//! `AgentClient`: the controller's handle on a remote node runtime, with the
//! same async methods as [`crate::runtime::NodeRuntime`] (set_stack, apply,
//! measure, graph, inventory, stop/start/freeze/thaw of apps, rosbag
//! recordings, events), over the agent's HTTP API: a Unix socket (no token;
//! the socket's mode is the access rule) or TCP with a bearer token. One HTTP/1 connection per call
//! (`configbot_http::client`), so a blocking `measure` never holds up other calls.

use std::path::PathBuf;
use std::time::Duration;

use configbot_api::graph::Graph;
use configbot_api::measure::{MeasureReport, MeasureRequest};
use configbot_http::client as http;
use configbot_manifests::{ResourceConfig, RobotStack};
use http_body_util::{BodyExt, Full};
use hyper::body::{Bytes, Incoming};
use hyper::{Method, Request, Response, StatusCode, header};
use serde::Serialize;
use serde::de::DeserializeOwned;
use tokio::sync::broadcast;

use crate::agent::NodeStatus;
use crate::events::RuntimeEvent;

/// Where the agent listens.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Endpoint {
    /// The agent's Unix socket (default `/run/configbot/agent.sock`).
    Unix(PathBuf),
    /// `host:port` of the agent's TCP listener and its bearer token.
    Tcp { addr: String, token: String },
}

impl std::fmt::Display for Endpoint {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Unix(p) => write!(f, "unix:{}", p.display()),
            Self::Tcp { addr, .. } => write!(f, "tcp:{addr}"),
        }
    }
}

/// Errors of [`AgentClient`].
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    #[error("connecting to the agent at {endpoint}")]
    Connect {
        endpoint: String,
        #[source]
        source: std::io::Error,
    },
    #[error("connecting to the agent at {endpoint}: timed out")]
    ConnectTimeout { endpoint: String },
    #[error("{method} {path} at {endpoint}")]
    Http {
        endpoint: String,
        method: Method,
        path: String,
        #[source]
        source: configbot_http::client::Error,
    },
    #[error("building request {method} {path}")]
    Request {
        method: Method,
        path: String,
        #[source]
        source: hyper::http::Error,
    },
    #[error("encoding the body of {path}")]
    Encode {
        path: String,
        #[source]
        source: serde_json::Error,
    },
    /// The agent refused: `message` is its error text (names the node/edge).
    #[error("agent answered {method} {path} with {status}: {message}")]
    Status {
        method: Method,
        path: String,
        status: u16,
        message: String,
    },
    #[error("decoding the agent's answer to {path}")]
    Decode {
        path: String,
        #[source]
        source: serde_json::Error,
    },
}

/// Result of client calls.
pub type ClientResult<T> = std::result::Result<T, ClientError>;

/// Drives a remote node runtime; cheap to clone.
#[derive(Debug, Clone)]
pub struct AgentClient {
    endpoint: Endpoint,
    connect_timeout: Duration,
}

/// The largest answer the client reads (an inventory or a graph is at most
/// a few MiB).
const MAX_RESPONSE_BYTES: usize = 64 << 20;

impl AgentClient {
    /// A client of the agent at `endpoint`.
    pub fn new(endpoint: Endpoint) -> Self {
        Self {
            endpoint,
            connect_timeout: Duration::from_secs(5),
        }
    }

    /// A client of the agent's Unix socket.
    pub fn unix(path: impl Into<PathBuf>) -> Self {
        Self::new(Endpoint::Unix(path.into()))
    }

    /// A client of the agent's TCP listener with its bearer token.
    pub fn tcp(addr: impl Into<String>, token: impl Into<String>) -> Self {
        Self::new(Endpoint::Tcp {
            addr: addr.into(),
            token: token.into(),
        })
    }

    /// Where this client connects.
    pub fn endpoint(&self) -> &Endpoint {
        &self.endpoint
    }

    /// The transport's view of where the agent is and what it may take.
    fn transport(&self) -> (http::Endpoint, http::Limits) {
        let endpoint = match &self.endpoint {
            Endpoint::Unix(p) => http::Endpoint::Unix(p.clone()),
            Endpoint::Tcp { addr, .. } => http::Endpoint::Tcp(addr.clone()),
        };
        let limits = http::Limits {
            connect_timeout: self.connect_timeout,
            // `measure` blocks for its window; event streams never end.
            response_timeout: None,
            max_body: MAX_RESPONSE_BYTES,
        };
        (endpoint, limits)
    }

    /// Sends one request on a fresh connection; returns the response
    /// (status checked) with its body still streaming.
    async fn send(
        &self,
        method: Method,
        path: &str,
        body: Option<Vec<u8>>,
    ) -> ClientResult<Response<Incoming>> {
        let mut req = Request::builder()
            .method(method.clone())
            .uri(path)
            .header(header::HOST, "configbot-agent");
        if let Endpoint::Tcp { token, .. } = &self.endpoint {
            req = req.header(header::AUTHORIZATION, format!("Bearer {token}"));
        }
        if body.is_some() {
            req = req.header(header::CONTENT_TYPE, "application/json");
        }
        let req = req
            .body(Full::new(Bytes::from(body.unwrap_or_default())))
            .map_err(|source| ClientError::Request {
                method: method.clone(),
                path: path.to_owned(),
                source,
            })?;
        let (endpoint, limits) = self.transport();
        let resp = http::send(&endpoint, req, &limits)
            .await
            .map_err(|e| self.transport_error(&method, path, e))?;
        if resp.status() == StatusCode::OK {
            return Ok(resp);
        }
        let status = resp.status().as_u16();
        let bytes = http::read_body(resp.into_body(), limits.max_body)
            .await
            .unwrap_or_default();
        let message = serde_json::from_slice::<serde_json::Value>(&bytes)
            .ok()
            .and_then(|v| v.get("error").and_then(|e| e.as_str()).map(str::to_owned))
            .unwrap_or_else(|| String::from_utf8_lossy(&bytes).into_owned());
        Err(ClientError::Status {
            method,
            path: path.to_owned(),
            status,
            message,
        })
    }

    /// A transport failure of `method path`, naming the agent's endpoint.
    fn transport_error(&self, method: &Method, path: &str, e: http::Error) -> ClientError {
        let endpoint = self.endpoint.to_string();
        match e {
            http::Error::Connect(source) => ClientError::Connect { endpoint, source },
            http::Error::ConnectTimeout(_) => ClientError::ConnectTimeout { endpoint },
            source => ClientError::Http {
                endpoint,
                method: method.clone(),
                path: path.to_owned(),
                source,
            },
        }
    }

    async fn call<T: DeserializeOwned>(
        &self,
        method: Method,
        path: &str,
        body: Option<&(impl Serialize + ?Sized)>,
    ) -> ClientResult<T> {
        let body =
            body.map(serde_json::to_vec)
                .transpose()
                .map_err(|source| ClientError::Encode {
                    path: path.to_owned(),
                    source,
                })?;
        let resp = self.send(method.clone(), path, body).await?;
        let bytes = http::read_body(resp.into_body(), MAX_RESPONSE_BYTES)
            .await
            .map_err(|e| self.transport_error(&method, path, e))?;
        serde_json::from_slice(&bytes).map_err(|source| ClientError::Decode {
            path: path.to_owned(),
            source,
        })
    }

    /// `PUT /v1/stack`: replaces the stack at run time.
    ///
    /// A stack without apps (the controller's "no stack": the last one was
    /// deleted) goes as an empty `StackSpec`: as a manifest it has no name
    /// and fails validation, and the agent would go on running the old nodes.
    pub async fn set_stack(&self, stack: &RobotStack) -> ClientResult<()> {
        let res = if stack.spec.apps.is_empty() {
            let empty = crate::spec::StackSpec::default();
            self.call::<serde_json::Value>(Method::PUT, "/v1/stack", Some(&empty))
                .await
        } else {
            self.call::<serde_json::Value>(Method::PUT, "/v1/stack", Some(stack))
                .await
        };
        res.map(|_| ())
    }

    /// `PUT /v1/config`: CPU limits atomically, then adaptor rates.
    pub async fn apply(&self, cfg: &ResourceConfig) -> ClientResult<()> {
        self.call::<serde_json::Value>(Method::PUT, "/v1/config", Some(cfg))
            .await
            .map(|_| ())
    }

    /// `POST /v1/measure`: blocks for the window.
    pub async fn measure(&self, req: &MeasureRequest) -> ClientResult<MeasureReport> {
        self.call(Method::POST, "/v1/measure", Some(req)).await
    }

    /// `GET /v1/graph`.
    pub async fn graph(&self) -> ClientResult<Graph> {
        self.call(Method::GET, "/v1/graph", None::<&()>).await
    }

    /// `GET /v1/nodes`.
    pub async fn inventory(&self) -> ClientResult<Vec<NodeStatus>> {
        self.call(Method::GET, "/v1/nodes", None::<&()>).await
    }

    /// `POST /v1/apps/{app}/stop`.
    pub async fn stop_app(&self, app: &str) -> ClientResult<()> {
        self.app_action(app, "stop").await
    }

    /// `POST /v1/apps/{app}/start`.
    pub async fn start_app(&self, app: &str) -> ClientResult<()> {
        self.app_action(app, "start").await
    }

    /// `POST /v1/apps/{app}/freeze`.
    pub async fn freeze_app(&self, app: &str) -> ClientResult<()> {
        self.app_action(app, "freeze").await
    }

    /// `POST /v1/apps/{app}/thaw`.
    pub async fn thaw_app(&self, app: &str) -> ClientResult<()> {
        self.app_action(app, "thaw").await
    }

    async fn app_action(&self, app: &str, action: &str) -> ClientResult<()> {
        let path = format!("/v1/apps/{}/{action}", path_segment(app));
        self.call::<serde_json::Value>(Method::POST, &path, None::<&()>)
            .await
            .map(|_| ())
    }

    /// `PUT /v1/recordings/{name}`: the bag's path, `None` without rosbag.
    pub async fn start_recording(
        &self,
        name: &str,
        topics: &[String],
    ) -> ClientResult<Option<std::path::PathBuf>> {
        let path = format!("/v1/recordings/{}", path_segment(name));
        let body = crate::api::RecordingRequest {
            topics: topics.to_vec(),
        };
        let r: crate::api::RecordingReply = self.call(Method::PUT, &path, Some(&body)).await?;
        Ok(r.path)
    }

    /// `DELETE /v1/recordings/{name}`: the finished bag's path.
    pub async fn stop_recording(&self, name: &str) -> ClientResult<Option<std::path::PathBuf>> {
        let path = format!("/v1/recordings/{}", path_segment(name));
        let r: crate::api::RecordingReply = self.call(Method::DELETE, &path, None::<&()>).await?;
        Ok(r.path)
    }

    /// `GET /v1/events`: returns once the agent has subscribed, so every
    /// event after this call arrives. The receiver closes when the
    /// connection ends; lines that do not parse are skipped.
    pub async fn events(&self) -> ClientResult<broadcast::Receiver<RuntimeEvent>> {
        let resp = self.send(Method::GET, "/v1/events", None).await?;
        let (tx, rx) = broadcast::channel(4096);
        tokio::spawn(async move {
            let mut body = resp.into_body();
            let mut buf: Vec<u8> = Vec::new();
            while let Some(Ok(frame)) = body.frame().await {
                let Some(data) = frame.data_ref() else {
                    continue;
                };
                buf.extend_from_slice(data);
                while let Some(i) = buf.iter().position(|b| *b == b'\n') {
                    let line: Vec<u8> = buf.drain(..=i).collect();
                    if let Ok(ev) = serde_json::from_slice::<RuntimeEvent>(&line)
                        && tx.send(ev).is_err()
                    {
                        return; // every receiver is gone
                    }
                }
            }
        });
        Ok(rx)
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn app_names_are_escaped_in_paths() {
        assert_eq!(path_segment("obj-detector"), "obj-detector");
        assert_eq!(path_segment("a/b c"), "a%2Fb%20c");
    }
}
