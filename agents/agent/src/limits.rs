//! The agent API's limits on what clients may send: the control plane's,
//! from [`configbot_http::limits`] (body size and time, head and idle
//! timeouts, the connection loop), with a refused body answered as
//! [`Refusal`] renders itself, the agent's `{"error": "..."}` with 413, 400
//! or 408.

use axum::extract::Request;
use axum::middleware::Next;
use axum::response::Response;
use configbot_http::limits::Refusal;
pub use configbot_http::limits::{MAX_BODY_BYTES, serve};

/// Middleware: [`configbot_http::limits::bounded_body`] with the agent's
/// error bodies.
pub async fn bounded_body(req: Request, next: Next) -> Response {
    configbot_http::limits::bounded_body::<Refusal>(req, next).await
}
