//! XML-RPC over HTTP: a hyper server that dispatches decoded calls (with
//! `system.multicall`) to a handler, and a minimal one-shot client used to
//! call node slave APIs (publisherUpdate, getPid, paramUpdate, ...).

use std::future::Future;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::Arc;
use std::time::Duration;

use http_body_util::{BodyExt, Full};
use hyper::body::Bytes;
use hyper::server::conn::http1;
use hyper::service::service_fn;
use hyper::{Request, Response as HttpResponse};
use hyper_util::rt::TokioIo;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

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

/// Serves XML-RPC on `listener` until the task is dropped/aborted.
pub async fn serve<H: Handler>(listener: TcpListener, handler: Arc<H>) {
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
                    let body = req.into_body().collect().await.map(|b| b.to_bytes());
                    let resp = match body {
                        Ok(b) => match xmlrpc::decode_call(&String::from_utf8_lossy(&b)) {
                            Ok(call) => dispatch(h, call).await,
                            Err(e) => Response::Fault {
                                code: -32700,
                                message: e.to_string(),
                            },
                        },
                        Err(e) => Response::Fault {
                            code: -32700,
                            message: format!("reading request body: {e}"),
                        },
                    };
                    let text = xmlrpc::encode_response(&resp);
                    HttpResponse::builder()
                        .header("Content-Type", "text/xml")
                        .body(Full::new(Bytes::from(text)))
                }
            });
            let _ = http1::Builder::new()
                .title_case_headers(true)
                .keep_alive(true)
                .serve_connection(TokioIo::new(stream), svc)
                .await;
        });
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

/// Calls `method` on the XML-RPC server at `uri` and returns its value.
pub async fn call(
    uri: &str,
    method: &str,
    params: &[Value],
    timeout: Duration,
) -> Result<Value, HttpError> {
    match tokio::time::timeout(timeout, call_inner(uri, method, params)).await {
        Ok(r) => r,
        Err(_) => Err(HttpError::Timeout {
            uri: uri.into(),
            method: method.into(),
        }),
    }
}

async fn call_inner(uri: &str, method: &str, params: &[Value]) -> Result<Value, HttpError> {
    let (host, port, path) = parse_uri(uri).ok_or_else(|| HttpError::BadUri(uri.into()))?;
    let io = |source| HttpError::Io {
        uri: uri.into(),
        method: method.into(),
        source,
    };
    let mut s = TcpStream::connect((host.as_str(), port))
        .await
        .map_err(io)?;
    let body = xmlrpc::encode_call(method, params);
    let req = format!(
        "POST {path} HTTP/1.1\r\nHost: {host}:{port}\r\nUser-Agent: configbot\r\nContent-Type: text/xml\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    );
    s.write_all(req.as_bytes()).await.map_err(io)?;
    let mut buf = Vec::new();
    s.read_to_end(&mut buf).await.map_err(io)?;
    let bad = || HttpError::BadHttp {
        uri: uri.into(),
        method: method.into(),
    };
    let split = buf
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .ok_or_else(bad)?;
    let head = String::from_utf8_lossy(&buf[..split]);
    if head.split_whitespace().nth(1).is_none_or(|c| c != "200") {
        return Err(bad());
    }
    let text = String::from_utf8_lossy(&buf[split + 4..]);
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
}
