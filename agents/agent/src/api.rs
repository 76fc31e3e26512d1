//! The agent's HTTP API (axum) and Prometheus endpoint.
//!
//! Access: by default a Unix socket with mode 0600 (only root/the agent's
//! user may connect); TCP only with a bearer token, over plain HTTP (the
//! control plane's TCP is HTTPS).
//! Bodies, request heads and idle connections are bounded by
//! [`crate::limits`]: an oversized body is a 413, a slow one a 408.
//!
//! The operations the controller calls are the routes of [`crate::contract`]
//! (method, path, body and answer each stated there once), registered here
//! with one handler each by `route`. Besides them:
//!
//! - `GET  /v1/status`             active process monitor, master URI, committed config
//! - `GET  /metrics`               Prometheus text format
//!
//! Any other path is a 404 with the usual `{"error"}` body.

use std::future::Future;
use std::os::unix::fs::PermissionsExt;
use std::path::Path;
use std::sync::Arc;

use axum::body::Body;
use axum::extract::rejection::JsonRejection;
use axum::extract::{
    DefaultBodyLimit, FromRequest, FromRequestParts, Path as UrlPath, Request, State,
};
use axum::http::request::Parts;
use axum::http::{Method, StatusCode, Uri, header};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::{MethodFilter, get, on};
use axum::{Json, Router};
use serde::de::DeserializeOwned;
use serde_json::json;

use configbot_api::graph::Graph;
use configbot_api::measure::{MeasureReport, MeasureRequest};
use configbot_manifests::{Manifest, ResourceConfig};

use crate::agent::NodeStatus;
use crate::agent::error_chain;
use crate::agent::stack::StackDiff;
use crate::contract::{
    AppReply, BoxFuture, Events, FreezeApp, GetGraph, Measure, NoBody, NodeApi, Nodes, PutConfig,
    PutStack, RecordingReply, RecordingRequest, Route, StackBody, StartApp, StartRecording,
    StopApp, StopRecording, ThawApp, Verb,
};
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
                tracing::error!(error = %error_chain(&e), "internal error answered as 500");
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
    let r = Router::new();
    let r = route::<Nodes, _, _>(r, nodes);
    let r = route::<PutStack, _, _>(r, put_stack);
    let r = route::<PutConfig, _, _>(r, put_config);
    let r = route::<Measure, _, _>(r, measure);
    let r = route::<GetGraph, _, _>(r, graph);
    let r = app_route::<StopApp>(r, NodeRuntime::stop_app);
    let r = app_route::<StartApp>(r, NodeRuntime::start_app);
    let r = app_route::<FreezeApp>(r, NodeRuntime::freeze_app);
    let r = app_route::<ThawApp>(r, NodeRuntime::thaw_app);
    let r = route::<StartRecording, _, _>(r, start_recording);
    let r = route::<StopRecording, _, _>(r, stop_recording);
    r.route(Events::PATH, on(filter(Events::METHOD), events))
        .route("/v1/status", get(status))
        .route("/metrics", get(metrics))
        .fallback(not_found)
        .with_state(rt)
        .layer(DefaultBodyLimit::max(limits::MAX_BODY_BYTES))
        .layer(middleware::from_fn(limits::bounded_body))
        .layer(middleware::from_fn_with_state(token, auth))
}

fn filter(v: Verb) -> MethodFilter {
    match v {
        Verb::Get => MethodFilter::GET,
        Verb::Put => MethodFilter::PUT,
        Verb::Post => MethodFilter::POST,
        Verb::Delete => MethodFilter::DELETE,
    }
}

/// Registers route `R` with `handler`, which gets the runtime, the path
/// parameter and the body as `R` types them and answers `R::Response` (as
/// JSON) or an [`ApiError`].
fn route<R, F, Fut>(router: Router<NodeRuntime>, handler: F) -> Router<NodeRuntime>
where
    R: Route + 'static,
    R::Param: FromPath,
    R::Request: FromBody,
    F: Fn(NodeRuntime, R::Param, R::Request) -> Fut + Clone + Send + Sync + 'static,
    Fut: Future<Output = Result<R::Response, ApiError>> + Send + 'static,
{
    let h = move |State(rt): State<NodeRuntime>, req: Request| async move {
        let (mut parts, body) = req.into_parts();
        let param = match R::Param::from_path(&mut parts).await {
            Ok(p) => p,
            Err(e) => return e,
        };
        let body = match R::Request::from_body(Request::from_parts(parts, body)).await {
            Ok(b) => b,
            Err(e) => return e,
        };
        match handler(rt, param, body).await {
            Ok(v) => Json(v).into_response(),
            Err(e) => e.into_response(),
        }
    };
    router.route(R::PATH, on(filter(R::METHOD), h))
}

/// Registers an app route: `op` on the app named in the path, answered with
/// the action (the path's last segment).
fn app_route<R>(
    router: Router<NodeRuntime>,
    op: for<'a> fn(&'a NodeRuntime, &'a str) -> BoxFuture<'a, crate::Result<()>>,
) -> Router<NodeRuntime>
where
    R: Route<Param = String, Request = NoBody, Response = AppReply> + 'static,
{
    route::<R, _, _>(router, move |rt, app, NoBody| async move {
        op(&rt, &app).await?;
        let done = R::PATH.rsplit('/').next().unwrap_or_default().to_owned();
        Ok(AppReply { app, done })
    })
}

/// A route's path parameter, taken from the request.
trait FromPath: Sized + Send {
    fn from_path(parts: &mut Parts) -> impl Future<Output = Result<Self, Response>> + Send;
}

impl FromPath for () {
    async fn from_path(_: &mut Parts) -> Result<(), Response> {
        Ok(())
    }
}

impl FromPath for String {
    async fn from_path(parts: &mut Parts) -> Result<Self, Response> {
        UrlPath::<String>::from_request_parts(parts, &())
            .await
            .map(|UrlPath(s)| s)
            .map_err(IntoResponse::into_response)
    }
}

/// A route's request body, taken from the request.
trait FromBody: Sized + Send {
    fn from_body(req: Request) -> impl Future<Output = Result<Self, Response>> + Send;
}

impl FromBody for NoBody {
    async fn from_body(_: Request) -> Result<NoBody, Response> {
        Ok(NoBody)
    }
}

impl<T: DeserializeOwned + Send> FromBody for T {
    async fn from_body(req: Request) -> Result<Self, Response> {
        Json::<T>::from_request(req, &())
            .await
            .map(|Json(v)| v)
            .map_err(|r| bad_json(&r).into_response())
    }
}

/// A `RobotStack` manifest (has `apiVersion`; decoded and validated, every
/// error named) or a plain `StackSpec`.
impl FromBody for StackBody {
    async fn from_body(req: Request) -> Result<Self, Response> {
        let v = serde_json::Value::from_body(req).await?;
        stack_body(v).map_err(IntoResponse::into_response)
    }
}

fn stack_body(v: serde_json::Value) -> Result<StackBody, ApiError> {
    if v.get("apiVersion").is_none() {
        return serde_json::from_value::<StackSpec>(v)
            .map(StackBody::Spec)
            .map_err(|e| ApiError::BadRequest(e.to_string()));
    }
    match configbot_manifests::decode_and_validate(&v) {
        Ok(Manifest::RobotStack(s)) => Ok(StackBody::Manifest(Box::new(s))),
        Ok(other) => Err(ApiError::BadRequest(format!(
            "want a RobotStack, got a {}",
            other.kind().name()
        ))),
        Err(errs) => {
            let msg: Vec<String> = errs
                .iter()
                .map(|e| format!("{}: {}", e.path, e.message))
                .collect();
            Err(ApiError::BadRequest(msg.join("; ")))
        }
    }
}

async fn not_found(method: Method, uri: Uri) -> ApiError {
    ApiError::NotFound(format!("no endpoint {method} {}", uri.path()))
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

async fn nodes(rt: NodeRuntime, (): (), _: NoBody) -> Result<Vec<NodeStatus>, ApiError> {
    Ok(rt.inventory().await?)
}

async fn put_stack(rt: NodeRuntime, (): (), body: StackBody) -> Result<StackDiff, ApiError> {
    let spec = match body {
        StackBody::Manifest(s) => StackSpec::from_manifest(&s)?,
        StackBody::Spec(s) => s,
    };
    Ok(rt.set_stack_spec(spec).await?)
}

async fn put_config(
    rt: NodeRuntime,
    (): (),
    cfg: ResourceConfig,
) -> Result<serde_json::Value, ApiError> {
    rt.apply(&cfg).await?;
    Ok(json!({ "applied": true, "committed": rt.agent().committed() }))
}

async fn measure(rt: NodeRuntime, (): (), req: MeasureRequest) -> Result<MeasureReport, ApiError> {
    Ok(rt.measure(&req).await?)
}

async fn graph(rt: NodeRuntime, (): (), _: NoBody) -> Result<Graph, ApiError> {
    Ok(rt.graph().await?)
}

async fn start_recording(
    rt: NodeRuntime,
    name: String,
    req: RecordingRequest,
) -> Result<RecordingReply, ApiError> {
    let path = rt.start_recording(&name, &req.topics).await?;
    Ok(RecordingReply { path })
}

async fn stop_recording(
    rt: NodeRuntime,
    name: String,
    _: NoBody,
) -> Result<RecordingReply, ApiError> {
    let path = rt.stop_recording(&name).await?;
    Ok(RecordingReply { path })
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

/// Serves the API on TCP; a bearer token that is not blank is mandatory.
pub async fn serve_tcp(
    rt: NodeRuntime,
    listener: tokio::net::TcpListener,
    token: String,
) -> std::io::Result<()> {
    if token.trim().is_empty() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "tcp listener needs a bearer token (not blank)",
        ));
    }
    limits::serve(listener, router(rt, Some(token))).await
}
