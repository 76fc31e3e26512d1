//! The agent's HTTP API (axum) and Prometheus endpoint.
//!
//! Access rules match the control plane: by default a Unix socket with mode
//! 0600 (only root/the agent's user may connect); TCP only with a bearer token.
//!
//! - `GET  /v1/nodes`              node inventory
//! - `PUT  /v1/config`             [`ConfigUpdate`]: CPU limits per node (+ period), adaptor rates
//! - `POST /v1/apps/{app}/stop`    graceful stop of an app
//! - `POST /v1/apps/{app}/start`   start an app again
//! - `GET  /v1/events`             NDJSON stream of [`AgentEvent`]s
//! - `GET  /v1/status`             active process monitor, committed config
//! - `GET  /metrics`               Prometheus text format

use std::os::unix::fs::PermissionsExt;
use std::path::Path;
use std::sync::Arc;

use axum::body::Body;
use axum::extract::rejection::JsonRejection;
use axum::extract::{Path as UrlPath, Request, State};
use axum::http::{StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post, put};
use axum::{Json, Router};
use serde_json::json;

use crate::agent::{Agent, ConfigUpdate, error_chain};
use crate::error::Error;

/// An API error; 5xx bodies never carry internals.
#[derive(Debug)]
pub enum ApiError {
    BadRequest(String),
    NotFound(String),
    Conflict(String),
    Internal,
}

impl From<Error> for ApiError {
    fn from(e: Error) -> Self {
        use configbot_cgroups::Error as C;
        match &e {
            Error::UnknownNode(_) | Error::UnknownApp(_) => Self::NotFound(e.to_string()),
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
            Self::Internal => (
                StatusCode::INTERNAL_SERVER_ERROR,
                "internal error".to_owned(),
            ),
        };
        (code, Json(json!({ "error": msg }))).into_response()
    }
}

/// The API router. `token`: require `Authorization: Bearer <token>` (TCP).
pub fn router(agent: Agent, token: Option<String>) -> Router {
    let token = Arc::new(token);
    Router::new()
        .route("/v1/nodes", get(nodes))
        .route("/v1/config", put(put_config))
        .route("/v1/apps/{app}/stop", post(stop_app))
        .route("/v1/apps/{app}/start", post(start_app))
        .route("/v1/events", get(events))
        .route("/v1/status", get(status))
        .route("/metrics", get(metrics))
        .with_state(agent)
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

async fn nodes(State(agent): State<Agent>) -> impl IntoResponse {
    Json(agent.inventory())
}

async fn put_config(
    State(agent): State<Agent>,
    body: Result<Json<ConfigUpdate>, JsonRejection>,
) -> Result<impl IntoResponse, ApiError> {
    let Json(update) = body.map_err(|r| ApiError::BadRequest(r.body_text()))?;
    let agent2 = agent.clone();
    // Cgroup writes are blocking file IO.
    tokio::task::spawn_blocking(move || agent2.put_config(update))
        .await
        .map_err(|_| ApiError::Internal)??;
    Ok(Json(
        json!({ "applied": true, "committed": agent.committed() }),
    ))
}

async fn stop_app(
    State(agent): State<Agent>,
    UrlPath(app): UrlPath<String>,
) -> Result<impl IntoResponse, ApiError> {
    agent.stop_app(&app).await?;
    Ok(Json(json!({ "app": app, "stopped": true })))
}

async fn start_app(
    State(agent): State<Agent>,
    UrlPath(app): UrlPath<String>,
) -> Result<impl IntoResponse, ApiError> {
    agent.start_app(&app)?;
    Ok(Json(json!({ "app": app, "started": true })))
}

async fn status(State(agent): State<Agent>) -> impl IntoResponse {
    Json(json!({
        "activeMonitor": agent.active_monitor(),
        "backend": agent.backend().kind(),
        "committed": agent.committed(),
    }))
}

async fn metrics(State(agent): State<Agent>) -> Result<impl IntoResponse, ApiError> {
    let text = agent.metrics().render().map_err(|_| ApiError::Internal)?;
    Ok(([(header::CONTENT_TYPE, "text/plain; version=0.0.4")], text))
}

async fn events(State(agent): State<Agent>) -> impl IntoResponse {
    let rx = agent.subscribe();
    let stream = futures_util::stream::unfold(rx, |mut rx| async move {
        let line = match rx.recv().await {
            Ok(ev) => {
                let mut line = serde_json::to_string(&ev).unwrap_or_default();
                line.push('\n');
                line
            }
            // A slow reader missed events: tell it, then go on.
            Err(tokio::sync::broadcast::error::RecvError::Lagged(n)) => {
                format!("{{\"type\":\"lagged\",\"missed\":{n}}}\n")
            }
            Err(tokio::sync::broadcast::error::RecvError::Closed) => return None,
        };
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
pub async fn serve_unix(agent: Agent, listener: tokio::net::UnixListener) -> std::io::Result<()> {
    axum::serve(listener, router(agent, None)).await
}

/// Serves the API on TCP; a non-empty bearer token is mandatory.
pub async fn serve_tcp(
    agent: Agent,
    listener: tokio::net::TcpListener,
    token: String,
) -> std::io::Result<()> {
    if token.is_empty() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "tcp listener needs a bearer token",
        ));
    }
    axum::serve(listener, router(agent, Some(token))).await
}
