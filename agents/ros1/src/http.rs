//! XML-RPC over HTTP: a hyper server that dispatches decoded calls (with
//! `system.multicall`) to a handler, and a one-shot client, on the
//! workspace's one transport (`configbot_http::client`), used to call node
//! slave APIs (publisherUpdate, getPid, paramUpdate, ...).
//! Both sides are bounded by [`crate::limits`]: body size, nesting depth
//! (in the codec), and how long a client may take to send a request or idle.

use std::future::Future;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::Arc;
use std::time::Duration;

use configbot_http::client;
use http_body_util::{BodyExt, Full};
use hyper::body::Bytes;
use hyper::server::conn::http1;
use hyper::service::service_fn;
use hyper::{Request, Response as HttpResponse};
use hyper_util::rt::{TokioIo, TokioTimer};
use tokio::net::TcpListener;

use crate::limits::{MAX_XMLRPC_BODY, ServeLimits};
use crate::xmlrpc::{self, MethodCall, Response, Value, XmlRpcError};

/// Errors of XML-RPC client calls.
#[derive(Debug, thiserror::Error)]
pub enum HttpError {
    #[error("bad uri {0}")]
    BadUri(String),
    #[error("xml-rpc call {method} to {uri} failed")]
    Io {
        uri: String,
        method: String,
        #[source]
        source: std::io::Error,
    },
    #[error("xml-rpc call {method} to {uri} timed out")]
    Timeout { uri: String, method: String },
    #[error("xml-rpc call {method} to {uri}: bad response")]
    Decode {
        uri: String,
        method: String,
        #[source]
        source: XmlRpcError,
    },
    #[error("xml-rpc call {method} to {uri}: fault {code}: {message}")]
    Fault {
        uri: String,
        method: String,
        code: i64,
        message: String,
    },
    #[error("xml-rpc call {method} to {uri}: malformed http response")]
    BadHttp { uri: String, method: String },
    #[error("xml-rpc call {method} to {uri}: response larger than {limit} bytes")]
    TooLarge {
        uri: String,
        method: String,
        limit: usize,
    },
}

/// A boxed future, for handler trait objects.
pub type BoxFut<T> = Pin<Box<dyn Future<Output = T> + Send>>;

/// Something that answers XML-RPC calls.
pub trait Handler: Send + Sync + 'static {
    /// Answers one call (never `system.multicall`, which the server unpacks).
    fn handle(self: Arc<Self>, call: MethodCall) -> BoxFut<Response>;
}

async fn dispatch<H: Handler>(h: Arc<H>, call: MethodCall) -> Response {
    if call.method != "system.multicall" {
        return h.handle(call).await;
    }
    let Some(Value::Array(calls)) = call.params.into_iter().next() else {
        return Response::Fault {
            code: -32600,
            message: "system.multicall expects an array".into(),
        };
    };
    let mut out = Vec::with_capacity(calls.len());
    for c in calls {
        let (method, params) = match c {
            Value::Struct(mut m) => (
                m.remove("methodName")
                    .and_then(|v| v.as_str().map(String::from)),
                m.remove("params"),
            ),
            _ => (None, None),
        };
        let r = match (method, params) {
            (Some(method), Some(Value::Array(params))) if method != "system.multicall" => {
                h.clone().handle(MethodCall { method, params }).await
            }
            _ => Response::Fault {
                code: -32600,
                message: "bad multicall entry".into(),
            },
        };
        out.push(match r {
            Response::Ok(v) => Value::Array(vec![v]),
            Response::Fault { code, message } => {
                let mut m = std::collections::BTreeMap::new();
                m.insert("faultCode".to_string(), Value::Int(code));
                m.insert("faultString".to_string(), Value::Str(message));
                Value::Struct(m)
            }
        });
    }
    Response::Ok(Value::Array(out))
}

/// Serves XML-RPC on `listener` until the task is dropped/aborted, with the
/// default [`ServeLimits`].
pub async fn serve<H: Handler>(listener: TcpListener, handler: Arc<H>) {
    serve_with(listener, handler, ServeLimits::default()).await;
}

/// Serves XML-RPC on `listener` until the task is dropped/aborted. A request
/// over `limits` is answered with fault −32700 and its connection closed; a
/// client that sends its head or body too slowly, or idles longer than the
/// header timeout between requests, is disconnected.
pub async fn serve_with<H: Handler>(listener: TcpListener, handler: Arc<H>, limits: ServeLimits) {
    loop {
        let Ok((stream, _)) = listener.accept().await else {
            tokio::time::sleep(Duration::from_millis(50)).await;
            continue;
        };
        let _ = stream.set_nodelay(true);
        let h = handler.clone();
        tokio::spawn(async move {
            let svc = service_fn(move |req: Request<hyper::body::Incoming>| {
                let h = h.clone();
                async move {
                    let (resp, keep) = match read_body(req, &limits).await {
                        Ok(b) => match xmlrpc::decode_call(&String::from_utf8_lossy(&b)) {
                            Ok(call) => (dispatch(h, call).await, true),
                            Err(e) => (parse_fault(e.to_string()), true),
                        },
                        // The rest of the body is unread: the connection cannot go on.
                        Err(message) => (parse_fault(message), false),
                    };
                    let text = xmlrpc::encode_response(&resp);
                    let mut b = HttpResponse::builder().header("Content-Type", "text/xml");
                    if !keep {
                        b = b.header("Connection", "close");
                    }
                    b.body(Full::new(Bytes::from(text)))
                }
            });
            let _ = http1::Builder::new()
                .timer(TokioTimer::new())
                .header_read_timeout(limits.header_timeout)
                .title_case_headers(true)
                .keep_alive(true)
                .serve_connection(TokioIo::new(stream), svc)
                .await;
        });
    }
}

fn parse_fault(message: String) -> Response {
    Response::Fault {
        code: -32700,
        message,
    }
}

/// The request body, or why it was refused: larger than the limit (told by
/// Content-Length before reading, or found while reading), too slow, broken.
async fn read_body(
    req: Request<hyper::body::Incoming>,
    limits: &ServeLimits,
) -> Result<Bytes, String> {
    let over = |n: Option<u64>| {
        let size = n.map(|n| format!(" ({n} bytes)")).unwrap_or_default();
        format!(
            "request body{size} is larger than the {} byte limit",
            limits.max_body
        )
    };
    let declared = req
        .headers()
        .get(hyper::header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok());
    if let Some(n) = declared.filter(|&n| n > limits.max_body as u64) {
        return Err(over(Some(n)));
    }
    let body = http_body_util::Limited::new(req.into_body(), limits.max_body);
    match tokio::time::timeout(limits.body_timeout, body.collect()).await {
        Ok(Ok(c)) => Ok(c.to_bytes()),
        Ok(Err(e)) if e.is::<http_body_util::LengthLimitError>() => Err(over(None)),
        Ok(Err(e)) => Err(format!("reading request body: {e}")),
        Err(_) => Err(format!(
            "request body not received within {} s",
            limits.body_timeout.as_secs_f64()
        )),
    }
}

/// `http://host:port/path` → (host, port, path).
pub fn parse_uri(uri: &str) -> Option<(String, u16, String)> {
    let rest = uri.strip_prefix("http://")?;
    let (hostport, path) = match rest.find('/') {
        Some(i) => (&rest[..i], &rest[i..]),
        None => (rest, "/"),
    };
    let (host, port) = match hostport.rfind(':') {
        Some(i) => (&hostport[..i], hostport[i + 1..].parse().ok()?),
        None => (hostport, 80),
    };
    Some((host.to_string(), port, path.to_string()))
}

/// Calls `method` on the XML-RPC server at `uri` and returns its value;
/// the whole call (connect, request, response) takes at most `timeout`.
pub async fn call(
    uri: &str,
    method: &str,
    params: &[Value],
    timeout: Duration,
) -> Result<Value, HttpError> {
    let (host, port, path) = parse_uri(uri).ok_or_else(|| HttpError::BadUri(uri.into()))?;
    let bad = || HttpError::BadHttp {
        uri: uri.into(),
        method: method.into(),
    };
    let req = Request::post(path)
        .header(hyper::header::HOST, format!("{host}:{port}"))
        .header(hyper::header::USER_AGENT, "configbot")
        .header(hyper::header::CONTENT_TYPE, "text/xml")
        .header(hyper::header::CONNECTION, "close")
        .body(Full::new(Bytes::from(xmlrpc::encode_call(method, params))))
        .map_err(|_| bad())?;
    let limits = client::Limits {
        connect_timeout: timeout,
        response_timeout: Some(timeout),
        max_body: MAX_XMLRPC_BODY,
    };
    let endpoint = client::Endpoint::Tcp(format!("{host}:{port}"));
    let resp = client::fetch(&endpoint, req, &limits)
        .await
        .map_err(|e| match e {
            client::Error::ConnectTimeout(_) | client::Error::Timeout(_) => HttpError::Timeout {
                uri: uri.into(),
                method: method.into(),
            },
            client::Error::TooLarge(limit) => HttpError::TooLarge {
                uri: uri.into(),
                method: method.into(),
                limit,
            },
            client::Error::Connect(source) => HttpError::Io {
                uri: uri.into(),
                method: method.into(),
                source,
            },
            // A write or read that failed under hyper: its IO kind is kept.
            e => match e.io() {
                Some(io) => HttpError::Io {
                    uri: uri.into(),
                    method: method.into(),
                    source: std::io::Error::new(io.kind(), e),
                },
                // Not HTTP, or cut short.
                None => bad(),
            },
        })?;
    if resp.status() != hyper::StatusCode::OK {
        return Err(bad());
    }
    let text = String::from_utf8_lossy(resp.body());
    match xmlrpc::decode_response(&text) {
        Ok(Response::Ok(v)) => Ok(v),
        Ok(Response::Fault { code, message }) => Err(HttpError::Fault {
            uri: uri.into(),
            method: method.into(),
            code,
            message,
        }),
        Err(source) => Err(HttpError::Decode {
            uri: uri.into(),
            method: method.into(),
            source,
        }),
    }
}

/// Binds a listener on `host:port` (port 0 = any).
pub async fn bind(host: &str, port: u16) -> std::io::Result<(TcpListener, SocketAddr)> {
    let l = TcpListener::bind((host, port)).await?;
    let a = l.local_addr()?;
    Ok((l, a))
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Echo;
    impl Handler for Echo {
        fn handle(self: Arc<Self>, call: MethodCall) -> BoxFut<Response> {
            Box::pin(async move {
                if call.method == "fail" {
                    Response::Fault {
                        code: 7,
                        message: "no".into(),
                    }
                } else {
                    Response::Ok(Value::Array(call.params))
                }
            })
        }
    }

    #[test]
    fn parses_uris() {
        assert_eq!(
            parse_uri("http://localhost:11311/"),
            Some(("localhost".into(), 11311, "/".into()))
        );
        assert_eq!(parse_uri("http://h:1"), Some(("h".into(), 1, "/".into())));
        assert_eq!(parse_uri("rosrpc://h:1"), None);
    }

    #[tokio::test]
    async fn client_and_server_talk_including_multicall_and_faults() {
        let (l, addr) = bind("127.0.0.1", 0).await.unwrap();
        let srv = tokio::spawn(serve(l, Arc::new(Echo)));
        let uri = format!("http://127.0.0.1:{}/", addr.port());
        let t = Duration::from_secs(5);
        let v = call(&uri, "x", &[Value::Int(1), Value::str("a")], t)
            .await
            .unwrap();
        assert_eq!(v, Value::Array(vec![Value::Int(1), Value::str("a")]));
        let err = call(&uri, "fail", &[], t).await.unwrap_err();
        assert!(matches!(err, HttpError::Fault { code: 7, .. }), "{err}");
        let entry = |m: &str| {
            let mut s = std::collections::BTreeMap::new();
            s.insert("methodName".to_string(), Value::str(m));
            s.insert("params".to_string(), Value::Array(vec![Value::Int(2)]));
            Value::Struct(s)
        };
        let v = call(
            &uri,
            "system.multicall",
            &[Value::Array(vec![entry("x"), entry("fail")])],
            t,
        )
        .await
        .unwrap();
        let a = v.as_array().unwrap();
        assert_eq!(a[0], Value::Array(vec![Value::Array(vec![Value::Int(2)])]));
        assert!(matches!(&a[1], Value::Struct(m) if m.contains_key("faultCode")));
        srv.abort();
    }

    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    use tokio::net::TcpStream;

    /// A server with `limits` and the client address it listens on.
    async fn limited(limits: ServeLimits) -> (tokio::task::JoinHandle<()>, SocketAddr, String) {
        let (l, addr) = bind("127.0.0.1", 0).await.unwrap();
        let srv = tokio::spawn(serve_with(l, Arc::new(Echo), limits));
        (srv, addr, format!("http://127.0.0.1:{}/", addr.port()))
    }

    /// Writes `req` and reads until the server closes, within 10 s.
    async fn exchange(addr: SocketAddr, req: &[u8]) -> String {
        let mut s = TcpStream::connect(addr).await.unwrap();
        s.write_all(req).await.unwrap();
        let mut out = Vec::new();
        tokio::time::timeout(Duration::from_secs(10), s.read_to_end(&mut out))
            .await
            .expect("the server neither answered nor closed within 10 s")
            .unwrap();
        String::from_utf8_lossy(&out).into_owned()
    }

    const SMALL: ServeLimits = ServeLimits {
        max_body: 1024,
        header_timeout: Duration::from_millis(300),
        body_timeout: Duration::from_millis(300),
    };

    #[tokio::test]
    async fn bodies_over_the_limit_are_faults_and_the_server_goes_on() {
        let (srv, addr, uri) = limited(SMALL).await;
        // Declared too large: refused before the body is read.
        let r = exchange(
            addr,
            b"POST / HTTP/1.1\r\nHost: x\r\nContent-Length: 2000\r\n\r\n",
        )
        .await;
        assert!(r.contains("<i4>-32700</i4>"), "{r}");
        assert!(
            r.contains("(2000 bytes) is larger than the 1024 byte limit"),
            "{r}"
        );
        // Chunked, no length: refused once 1024 bytes have arrived.
        let chunk = "a".repeat(2000);
        let req = format!(
            "POST / HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\nConnection: close\r\n\r\n7d0\r\n{chunk}\r\n0\r\n\r\n"
        );
        let r = exchange(addr, req.as_bytes()).await;
        assert!(
            r.contains("request body is larger than the 1024 byte limit"),
            "{r}"
        );
        let v = call(&uri, "x", &[Value::Int(3)], Duration::from_secs(5))
            .await
            .unwrap();
        assert_eq!(v, Value::Array(vec![Value::Int(3)]));
        srv.abort();
    }

    #[tokio::test]
    async fn deep_nesting_is_a_fault() {
        let (srv, _, uri) = limited(ServeLimits::default()).await;
        let mut v = Value::Int(1);
        for _ in 0..200 {
            v = Value::Array(vec![v]);
        }
        let err = call(&uri, "x", &[v], Duration::from_secs(5))
            .await
            .unwrap_err();
        assert!(
            matches!(&err, HttpError::Fault { code: -32700, message, .. } if message.contains("nested deeper than 128")),
            "{err}"
        );
        srv.abort();
    }

    #[tokio::test]
    async fn slow_and_idle_clients_are_disconnected() {
        let (srv, addr, uri) = limited(SMALL).await;
        // Idle: connected, nothing sent; closed after the header timeout.
        assert_eq!(exchange(addr, b"").await, "");
        // Half a head, then silence.
        assert_eq!(exchange(addr, b"POST / HTTP/1.1\r\nHost:").await, "");
        // A body that stops arriving: a fault once the body timeout passes.
        let r = exchange(
            addr,
            b"POST / HTTP/1.1\r\nHost: x\r\nContent-Length: 100\r\n\r\n<methodCall>",
        )
        .await;
        assert!(r.contains("request body not received within 0.3 s"), "{r}");
        let v = call(&uri, "x", &[], Duration::from_secs(5)).await.unwrap();
        assert_eq!(v, Value::Array(vec![]));
        srv.abort();
    }
}
