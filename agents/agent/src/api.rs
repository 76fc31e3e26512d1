//! The agent's HTTP API (axum) and Prometheus endpoint.
//!
//! Access rules match the control plane: by default a Unix socket with mode
//! 0600 (only root/the agent's user may connect); TCP only with a bearer token.
//! Bodies, request heads and idle connections are bounded by
//! [`crate::limits`]: an oversized body is a 413, a slow one a 408.
//!
//! - `GET  /v1/nodes`              node inventory
//! - `PUT  /v1/stack`              a `RobotStack` manifest (or a plain `StackSpec`), applied live
//! - `PUT  /v1/config`             a `ResourceConfig`: CPU limits per node, adaptor rates per edge
//! - `POST /v1/measure`            a [`MeasureRequest`] → [`MeasureReport`] (blocks for the window)
//! - `GET  /v1/graph`              the ROS graph
//! - `POST /v1/apps/{app}/stop`    graceful stop of an app
//! - `POST /v1/apps/{app}/start`   start an app again
//! - `POST /v1/apps/{app}/freeze`  SIGSTOP an app's processes (`/thaw`: SIGCONT)
//! - `PUT  /v1/recordings/{name}`  `{"topics": [...]}`: start a rosbag recording → `{"path"}`
//! - `DELETE /v1/recordings/{name}` stop it → `{"path"}` (null: none was running)
//! - `GET  /v1/events`             NDJSON stream of [`RuntimeEvent`]s
//! - `GET  /v1/status`             active process monitor, master URI, committed config
//! - `GET  /metrics`               Prometheus text format

use std::os::unix::fs::PermissionsExt;
use std::path::Path;
use std::sync::Arc;

use axum::body::Body;
use axum::extract::rejection::JsonRejection;
use axum::extract::{DefaultBodyLimit, Path as UrlPath, Request, State};
use axum::http::{StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post, put};
use axum::{Json, Router};
use serde_json::json;

use configbot_api::measure::{MeasureReport, MeasureRequest};
use configbot_manifests::{Manifest, ResourceConfig};

use crate::agent::error_chain;
use crate::error::Error;
use crate::events::RuntimeEvent;
use crate::limits;
use crate::runtime::NodeRuntime;
use crate::spec::StackSpec;

/// An API error; 5xx bodies never carry internals.
#[derive(Debug)]
pub enum ApiError {
    BadRequest(String),
    NotFound(String),
    Conflict(String),
    TooLarge(String),
    Internal,
}

impl From<Error> for ApiError {
    fn from(e: Error) -> Self {
        use configbot_cgroups::Error as C;
        match &e {
            Error::UnknownNode(_) | Error::UnknownApp(_) => Self::NotFound(e.to_string()),
            Error::InvalidStack(_)
            | Error::InvalidConfig(_)
            | Error::InvalidMeasure(_)
            | Error::InvalidRecording(_)
            | Error::Manifest { .. }
            | Error::Adaptor {
                source: configbot_dataplane::DataPlaneError::InvalidRate(_),
                ..
            } => Self::BadRequest(error_chain(&e)),
            Error::NoDataPlane { .. } | Error::Adaptor { .. } => Self::Conflict(error_chain(&e)),
            Error::Cgroup(C::InvalidLimit { .. } | C::InvalidName { .. }) => {
                Self::BadRequest(e.to_string())
            }
            // A kernel-rejected write: the controller needs the file and value.
            Error::Cgroup(C::Apply { .. }) => Self::Conflict(error_chain(&e)),
            _ => {
                eprintln!("configbot-agent: internal error: {}", error_chain(&e));
                Self::Internal
            }
        }
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let (code, msg) = match self {
            Self::BadRequest(m) => (StatusCode::BAD_REQUEST, m),
            Self::NotFound(m) => (StatusCode::NOT_FOUND, m),
            Self::Conflict(m) => (StatusCode::CONFLICT, m),
            Self::TooLarge(m) => (StatusCode::PAYLOAD_TOO_LARGE, m),
            Self::Internal => (
                StatusCode::INTERNAL_SERVER_ERROR,
                "internal error".to_owned(),
            ),
        };
        (code, Json(json!({ "error": msg }))).into_response()
    }
}

/// The API router. `token`: require `Authorization: Bearer <token>` (TCP).
pub fn router(rt: NodeRuntime, token: Option<String>) -> Router {
    let token = Arc::new(token);
    Router::new()
        .route("/v1/nodes", get(nodes))
        .route("/v1/stack", put(put_stack))
        .route("/v1/config", put(put_config))
        .route("/v1/measure", post(measure))
        .route("/v1/graph", get(graph))
        .route("/v1/apps/{app}/{action}", post(app_action))
        .route(
            "/v1/recordings/{name}",
            put(start_recording).delete(stop_recording),
        )
        .route("/v1/events", get(events))
        .route("/v1/status", get(status))
        .route("/metrics", get(metrics))
        .with_state(rt)
        .layer(DefaultBodyLimit::max(limits::MAX_BODY_BYTES))
        .layer(middleware::from_fn(limits::bounded_body))
        .layer(middleware::from_fn_with_state(token, auth))
}

async fn auth(State(token): State<Arc<Option<String>>>, req: Request, next: Next) -> Response {
    if let Some(want) = token.as_deref() {
        let got = req
            .headers()
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.strip_prefix("Bearer "));
        if !got.is_some_and(|g| constant_time_eq(g.as_bytes(), want.as_bytes())) {
            return (
                StatusCode::UNAUTHORIZED,
                Json(json!({ "error": "missing or wrong bearer token" })),
            )
                .into_response();
        }
    }
    next.run(req).await
}

fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

fn bad_json(r: &JsonRejection) -> ApiError {
    if r.status() == StatusCode::PAYLOAD_TOO_LARGE {
        return ApiError::TooLarge(r.body_text());
    }
    ApiError::BadRequest(r.body_text())
}

async fn nodes(State(rt): State<NodeRuntime>) -> Result<impl IntoResponse, ApiError> {
    Ok(Json(rt.inventory().await?))
}

async fn put_stack(
    State(rt): State<NodeRuntime>,
    body: Result<Json<serde_json::Value>, JsonRejection>,
) -> Result<impl IntoResponse, ApiError> {
    let Json(v) = body.map_err(|r| bad_json(&r))?;
    let spec = if v.get("apiVersion").is_some() {
        match configbot_manifests::decode_and_validate(&v) {
            Ok(Manifest::RobotStack(s)) => StackSpec::from_manifest(&s)?,
            Ok(other) => {
                return Err(ApiError::BadRequest(format!(
                    "want a RobotStack, got a {}",
                    other.kind().name()
                )));
            }
            Err(errs) => {
                let msg: Vec<String> = errs
                    .iter()
                    .map(|e| format!("{}: {}", e.path, e.message))
                    .collect();
                return Err(ApiError::BadRequest(msg.join("; ")));
            }
        }
    } else {
        serde_json::from_value::<StackSpec>(v).map_err(|e| ApiError::BadRequest(e.to_string()))?
    };
    let diff = rt.set_stack_spec(spec).await?;
    Ok(Json(diff))
}

async fn put_config(
    State(rt): State<NodeRuntime>,
    body: Result<Json<ResourceConfig>, JsonRejection>,
) -> Result<impl IntoResponse, ApiError> {
    let Json(cfg) = body.map_err(|r| bad_json(&r))?;
    rt.apply(&cfg).await?;
    Ok(Json(
        json!({ "applied": true, "committed": rt.agent().committed() }),
    ))
}

async fn measure(
    State(rt): State<NodeRuntime>,
    body: Result<Json<MeasureRequest>, JsonRejection>,
) -> Result<Json<MeasureReport>, ApiError> {
    let Json(req) = body.map_err(|r| bad_json(&r))?;
    Ok(Json(rt.measure(&req).await?))
}

async fn graph(State(rt): State<NodeRuntime>) -> Result<impl IntoResponse, ApiError> {
    Ok(Json(rt.graph().await?))
}

/// `POST /v1/apps/{app}/{action}`: stop, start, freeze or thaw an app.
async fn app_action(
    State(rt): State<NodeRuntime>,
    UrlPath((app, action)): UrlPath<(String, String)>,
) -> Result<impl IntoResponse, ApiError> {
    match action.as_str() {
        "stop" => rt.stop_app(&app).await?,
        "start" => rt.start_app(&app).await?,
        "freeze" => rt.freeze_app(&app).await?,
        "thaw" => rt.thaw_app(&app).await?,
        other => {
            return Err(ApiError::NotFound(format!(
                "no app action {other:?} (stop, start, freeze, thaw)"
            )));
        }
    }
    Ok(Json(json!({ "app": app, "done": action })))
}

/// Body of `PUT /v1/recordings/{name}`.
#[derive(Debug, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecordingRequest {
    pub topics: Vec<String>,
}

/// Reply of the recording endpoints.
#[derive(Debug, serde::Serialize, serde::Deserialize)]
pub struct RecordingReply {
    pub path: Option<std::path::PathBuf>,
}

async fn start_recording(
    State(rt): State<NodeRuntime>,
    UrlPath(name): UrlPath<String>,
    body: Result<Json<RecordingRequest>, JsonRejection>,
) -> Result<Json<RecordingReply>, ApiError> {
    let Json(req) = body.map_err(|r| bad_json(&r))?;
    let path = rt.start_recording(&name, &req.topics).await?;
    Ok(Json(RecordingReply { path }))
}

async fn stop_recording(
    State(rt): State<NodeRuntime>,
    UrlPath(name): UrlPath<String>,
) -> Result<Json<RecordingReply>, ApiError> {
    let path = rt.stop_recording(&name).await?;
    Ok(Json(RecordingReply { path }))
}

async fn status(State(rt): State<NodeRuntime>) -> impl IntoResponse {
    let agent = rt.agent();
    Json(json!({
        "activeMonitor": agent.active_monitor(),
        "monitor": rt.monitor_status(),
        "masterUri": rt.master_uri(),
        "backend": agent.backend().kind(),
        "committed": agent.committed(),
    }))
}

async fn metrics(State(rt): State<NodeRuntime>) -> Result<impl IntoResponse, ApiError> {
    let text = rt.render_metrics().map_err(|_| ApiError::Internal)?;
    Ok(([(header::CONTENT_TYPE, "text/plain; version=0.0.4")], text))
}

async fn events(State(rt): State<NodeRuntime>) -> impl IntoResponse {
    let rx = rt.events();
    let stream = futures_util::stream::unfold(rx, |mut rx| async move {
        let ev = match rx.recv().await {
            Ok(ev) => ev,
            // A slow reader missed events: tell it, then go on.
            Err(tokio::sync::broadcast::error::RecvError::Lagged(n)) => {
                RuntimeEvent::Lagged { missed: n }
            }
            Err(tokio::sync::broadcast::error::RecvError::Closed) => return None,
        };
        let mut line = serde_json::to_string(&ev).unwrap_or_default();
        line.push('\n');
        Some((Ok::<_, std::convert::Infallible>(line), rx))
    });
    (
        [(header::CONTENT_TYPE, "application/x-ndjson")],
        Body::from_stream(stream),
    )
}

/// Binds a Unix socket at `path` with mode 0600, replacing a stale socket file.
pub fn bind_unix(path: &Path) -> std::io::Result<tokio::net::UnixListener> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir)?;
    }
    match std::fs::remove_file(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(e),
        _ => {}
    }
    let listener = tokio::net::UnixListener::bind(path)?;
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o600))?;
    Ok(listener)
}

/// Serves the API on a Unix socket (no token: the file mode is the access rule).
pub async fn serve_unix(
    rt: NodeRuntime,
    listener: tokio::net::UnixListener,
) -> std::io::Result<()> {
    limits::serve(listener, router(rt, None)).await
}

/// Serves the API on TCP; a non-empty bearer token is mandatory.
pub async fn serve_tcp(
    rt: NodeRuntime,
    listener: tokio::net::TcpListener,
    token: String,
) -> std::io::Result<()> {
    if token.is_empty() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "tcp listener needs a bearer token",
        ));
    }
    limits::serve(listener, router(rt, Some(token))).await
}
