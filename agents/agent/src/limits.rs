//! The agent API's limits on what clients may send: the control plane's,
//! from [`configbot_http::limits`] (body size and time, head and idle
//! timeouts, the connection loop), with a refused body answered in the
//! agent's own error format, `{"error": "..."}`, with 413, 400 or 408.

use axum::extract::Request;
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use configbot_http::limits::Refusal;
pub use configbot_http::limits::{MAX_BODY_BYTES, serve};
use serde_json::json;

/// A refused request body, as the agent answers it.
#[derive(Debug)]
struct Refused(Refusal);

impl From<Refusal> for Refused {
    fn from(r: Refusal) -> Self {
        Self(r)
    }
}

impl IntoResponse for Refused {
    fn into_response(self) -> Response {
        let code = self.0.status();
        (code, axum::Json(json!({ "error": self.0.into_message() }))).into_response()
    }
}

/// Middleware: [`configbot_http::limits::bounded_body`] with the agent's
/// error bodies.
pub async fn bounded_body(req: Request, next: Next) -> Response {
    configbot_http::limits::bounded_body::<Refused>(req, next).await
}

#[cfg(test)]
mod tests {
    use axum::http::StatusCode;
    use http_body_util::BodyExt;

    use super::*;

    #[tokio::test]
    async fn refusals_are_the_agents_error_bodies() {
        let r = Refused(Refusal::TooSlow(
            "request body not received within 30 s".into(),
        ));
        let resp = r.into_response();
        assert_eq!(resp.status(), StatusCode::REQUEST_TIMEOUT);
        let bytes = resp.into_body().collect().await.unwrap().to_bytes();
        assert_eq!(
            &bytes[..],
            br#"{"error":"request body not received within 30 s"}"#
        );
    }
}
