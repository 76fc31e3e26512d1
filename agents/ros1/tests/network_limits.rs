//! The data plane's listeners under hostile input: a 200 000-level XML
//! nesting bomb and a streamed 100 MB body to the master's and the adaptor's
//! XML-RPC servers, and the same to the adaptor's TCPROS port as a connection
//! header. Each is answered with an error (an XML-RPC fault, a TCPROS error
//! header), and the next ordinary request is served. Needs no ROS install.

use std::time::Duration;

use configbot_ros1::http;
use configbot_ros1::limits::{MAX_PARAM_DEPTH, MAX_TCPROS_HEADER, MAX_XMLRPC_BODY};
use configbot_ros1::tcpros::{self, Header};
use configbot_ros1::xmlrpc::Value;
use configbot_ros1::{Ros1Config, Ros1DataPlane};
use configbot_test_support::free_port;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::net::TcpStream;

const TIMEOUT: Duration = Duration::from_secs(30);
const HUNDRED_MB: usize = 100 << 20;
const BOMB_DEPTH: usize = 200_000;

struct Fixture {
    dp: Ros1DataPlane,
    tcpros_port: u16,
    _dir: tempfile::TempDir,
}

async fn start() -> Fixture {
    let dir = tempfile::tempdir().unwrap();
    let tcpros_port = free_port();
    let cfg = Ros1Config {
        master_uri: format!("http://127.0.0.1:{}/", free_port()),
        bind_host: "127.0.0.1".into(),
        advertise_host: "127.0.0.1".into(),
        adaptor_tcpros_port: tcpros_port,
        refresh_period: Duration::from_secs(60),
        ..Ros1Config::default()
    };
    let dp = Ros1DataPlane::start(
        cfg,
        &dir.path().join("ros1.db"),
        &prometheus::Registry::new(),
    )
    .await
    .unwrap();
    Fixture {
        dp,
        tcpros_port,
        _dir: dir,
    }
}

/// A methodCall whose one parameter is `depth` nested arrays.
fn nesting_bomb(depth: usize) -> Vec<u8> {
    let mut s = String::from(
        "<?xml version=\"1.0\"?><methodCall><methodName>getSystemState</methodName><params><param>",
    );
    s.push_str(&"<value><array><data>".repeat(depth));
    s.push_str(&"</data></array></value>".repeat(depth));
    s.push_str("</param></params></methodCall>");
    s.into_bytes()
}

/// Writes `total` bytes of `fill`, framed by `frame` (chunk size → chunk
/// bytes), 64 KiB at a time from one buffer. Stops at the first write error
/// (the peer closed): that is the expected end for a refused body.
async fn stream<W: AsyncWrite + Unpin>(
    w: &mut W,
    total: usize,
    frame: impl Fn(usize) -> (Vec<u8>, Vec<u8>),
) -> std::io::Result<()> {
    let buf = vec![b' '; 64 << 10];
    let mut left = total;
    while left > 0 {
        let n = left.min(buf.len());
        let (pre, post) = frame(n);
        w.write_all(&pre).await?;
        w.write_all(&buf[..n]).await?;
        w.write_all(&post).await?;
        left -= n;
    }
    Ok(())
}

/// Everything the peer sends until it closes (a reset after data counts as
/// a close), within [`TIMEOUT`].
async fn read_all<R: AsyncRead + Unpin>(r: &mut R) -> Vec<u8> {
    let mut out = Vec::new();
    let mut buf = [0u8; 8192];
    let read = async {
        loop {
            match r.read(&mut buf).await {
                Ok(0) | Err(_) => break,
                Ok(n) => out.extend_from_slice(&buf[..n]),
            }
        }
    };
    tokio::time::timeout(TIMEOUT, read)
        .await
        .expect("the server neither answered nor closed");
    out
}

/// Sends `head` then streams `body_len` bytes (chunked when `chunked`) while
/// reading the answer; returns the answer. The writer must end: the server
/// either read everything or closed the connection.
async fn post_streamed(addr: &str, head: String, body_len: usize, chunked: bool) -> String {
    let s = TcpStream::connect(addr).await.unwrap();
    let (mut r, mut w) = s.into_split();
    let writer = tokio::spawn(async move {
        w.write_all(head.as_bytes()).await?;
        if chunked {
            stream(&mut w, body_len, |n| {
                (format!("{n:x}\r\n").into_bytes(), b"\r\n".to_vec())
            })
            .await?;
            w.write_all(b"0\r\n\r\n").await
        } else {
            stream(&mut w, body_len, |_| (Vec::new(), Vec::new())).await
        }
    });
    let answer = read_all(&mut r).await;
    tokio::time::timeout(TIMEOUT, writer)
        .await
        .expect("the server kept reading a refused body")
        .unwrap()
        .ok();
    String::from_utf8_lossy(&answer).into_owned()
}

fn host_port(uri: &str) -> String {
    let (host, port, _) = http::parse_uri(uri).unwrap();
    format!("{host}:{port}")
}

/// The master answers an ordinary call normally.
async fn assert_serves(master: &str) {
    let v = http::call(
        master,
        "getSystemState",
        &[Value::str("/probe")],
        Duration::from_secs(5),
    )
    .await
    .unwrap();
    assert_eq!(v.as_array().unwrap()[0], Value::Int(1), "{v:?}");
}

#[tokio::test]
async fn xmlrpc_servers_refuse_nesting_bombs_and_100_mb_bodies_and_go_on() {
    let f = start().await;
    let master = f.dp.master_uri().to_string();
    for uri in [master.as_str(), f.dp.adaptor_uri()] {
        let addr = host_port(uri);
        let bomb = nesting_bomb(BOMB_DEPTH);
        let head = format!(
            "POST / HTTP/1.1\r\nHost: {addr}\r\nContent-Type: text/xml\r\nContent-Length: {}\r\n\r\n",
            bomb.len()
        );
        let mut s = TcpStream::connect(&addr).await.unwrap();
        s.write_all(head.as_bytes()).await.unwrap();
        s.write_all(&bomb).await.unwrap();
        drop(bomb);
        let mut resp = vec![0u8; 4096];
        let n = tokio::time::timeout(TIMEOUT, s.read(&mut resp))
            .await
            .expect("no answer to the nesting bomb")
            .unwrap();
        let resp = String::from_utf8_lossy(&resp[..n]);
        assert!(resp.contains("<i4>-32700</i4>"), "{uri}: {resp}");
        assert!(
            resp.contains("elements nested deeper than 128"),
            "{uri}: {resp}"
        );

        // 100 MB announced by Content-Length: refused before it is read.
        let head =
            format!("POST / HTTP/1.1\r\nHost: {addr}\r\nContent-Length: {HUNDRED_MB}\r\n\r\n");
        let resp = post_streamed(&addr, head, HUNDRED_MB, false).await;
        assert!(
            resp.contains(&format!(
                "request body ({HUNDRED_MB} bytes) is larger than the {MAX_XMLRPC_BODY} byte limit"
            )),
            "{uri}: {resp}"
        );
        // 100 MB chunked (no length): refused once the limit is reached.
        let head = format!("POST / HTTP/1.1\r\nHost: {addr}\r\nTransfer-Encoding: chunked\r\n\r\n");
        let resp = post_streamed(&addr, head, HUNDRED_MB, true).await;
        assert!(
            resp.contains(&format!(
                "request body is larger than the {MAX_XMLRPC_BODY} byte limit"
            )),
            "{uri}: {resp}"
        );
    }
    assert_serves(&master).await;
}

#[tokio::test]
async fn parameters_deeper_than_the_limit_are_refused() {
    let f = start().await;
    let master = f.dp.master_uri().to_string();
    let t = Duration::from_secs(5);
    let mut deep = Value::Int(1);
    for _ in 0..MAX_PARAM_DEPTH {
        deep = Value::Array(vec![deep]);
    }
    let set = |key: &str, v: Value| {
        let master = master.clone();
        let key = key.to_string();
        async move {
            http::call(
                &master,
                "setParam",
                &[Value::str("/probe"), Value::str(key), v],
                t,
            )
            .await
            .unwrap()
        }
    };
    // `/a` and 32 nested values: 33 levels.
    let r = set("/a", deep.clone()).await;
    let r = r.as_array().unwrap();
    assert_eq!(r[0], Value::Int(-1));
    assert!(r[1].as_str().unwrap().contains("nests 33 levels"), "{r:?}");
    // A key of 33 names.
    let r = set(&"/n".repeat(MAX_PARAM_DEPTH + 1), Value::Int(1)).await;
    assert_eq!(r.as_array().unwrap()[0], Value::Int(-1), "{r:?}");
    // At the limit: stored, and the whole tree reads back.
    let Value::Array(inner) = deep else {
        unreachable!()
    };
    let r = set("/a", inner.into_iter().next().unwrap()).await;
    assert_eq!(r.as_array().unwrap()[0], Value::Int(1), "{r:?}");
    let v = http::call(
        &master,
        "getParam",
        &[Value::str("/probe"), Value::str("/")],
        t,
    )
    .await
    .unwrap();
    assert_eq!(v.as_array().unwrap()[0], Value::Int(1));
}

/// Reads the adaptor's one reply header.
async fn reply_header(s: &mut TcpStream) -> Header {
    tokio::time::timeout(TIMEOUT, tcpros::read_header(s, "adaptor"))
        .await
        .expect("no reply header")
        .unwrap()
}

#[tokio::test]
async fn adaptor_tcpros_port_refuses_huge_headers_and_goes_on() {
    let f = start().await;
    let addr = format!("127.0.0.1:{}", f.tcpros_port);
    // A 100 MB header, streamed after its length.
    let s = TcpStream::connect(&addr).await.unwrap();
    let (mut r, mut w) = s.into_split();
    let writer = tokio::spawn(async move {
        w.write_all(&u32::try_from(HUNDRED_MB).unwrap().to_le_bytes())
            .await?;
        stream(&mut w, HUNDRED_MB, |_| (Vec::new(), Vec::new())).await
    });
    let answer = read_all(&mut r).await;
    tokio::time::timeout(TIMEOUT, writer)
        .await
        .expect("the adaptor kept reading a refused header")
        .unwrap()
        .ok();
    let h = tcpros::decode_header(&answer[4..]).unwrap();
    assert_eq!(
        h.get("error").map(String::as_str),
        Some(
            format!("header length {HUNDRED_MB} is larger than the {MAX_TCPROS_HEADER} byte limit")
                .as_str()
        )
    );

    // The nesting bomb as a header field: too large as well.
    let mut bomb = Header::new();
    bomb.insert(
        "message_definition".into(),
        String::from_utf8(nesting_bomb(BOMB_DEPTH)).unwrap(),
    );
    let mut s = TcpStream::connect(&addr).await.unwrap();
    let (mut r, mut w) = s.split();
    let bytes = tcpros::encode_header(&bomb);
    let (_, h) = tokio::join!(w.write_all(&bytes), async {
        tokio::time::timeout(TIMEOUT, tcpros::read_header(&mut r, "adaptor"))
            .await
            .expect("no reply header")
            .unwrap()
    });
    assert!(
        h.get("error").is_some_and(|e| e.contains("is larger than")),
        "{h:?}"
    );

    // An ordinary subscriber's header gets the ordinary answer.
    let mut hello = Header::new();
    hello.insert("callerid".into(), "/listener".into());
    hello.insert("topic".into(), "/chatter".into());
    hello.insert("md5sum".into(), "*".into());
    let mut s = TcpStream::connect(&addr).await.unwrap();
    s.write_all(&tcpros::encode_header(&hello)).await.unwrap();
    let h = reply_header(&mut s).await;
    assert_eq!(
        h.get("error").map(String::as_str),
        Some("no adaptor for /listener on /chatter")
    );
    assert_serves(f.dp.master_uri()).await;
}
