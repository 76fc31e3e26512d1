//! A small HTTP client for the control plane's API over its Unix socket, used
//! by the CLI and the tests, on the workspace's one transport
//! (`configbot_http::client`). (Remote access goes through the HTTPS listener,
//! with kubectl or any Kubernetes client.)

use std::path::PathBuf;
use std::time::Duration;

use configbot_http::client as http;
use http_body_util::{BodyExt, Full};
use hyper::body::Bytes;
use hyper::{Method, Request, StatusCode};
use serde_json::Value;

/// How long connecting to the socket may take (a live server accepts at once).
const CONNECT_TIMEOUT: Duration = Duration::from_secs(5);

/// The largest answer the CLI reads: a list of every object in the store,
/// each at most the API's 3 MiB.
const MAX_RESPONSE_BYTES: usize = 256 << 20;

/// Where the API is.
#[derive(Debug, Clone)]
pub enum Endpoint {
    Unix(PathBuf),
}

impl Endpoint {
    /// `unix:///path` or a bare path.
    pub fn parse(s: &str) -> Result<Endpoint, String> {
        if s.starts_with("http://") || s.starts_with("https://") {
            return Err(format!(
                "{s}: the configbot CLI talks to the control plane's Unix socket; for the HTTPS listener use kubectl"
            ));
        }
        let path = s.strip_prefix("unix://").unwrap_or(s);
        Ok(Endpoint::Unix(PathBuf::from(path)))
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    #[error(
        "cannot reach the control plane at {endpoint}: {source} (is `configbot serve` running? set --server or CONFIGBOT_SERVER)"
    )]
    Connect {
        endpoint: String,
        #[source]
        source: std::io::Error,
    },
    #[error("http: {0}")]
    Http(String),
    /// The server answered with a Kubernetes `Status` failure.
    #[error("{message}")]
    Api {
        code: u16,
        reason: String,
        message: String,
        body: Value,
    },
}

/// A response: status and JSON body.
#[derive(Debug)]
pub struct Response {
    pub status: StatusCode,
    pub body: Value,
}

#[derive(Debug, Clone)]
pub struct Client {
    endpoint: Endpoint,
}

impl Client {
    pub fn new(endpoint: Endpoint) -> Client {
        Client { endpoint }
    }

    /// The transport's view of where the API is and what it may take.
    fn transport(&self) -> (http::Endpoint, http::Limits) {
        let Endpoint::Unix(p) = &self.endpoint;
        let limits = http::Limits {
            connect_timeout: CONNECT_TIMEOUT,
            // Watches stream until the caller has seen enough.
            response_timeout: None,
            max_body: MAX_RESPONSE_BYTES,
        };
        (http::Endpoint::Unix(p.clone()), limits)
    }

    /// A transport failure: an unreachable server names its endpoint.
    fn transport_error(&self, e: http::Error) -> ClientError {
        let endpoint = format!("{:?}", self.endpoint);
        match e {
            http::Error::Connect(source) => ClientError::Connect { endpoint, source },
            http::Error::ConnectTimeout(t) => ClientError::Connect {
                endpoint,
                source: std::io::Error::new(
                    std::io::ErrorKind::TimedOut,
                    format!("no connection within {} s", t.as_secs_f64()),
                ),
            },
            e => ClientError::Http(e.to_string()),
        }
    }

    fn request(
        &self,
        method: Method,
        path: &str,
        content_type: &str,
        body: Vec<u8>,
    ) -> Result<Request<Full<Bytes>>, ClientError> {
        Request::builder()
            .method(method)
            .uri(path)
            .header("host", "configbot")
            .header("content-type", content_type)
            .header("accept", "application/json")
            .body(Full::new(Bytes::from(body)))
            .map_err(|e| ClientError::Http(e.to_string()))
    }

    /// Send a request and read the whole JSON answer; failures become `ClientError::Api`.
    pub async fn send(
        &self,
        method: Method,
        path: &str,
        body: Option<&Value>,
        content_type: &str,
    ) -> Result<Response, ClientError> {
        let bytes = body.map(|b| b.to_string().into_bytes()).unwrap_or_default();
        let req = self.request(method, path, content_type, bytes)?;
        let (endpoint, limits) = self.transport();
        let resp = http::fetch(&endpoint, req, &limits)
            .await
            .map_err(|e| self.transport_error(e))?;
        let status = resp.status();
        let data = resp.into_body();
        let body: Value = serde_json::from_slice(&data)
            .unwrap_or_else(|_| Value::String(String::from_utf8_lossy(&data).into_owned()));
        if !status.is_success() {
            return Err(ClientError::Api {
                code: status.as_u16(),
                reason: body["reason"].as_str().unwrap_or("").to_string(),
                message: body["message"]
                    .as_str()
                    .map(str::to_string)
                    .unwrap_or_else(|| format!("HTTP {status}: {body}")),
                body,
            });
        }
        Ok(Response { status, body })
    }

    pub async fn get(&self, path: &str) -> Result<Value, ClientError> {
        Ok(self
            .send(Method::GET, path, None, "application/json")
            .await?
            .body)
    }

    /// Stream newline-delimited JSON values (a watch) to `on_line` until it returns false.
    pub async fn watch(
        &self,
        path: &str,
        mut on_line: impl FnMut(Value) -> bool,
    ) -> Result<(), ClientError> {
        let req = self.request(Method::GET, path, "application/json", Vec::new())?;
        let (endpoint, limits) = self.transport();
        let resp = http::send(&endpoint, req, &limits)
            .await
            .map_err(|e| self.transport_error(e))?;
        if !resp.status().is_success() {
            return Err(ClientError::Http(format!(
                "watch failed: HTTP {}",
                resp.status()
            )));
        }
        let mut body = resp.into_body();
        let mut buf = Vec::new();
        while let Some(frame) = body.frame().await {
            let frame = frame.map_err(|e| ClientError::Http(e.to_string()))?;
            if let Some(data) = frame.data_ref() {
                buf.extend_from_slice(data);
                while let Some(i) = buf.iter().position(|b| *b == b'\n') {
                    let line: Vec<u8> = buf.drain(..=i).collect();
                    if let Ok(v) = serde_json::from_slice::<Value>(&line)
                        && !on_line(v)
                    {
                        return Ok(());
                    }
                }
            }
        }
        Ok(())
    }
}

/// The API path of a collection or an object.
pub fn path(
    kind: configbot_manifests::Kind,
    namespace: Option<&str>,
    name: Option<&str>,
) -> String {
    let mut p = String::from("/apis/configbot.dev/v1alpha1");
    if let Some(ns) = namespace {
        p.push_str(&format!("/namespaces/{ns}"));
    }
    p.push('/');
    p.push_str(kind.plural());
    if let Some(n) = name {
        p.push('/');
        p.push_str(n);
    }
    p
}
