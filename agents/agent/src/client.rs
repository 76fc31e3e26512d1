//! `AgentClient`: the controller's handle on a remote node runtime. It
//! implements [`NodeApi`] like [`crate::runtime::NodeRuntime`] does, plus
//! the inventory and the event stream, over the agent's HTTP API: a Unix
//! socket (no token; the socket's mode is the access rule) or TCP with a
//! bearer token. Every operation is one [`AgentClient::call`] of a route of
//! [`crate::contract`]. One HTTP/1 connection per call
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
use tokio::sync::broadcast;

use crate::agent::NodeStatus;
use crate::contract::{
    BoxFuture, Events, FreezeApp, GetGraph, Measure, NoBody, NodeApi, Nodes, PathParam, PutConfig,
    PutStack, RecordingRequest, RequestBody, Route, StackBody, StartApp, StartRecording, StopApp,
    StopRecording, ThawApp, Verb,
};
use crate::spec::StackSpec;

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

    /// Sends route `R` with its path parameter and body; its answer.
    pub async fn call<R: Route>(
        &self,
        param: &R::Param,
        req: &R::Request,
    ) -> ClientResult<R::Response> {
        let path = param.fill(R::PATH);
        let method = method(R::METHOD);
        let body = req
            .encode()
            .transpose()
            .map_err(|source| ClientError::Encode {
                path: path.clone(),
                source,
            })?;
        let resp = self.send(method.clone(), &path, body).await?;
        let bytes = http::read_body(resp.into_body(), MAX_RESPONSE_BYTES)
            .await
            .map_err(|e| self.transport_error(&method, &path, e))?;
        serde_json::from_slice(&bytes).map_err(|source| ClientError::Decode { path, source })
    }

    /// The node inventory.
    pub async fn inventory(&self) -> ClientResult<Vec<NodeStatus>> {
        self.call::<Nodes>(&(), &NoBody).await
    }

    /// The agent's runtime events: returns once the agent has subscribed,
    /// so every event after this call arrives. The receiver closes when the
    /// connection ends; lines that do not parse are skipped.
    pub async fn events(&self) -> ClientResult<broadcast::Receiver<<Events as Route>::Response>> {
        let resp = self
            .send(method(Events::METHOD), Events::PATH, None)
            .await?;
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
                    if let Ok(ev) = serde_json::from_slice(&line)
                        && tx.send(ev).is_err()
                    {
                        return; // every receiver is gone
                    }
                }
            }
        });
        Ok(rx)
    }

    /// Calls the app route `R` on `app`.
    fn app<R: Route<Param = String, Request = NoBody>>(
        &self,
        app: &str,
    ) -> BoxFuture<'_, ClientResult<()>> {
        let app = app.to_owned();
        Box::pin(async move { self.call::<R>(&app, &NoBody).await.map(|_| ()) })
    }
}

fn method(v: Verb) -> Method {
    match v {
        Verb::Get => Method::GET,
        Verb::Put => Method::PUT,
        Verb::Post => Method::POST,
        Verb::Delete => Method::DELETE,
    }
}

impl NodeApi for AgentClient {
    type Error = ClientError;

    fn apply<'a>(&'a self, cfg: &'a ResourceConfig) -> BoxFuture<'a, ClientResult<()>> {
        Box::pin(async move { self.call::<PutConfig>(&(), cfg).await.map(|_| ()) })
    }

    fn measure<'a>(
        &'a self,
        req: &'a MeasureRequest,
    ) -> BoxFuture<'a, ClientResult<MeasureReport>> {
        Box::pin(self.call::<Measure>(&(), req))
    }

    fn graph(&self) -> BoxFuture<'_, ClientResult<Graph>> {
        Box::pin(self.call::<GetGraph>(&(), &NoBody))
    }

    fn stop_app<'a>(&'a self, app: &'a str) -> BoxFuture<'a, ClientResult<()>> {
        self.app::<StopApp>(app)
    }

    fn start_app<'a>(&'a self, app: &'a str) -> BoxFuture<'a, ClientResult<()>> {
        self.app::<StartApp>(app)
    }

    fn freeze_app<'a>(&'a self, app: &'a str) -> BoxFuture<'a, ClientResult<()>> {
        self.app::<FreezeApp>(app)
    }

    fn thaw_app<'a>(&'a self, app: &'a str) -> BoxFuture<'a, ClientResult<()>> {
        self.app::<ThawApp>(app)
    }

    fn start_recording<'a>(
        &'a self,
        name: &'a str,
        topics: &'a [String],
    ) -> BoxFuture<'a, ClientResult<Option<PathBuf>>> {
        Box::pin(async move {
            let body = RecordingRequest {
                topics: topics.to_vec(),
            };
            let r = self.call::<StartRecording>(&name.to_owned(), &body).await?;
            Ok(r.path)
        })
    }

    fn stop_recording<'a>(&'a self, name: &'a str) -> BoxFuture<'a, ClientResult<Option<PathBuf>>> {
        Box::pin(async move {
            let r = self
                .call::<StopRecording>(&name.to_owned(), &NoBody)
                .await?;
            Ok(r.path)
        })
    }

    /// No stack, or a stack without apps (the last one was deleted), goes
    /// as an empty `StackSpec`: as a manifest it has no name and fails
    /// validation, and the agent would go on running the old nodes.
    fn set_stack<'a>(&'a self, stack: Option<&'a RobotStack>) -> BoxFuture<'a, ClientResult<()>> {
        let body = match stack {
            Some(s) if !s.spec.apps.is_empty() => StackBody::Manifest(Box::new(s.clone())),
            _ => StackBody::Spec(StackSpec::default()),
        };
        Box::pin(async move { self.call::<PutStack>(&(), &body).await.map(|_| ()) })
    }
}
