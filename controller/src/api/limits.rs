//! The control-plane API's limits on what clients may send: the agent's,
//! from [`configbot_http::limits`] (body size and time, head and idle
//! timeouts, the HTTP/1.1 connection loop of the Unix socket; the TLS
//! listener in `tls.rs` uses the same timeouts), with a refused body
//! answered as a Kubernetes `Status` (413, 400 or 408). YAML nesting is
//! bounded by the manifest loader's (`configbot_manifests::yaml`): a deeper
//! body is a 400, never a stack overflow.

use axum::extract::Request;
use axum::middleware::Next;
use axum::response::Response;
use configbot_http::limits::Refusal;
pub use configbot_http::limits::{HEADER_TIMEOUT, MAX_BODY_BYTES, serve};

use super::status::ApiError;

impl From<Refusal> for ApiError {
    fn from(r: Refusal) -> Self {
        match r {
            Refusal::TooLarge(m) => ApiError::PayloadTooLarge(m),
            Refusal::Unreadable(m) => ApiError::BadRequest(m),
            Refusal::TooSlow(m) => ApiError::RequestTimeout(m),
        }
    }
}

/// Middleware: [`configbot_http::limits::bounded_body`] answering with a
/// Kubernetes `Status`.
pub async fn bounded_body(req: Request, next: Next) -> Response {
    configbot_http::limits::bounded_body::<ApiError>(req, next).await
}

#[cfg(test)]
mod tests {
    use axum::http::StatusCode;
    use axum::response::IntoResponse;
    use http_body_util::BodyExt;

    use super::*;

    #[tokio::test]
    async fn refusals_are_kubernetes_statuses_with_their_codes() {
        let cases = [
            (
                Refusal::TooLarge("big".into()),
                StatusCode::PAYLOAD_TOO_LARGE,
            ),
            (
                Refusal::Unreadable("broken".into()),
                StatusCode::BAD_REQUEST,
            ),
            (Refusal::TooSlow("slow".into()), StatusCode::REQUEST_TIMEOUT),
        ];
        for (refusal, code) in cases {
            assert_eq!(refusal.status(), code);
            let resp = ApiError::from(refusal).into_response();
            assert_eq!(resp.status(), code);
        }
        let resp = ApiError::from(Refusal::TooSlow(
            "request body not received within 30 s".into(),
        ))
        .into_response();
        let bytes = resp.into_body().collect().await.unwrap().to_bytes();
        let body = String::from_utf8_lossy(&bytes);
        assert!(body.contains("not received within 30 s"), "{body}");
        assert!(body.contains(r#""reason":"Timeout""#), "{body}");
    }
}
