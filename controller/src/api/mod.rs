//! The control plane's HTTP API (axum): Kubernetes-style paths so stock
//! `kubectl` works, plus `/metrics`. Served on a Unix socket (0600) by
//! default; on TCP only over TLS with a bearer token. Request bodies, heads
//! and idle connections are bounded by [`limits`].

pub mod apply;
pub mod discovery;
pub mod limits;
pub mod managed;
pub mod openapi;
pub mod patch;
pub mod resources;
pub mod selector;
pub mod status;
pub mod tls;
pub mod watch;

use std::os::unix::fs::PermissionsExt;
use std::path::Path;
use std::sync::Arc;

use axum::Router;
use axum::extract::{DefaultBodyLimit, Request, State};
use axum::http::{StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::get;

use crate::metrics::Metrics;
use crate::store::Store;
use status::ApiError;

pub use limits::MAX_BODY_BYTES;

/// Shared state of every handler.
#[derive(Debug, Clone)]
pub struct AppState {
    pub store: Arc<Store>,
    pub metrics: Arc<Metrics>,
}

/// The API as a router (no listener), so tests drive it with `oneshot`.
pub fn router(state: AppState) -> Router {
    use resources as r;
    let obj = "/apis/configbot.dev/v1alpha1/namespaces/{ns}/{plural}/{name}";
    Router::new()
        .route("/version", get(discovery::version))
        .route("/api", get(discovery::core_versions))
        .route("/api/v1", get(discovery::core_v1))
        .route("/api/v1/events", get(r::events))
        .route("/api/v1/namespaces", get(r::namespaces))
        .route("/api/v1/namespaces/{ns}/events", get(r::events))
        .route("/openapi/v3", get(openapi::index))
        .route(
            "/openapi/v3/apis/configbot.dev/v1alpha1",
            get(openapi::group_version),
        )
        .route("/apis", get(discovery::groups))
        .route("/apis/configbot.dev", get(discovery::group))
        .route("/apis/configbot.dev/v1alpha1", get(discovery::resources))
        .route("/apis/configbot.dev/v1alpha1/{plural}", get(r::list_all))
        .route(
            "/apis/configbot.dev/v1alpha1/namespaces/{ns}/{plural}",
            get(r::list_ns).post(r::create),
        )
        .route(
            obj,
            get(r::get)
                .put(r::replace)
                .patch(r::patch)
                .delete(r::delete),
        )
        .route(
            &format!("{obj}/status"),
            get(r::get_status).put(r::put_status).patch(r::patch_status),
        )
        .route("/metrics", get(metrics))
        .route("/healthz", get(|| async { "ok" }))
        .fallback(|| async {
            ApiError::NotFound("the server could not find the requested resource".into())
        })
        .layer(DefaultBodyLimit::max(MAX_BODY_BYTES))
        .layer(middleware::from_fn(limits::bounded_body))
        .layer(middleware::from_fn_with_state(state.clone(), observe))
        .with_state(state)
}

async fn metrics(State(s): State<AppState>) -> Response {
    (
        [(header::CONTENT_TYPE, "text/plain; version=0.0.4")],
        s.metrics.render(),
    )
        .into_response()
}

async fn observe(State(s): State<AppState>, req: Request, next: Next) -> Response {
    let verb = req.method().as_str().to_string();
    let resp = next.run(req).await;
    s.metrics
        .api_requests
        .with_label_values(&[verb.as_str(), resp.status().as_str()])
        .inc();
    resp
}

/// Require `Authorization: Bearer <token>` (TCP listeners).
pub fn with_token(router: Router, token: String) -> Router {
    let token = Arc::new(token);
    router.layer(middleware::from_fn(move |req: Request, next: Next| {
        let token = token.clone();
        async move {
            // Like Kubernetes' public-info-viewer: version and health need no token.
            if matches!(req.uri().path(), "/version" | "/healthz") {
                return next.run(req).await;
            }
            let given = req
                .headers()
                .get(header::AUTHORIZATION)
                .and_then(|v| v.to_str().ok())
                .and_then(|v| v.strip_prefix("Bearer "));
            if given.is_some_and(|g| constant_time_eq(g.as_bytes(), token.as_bytes())) {
                next.run(req).await
            } else {
                let body = status::status_body(
                    StatusCode::UNAUTHORIZED,
                    "Unauthorized",
                    "a bearer token is required",
                    serde_json::json!({}),
                );
                (StatusCode::UNAUTHORIZED, axum::Json(body)).into_response()
            }
        }
    }))
}

fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// Serve on a Unix socket readable and writable by the owner only.
pub async fn serve_unix(router: Router, path: &Path) -> std::io::Result<()> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir)?;
    }
    let _ = std::fs::remove_file(path);
    // Create the socket under a restrictive umask so it is never briefly world-accessible.
    let listener = {
        let _umask = UmaskGuard::set(0o177);
        tokio::net::UnixListener::bind(path)?
    };
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o600))?;
    limits::serve(listener, router).await
}

/// Serve HTTPS on TCP; every request needs the bearer token.
pub async fn serve_tcp(
    router: Router,
    listener: tokio::net::TcpListener,
    token: String,
    tls: &tls::TlsFiles,
) -> std::io::Result<()> {
    tls::serve(with_token(router, token), listener, tls).await
}

struct UmaskGuard(libc::mode_t);

impl UmaskGuard {
    #[allow(unsafe_code)]
    fn set(mask: libc::mode_t) -> UmaskGuard {
        // SAFETY: umask only swaps the process file-mode mask; it cannot fail.
        UmaskGuard(unsafe { libc::umask(mask) })
    }
}

impl Drop for UmaskGuard {
    #[allow(unsafe_code)]
    fn drop(&mut self) {
        // SAFETY: restores the mask saved in `set`.
        unsafe { libc::umask(self.0) };
    }
}
