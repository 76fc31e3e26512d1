//! The one HTTP client transport: [`send`] makes one request over a fresh
//! HTTP/1 connection (hyper's low-level client) on a Unix socket or TCP and
//! returns the response with its body still streaming (watches, event
//! streams); [`fetch`] also reads the whole body; [`read_body`] reads one
//! under a size limit. A fresh connection per request means a call that
//! blocks (a measurement window) never holds up another.
//!
//! Errors say what went wrong, not where: every caller wraps them with its
//! endpoint, method and path, in its own words.

use std::path::PathBuf;
use std::time::Duration;

use http_body_util::{BodyExt, Full, Limited};
use hyper::body::{Bytes, Incoming};
use hyper::{Request, Response};
use hyper_util::rt::TokioIo;

/// Where a server listens.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Endpoint {
    /// A Unix socket's path.
    Unix(PathBuf),
    /// `host:port`.
    Tcp(String),
}

impl std::fmt::Display for Endpoint {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Unix(p) => write!(f, "unix:{}", p.display()),
            Self::Tcp(addr) => write!(f, "tcp:{addr}"),
        }
    }
}

/// How long an exchange may take and how much it may read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    /// How long connecting may take.
    pub connect_timeout: Duration,
    /// How long the whole exchange may take, from connecting to the response
    /// head ([`send`]) or to the end of the body ([`fetch`]); `None`: as long
    /// as the server takes (calls that block by design, streams).
    pub response_timeout: Option<Duration>,
    /// The largest response body [`fetch`] reads, in bytes.
    pub max_body: usize,
}

/// What went wrong in an exchange.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("cannot connect")]
    Connect(#[source] std::io::Error),
    #[error("connecting timed out after {} s", .0.as_secs_f64())]
    ConnectTimeout(Duration),
    #[error("no complete response within {} s", .0.as_secs_f64())]
    Timeout(Duration),
    #[error(transparent)]
    Http(#[from] hyper::Error),
    #[error("response body larger than {0} bytes")]
    TooLarge(usize),
}

impl Error {
    /// The IO error under a failed connect, write or read, if that is what
    /// failed (a refused connection, a reset).
    pub fn io(&self) -> Option<&std::io::Error> {
        let mut src: Option<&(dyn std::error::Error + 'static)> = match self {
            Self::Connect(e) => return Some(e),
            Self::Http(e) => std::error::Error::source(e),
            _ => None,
        };
        while let Some(s) = src {
            if let Some(io) = s.downcast_ref::<std::io::Error>() {
                return Some(io);
            }
            src = s.source();
        }
        None
    }
}

trait Io: tokio::io::AsyncRead + tokio::io::AsyncWrite + Send + Unpin + 'static {}
impl<T: tokio::io::AsyncRead + tokio::io::AsyncWrite + Send + Unpin + 'static> Io for T {}

async fn connect(endpoint: &Endpoint, timeout: Duration) -> Result<Box<dyn Io>, Error> {
    let fut = async {
        match endpoint {
            Endpoint::Unix(p) => tokio::net::UnixStream::connect(p)
                .await
                .map(|s| Box::new(s) as Box<dyn Io>),
            Endpoint::Tcp(addr) => tokio::net::TcpStream::connect(addr.as_str())
                .await
                .map(|s| Box::new(s) as Box<dyn Io>),
        }
    };
    match tokio::time::timeout(timeout, fut).await {
        Ok(r) => r.map_err(Error::Connect),
        Err(_) => Err(Error::ConnectTimeout(timeout)),
    }
}

async fn exchange(
    endpoint: &Endpoint,
    req: Request<Full<Bytes>>,
    limits: &Limits,
) -> Result<Response<Incoming>, Error> {
    let io = connect(endpoint, limits.connect_timeout).await?;
    let (mut sender, conn) = hyper::client::conn::http1::handshake(TokioIo::new(io)).await?;
    tokio::spawn(async move {
        let _ = conn.await;
    });
    Ok(sender.send_request(req).await?)
}

/// Within `limits.response_timeout`, if any.
async fn bounded<T>(
    limits: &Limits,
    fut: impl Future<Output = Result<T, Error>>,
) -> Result<T, Error> {
    match limits.response_timeout {
        None => fut.await,
        Some(t) => tokio::time::timeout(t, fut)
            .await
            .unwrap_or(Err(Error::Timeout(t))),
    }
}

/// Sends `req` on a fresh connection to `endpoint`; returns the response
/// (any status) with its body still streaming.
pub async fn send(
    endpoint: &Endpoint,
    req: Request<Full<Bytes>>,
    limits: &Limits,
) -> Result<Response<Incoming>, Error> {
    bounded(limits, exchange(endpoint, req, limits)).await
}

/// [`send`], then the whole body, at most `limits.max_body` bytes.
pub async fn fetch(
    endpoint: &Endpoint,
    req: Request<Full<Bytes>>,
    limits: &Limits,
) -> Result<Response<Bytes>, Error> {
    bounded(limits, async {
        let (parts, body) = exchange(endpoint, req, limits).await?.into_parts();
        let bytes = read_body(body, limits.max_body).await?;
        Ok(Response::from_parts(parts, bytes))
    })
    .await
}

/// Reads a whole response body of at most `max` bytes.
pub async fn read_body(body: Incoming, max: usize) -> Result<Bytes, Error> {
    match Limited::new(body, max).collect().await {
        Ok(c) => Ok(c.to_bytes()),
        Err(e) => match e.downcast::<hyper::Error>() {
            Ok(e) => Err(Error::Http(*e)),
            // The only other error `Limited` makes is its length limit.
            Err(_) => Err(Error::TooLarge(max)),
        },
    }
}

#[cfg(test)]
mod tests {
    use std::convert::Infallible;

    use hyper::service::service_fn;
    use hyper::{Method, StatusCode};
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    use super::*;

    const LIMITS: Limits = Limits {
        connect_timeout: Duration::from_secs(5),
        response_timeout: Some(Duration::from_secs(5)),
        max_body: 1024,
    };

    fn get(path: &str) -> Request<Full<Bytes>> {
        Request::builder()
            .method(Method::GET)
            .uri(path)
            .header(hyper::header::HOST, "test")
            .body(Full::new(Bytes::new()))
            .unwrap()
    }

    /// A server answering `GET /n` with `n` bytes and status 200, on
    /// Unix and TCP.
    async fn serve_sized(l: impl Listener) {
        loop {
            let io = l.accept_io().await;
            tokio::spawn(async move {
                let svc = service_fn(|req: Request<Incoming>| async move {
                    let n: usize = req.uri().path()[1..].parse().unwrap_or(0);
                    Ok::<_, Infallible>(Response::new(Full::new(Bytes::from(vec![b'x'; n]))))
                });
                let _ = hyper::server::conn::http1::Builder::new()
                    .serve_connection(TokioIo::new(io), svc)
                    .await;
            });
        }
    }

    trait Listener: Send + 'static {
        fn accept_io(&self) -> impl Future<Output = Box<dyn Io>> + Send;
    }
    impl Listener for tokio::net::TcpListener {
        async fn accept_io(&self) -> Box<dyn Io> {
            Box::new(self.accept().await.unwrap().0)
        }
    }
    impl Listener for tokio::net::UnixListener {
        async fn accept_io(&self) -> Box<dyn Io> {
            Box::new(self.accept().await.unwrap().0)
        }
    }

    #[tokio::test]
    async fn fetch_reads_bodies_up_to_the_limit_over_tcp_and_unix() {
        let tcp = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let tcp_ep = Endpoint::Tcp(tcp.local_addr().unwrap().to_string());
        let dir = std::env::temp_dir().join(format!("configbot-http-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let sock = dir.join("s.sock");
        let _ = std::fs::remove_file(&sock);
        let unix = tokio::net::UnixListener::bind(&sock).unwrap();
        let srv = [
            tokio::spawn(serve_sized(tcp)),
            tokio::spawn(serve_sized(unix)),
        ];
        for ep in [tcp_ep, Endpoint::Unix(sock.clone())] {
            let r = fetch(&ep, get("/1024"), &LIMITS).await.unwrap();
            assert_eq!((r.status(), r.body().len()), (StatusCode::OK, 1024), "{ep}");
            let err = fetch(&ep, get("/1025"), &LIMITS).await.unwrap_err();
            assert!(matches!(err, Error::TooLarge(1024)), "{ep}: {err}");
            assert_eq!(err.to_string(), "response body larger than 1024 bytes");
            // `send` leaves the body to the caller.
            let r = send(&ep, get("/5000"), &LIMITS).await.unwrap();
            let all = r.into_body().collect().await.unwrap().to_bytes();
            assert_eq!(all.len(), 5000);
        }
        srv.iter().for_each(|s| s.abort());
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[tokio::test]
    async fn a_refused_connection_is_a_connect_error_with_its_io_kind() {
        let l = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let ep = Endpoint::Tcp(l.local_addr().unwrap().to_string());
        drop(l);
        let err = fetch(&ep, get("/"), &LIMITS).await.unwrap_err();
        assert!(matches!(err, Error::Connect(_)), "{err}");
        assert_eq!(
            err.io().map(|e| e.kind()),
            Some(std::io::ErrorKind::ConnectionRefused)
        );
        let missing = Endpoint::Unix("/nonexistent/configbot.sock".into());
        let err = send(&missing, get("/"), &LIMITS).await.unwrap_err();
        assert!(matches!(err, Error::Connect(_)), "{err}");
    }

    #[tokio::test(start_paused = true)]
    async fn a_server_that_does_not_answer_times_out() {
        let l = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let ep = Endpoint::Tcp(l.local_addr().unwrap().to_string());
        // Accepts and reads, never answers.
        let srv = tokio::spawn(async move {
            let (mut s, _) = l.accept().await.unwrap();
            let mut buf = [0u8; 1024];
            while s.read(&mut buf).await.is_ok_and(|n| n > 0) {}
            let _ = s.shutdown().await;
        });
        let err = fetch(&ep, get("/"), &LIMITS).await.unwrap_err();
        assert!(matches!(err, Error::Timeout(_)), "{err}");
        assert_eq!(err.to_string(), "no complete response within 5 s");
        srv.abort();
    }

    #[tokio::test]
    async fn a_connection_closed_before_the_answer_is_an_http_error() {
        let l = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let ep = Endpoint::Tcp(l.local_addr().unwrap().to_string());
        let srv = tokio::spawn(async move {
            let (mut s, _) = l.accept().await.unwrap();
            let mut buf = [0u8; 16];
            let _ = s.read(&mut buf).await;
            let _ = s.write_all(b"HTTP/1.1 200 OK\r\nContent-Le").await;
        });
        let err = fetch(&ep, get("/"), &LIMITS).await.unwrap_err();
        assert!(matches!(err, Error::Http(_)), "{err}");
        srv.abort();
    }
}
