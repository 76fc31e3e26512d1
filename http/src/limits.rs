//! What clients may send the agent's and the control plane's HTTP APIs, in
//! one place, and the two pieces that enforce it: [`bounded_body`] (size and
//! time of a request body; a refusal is answered 413, 400 or 408 in the
//! server's own error format) and [`serve`] (the HTTP/1.1 connection loop,
//! which closes connections whose request head is too slow or which idle
//! too long). JSON nesting is bounded by `serde_json`'s own recursion limit
//! (128): a deeper body is a 400 from the extractor, never a stack overflow.

use std::time::Duration;

use axum::Router;
use axum::body::Body;
use axum::extract::Request;
use axum::http::{StatusCode, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;

/// Largest request body, in bytes: a RobotStack manifest or a config is a
/// few KiB; Kubernetes' limit on an object is 3 MiB.
pub const MAX_BODY_BYTES: usize = 3 * 1024 * 1024;

/// How long a client may take to send a request's head (or, over TLS, to
/// finish the handshake), and how long a kept-alive connection may idle
/// before it is closed.
pub const HEADER_TIMEOUT: Duration = Duration::from_secs(30);

/// How long a client may take to send a request's body.
pub const BODY_TIMEOUT: Duration = Duration::from_secs(30);

/// Why [`bounded_body`] refused a request body. A server answers it in its
/// own error format (`From<Refusal>`, with [`Refusal::status`]) or as it is:
/// `{"error": "<message>"}`, the agent's format.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Refusal {
    /// Over [`MAX_BODY_BYTES`], declared or found while reading: 413.
    TooLarge(String),
    /// The body could not be read: 400.
    Unreadable(String),
    /// Not received within [`BODY_TIMEOUT`]: 408.
    TooSlow(String),
}

impl Refusal {
    /// The status a refusal is answered with.
    pub fn status(&self) -> StatusCode {
        match self {
            Self::TooLarge(_) => StatusCode::PAYLOAD_TOO_LARGE,
            Self::Unreadable(_) => StatusCode::BAD_REQUEST,
            Self::TooSlow(_) => StatusCode::REQUEST_TIMEOUT,
        }
    }

    /// The message for the client.
    pub fn into_message(self) -> String {
        match self {
            Self::TooLarge(m) | Self::Unreadable(m) | Self::TooSlow(m) => m,
        }
    }
}

impl IntoResponse for Refusal {
    fn into_response(self) -> Response {
        let code = self.status();
        let body = serde_json::json!({ "error": self.into_message() });
        (code, axum::Json(body)).into_response()
    }
}

/// Middleware: reads the whole request body within [`BODY_TIMEOUT`] and
/// [`MAX_BODY_BYTES`] before the handler runs; a refusal is answered with
/// `E` (the server's error type) and closes the connection, whose body is
/// left unread. A declared length over the limit is refused before anything
/// is read.
pub async fn bounded_body<E: From<Refusal> + IntoResponse>(req: Request, next: Next) -> Response {
    match read_bounded(req).await {
        Ok(req) => next.run(req).await,
        Err(refusal) => {
            let mut r = E::from(refusal).into_response();
            r.headers_mut().insert(
                header::CONNECTION,
                header::HeaderValue::from_static("close"),
            );
            r
        }
    }
}

/// The request with its body read, or why not.
async fn read_bounded(req: Request) -> Result<Request, Refusal> {
    let declared = req
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok());
    let too_large = |size: String| {
        Refusal::TooLarge(format!(
            "request body{size} is larger than the {MAX_BODY_BYTES} byte limit"
        ))
    };
    if let Some(n) = declared.filter(|&n| n > MAX_BODY_BYTES as u64) {
        return Err(too_large(format!(" ({n} bytes)")));
    }
    let (parts, body) = req.into_parts();
    let read = tokio::time::timeout(BODY_TIMEOUT, axum::body::to_bytes(body, MAX_BODY_BYTES));
    match read.await {
        Ok(Ok(b)) => Ok(Request::from_parts(parts, Body::from(b))),
        Ok(Err(e)) if is_length_limit(&e) => Err(too_large(String::new())),
        Ok(Err(e)) => Err(Refusal::Unreadable(format!("reading request body: {e}"))),
        Err(_) => Err(Refusal::TooSlow(format!(
            "request body not received within {} s",
            BODY_TIMEOUT.as_secs()
        ))),
    }
}

fn is_length_limit(e: &axum::Error) -> bool {
    let mut src: Option<&(dyn std::error::Error + 'static)> = Some(e);
    while let Some(s) = src {
        if s.is::<http_body_util::LengthLimitError>() {
            return true;
        }
        src = s.source();
    }
    false
}

/// Serves `router` on `listener` (TCP or Unix) over HTTP/1.1 until the task
/// is dropped: a connection whose request head takes longer than
/// [`HEADER_TIMEOUT`], or that idles that long between requests, is closed.
pub async fn serve<L>(mut listener: L, router: Router) -> std::io::Result<()>
where
    L: axum::serve::Listener,
{
    loop {
        let (io, _) = listener.accept().await;
        let svc = TowerToHyperService::new(router.clone());
        tokio::spawn(async move {
            let _ = hyper::server::conn::http1::Builder::new()
                .timer(TokioTimer::new())
                .header_read_timeout(HEADER_TIMEOUT)
                .serve_connection(TokioIo::new(io), svc)
                .with_upgrades()
                .await;
        });
    }
}

#[cfg(test)]
mod tests {
    use axum::routing::post;
    use http_body_util::BodyExt;
    use tokio::io::AsyncReadExt;
    use tower::ServiceExt;

    use super::*;

    /// A route that echoes its body's length behind [`bounded_body`], with
    /// the extractors' limit raised to the same size as in the API routers.
    fn app() -> Router {
        Router::new()
            .route(
                "/",
                post(|b: axum::body::Bytes| async move { b.len().to_string() }),
            )
            .layer(axum::extract::DefaultBodyLimit::max(MAX_BODY_BYTES))
            .layer(axum::middleware::from_fn(bounded_body::<Refusal>))
    }

    async fn send(body: Body, length: Option<u64>) -> (StatusCode, String, bool) {
        let mut req = Request::post("/");
        if let Some(n) = length {
            req = req.header(header::CONTENT_LENGTH, n);
        }
        let resp = app().oneshot(req.body(body).unwrap()).await.unwrap();
        let code = resp.status();
        let close = resp
            .headers()
            .get(header::CONNECTION)
            .is_some_and(|v| v == "close");
        let bytes = resp.into_body().collect().await.unwrap().to_bytes();
        (code, String::from_utf8_lossy(&bytes).into_owned(), close)
    }

    #[tokio::test]
    async fn bodies_within_the_limit_pass_and_larger_ones_are_413() {
        let (code, body, close) = send(Body::from(vec![b'x'; MAX_BODY_BYTES]), None).await;
        assert_eq!(
            (code, body, close),
            (StatusCode::OK, MAX_BODY_BYTES.to_string(), false)
        );
        let (code, body, close) = send(Body::empty(), Some(MAX_BODY_BYTES as u64 + 1)).await;
        assert_eq!((code, close), (StatusCode::PAYLOAD_TOO_LARGE, true));
        assert_eq!(
            body,
            r#"{"error":"request body (3145729 bytes) is larger than the 3145728 byte limit"}"#
        );
        // No length: found while reading.
        let chunks = futures_util::stream::iter(
            (0..4).map(|_| Ok::<_, std::io::Error>(vec![b'x'; 1 << 20])),
        );
        let (code, body, _) = send(Body::from_stream(chunks), None).await;
        assert_eq!(code, StatusCode::PAYLOAD_TOO_LARGE, "{body}");
        assert_eq!(
            body,
            r#"{"error":"request body is larger than the 3145728 byte limit"}"#
        );
    }

    #[tokio::test]
    async fn a_body_that_breaks_off_is_400() {
        let broken = futures_util::stream::iter([
            Ok(vec![b'x'; 10]),
            Err(std::io::Error::other("peer went away")),
        ]);
        let (code, body, close) = send(Body::from_stream(broken), None).await;
        assert_eq!((code, close), (StatusCode::BAD_REQUEST, true), "{body}");
        assert!(
            body.starts_with(r#"{"error":"reading request body: "#),
            "{body}"
        );
    }

    #[tokio::test(start_paused = true)]
    async fn a_body_that_stops_arriving_is_408() {
        let stalled = futures_util::stream::pending::<Result<Vec<u8>, std::io::Error>>();
        let (code, body, close) = send(Body::from_stream(stalled), None).await;
        assert_eq!((code, close), (StatusCode::REQUEST_TIMEOUT, true));
        assert_eq!(body, r#"{"error":"request body not received within 30 s"}"#);
    }

    #[tokio::test(start_paused = true)]
    async fn idle_connections_are_closed_after_the_header_timeout() {
        let l = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = l.local_addr().unwrap();
        let srv = tokio::spawn(serve(l, app()));
        let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
        let start = tokio::time::Instant::now();
        let mut out = Vec::new();
        s.read_to_end(&mut out).await.unwrap();
        assert!(out.is_empty());
        assert!(start.elapsed() >= HEADER_TIMEOUT, "{:?}", start.elapsed());
        srv.abort();
    }
}
