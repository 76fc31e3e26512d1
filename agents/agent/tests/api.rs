//! HTTP API tests: `Router::oneshot` for the endpoints, a real TCP listener
//! for the bearer token, a real Unix socket for the 0600 rule (root needed),
//! and both listeners under nesting bombs and 100 MB bodies.

mod common;

use std::os::unix::fs::PermissionsExt;
use std::os::unix::process::CommandExt;
use std::time::Duration;

use axum::body::Body;
use axum::http::{Request, StatusCode};
use common::*;
use configbot_agent::NodeApi;
use configbot_agent::api::{bind_unix, router, serve_tcp, serve_unix};
use http_body_util::BodyExt;
use tower::ServiceExt;

const STACK: &str = r#"{"apps":[{"name":"a","nodes":[
    {"name":"/sleeper","run":{"command":"/bin/sleep","args":["120"]}},
    {"name":"/absent","match":{"cmdlineRegex":"^no such process [0-9]{40}$"}}]}]}"#;

async fn call(
    app: &axum::Router,
    method: &str,
    uri: &str,
    body: &str,
    token: Option<&str>,
) -> (StatusCode, String) {
    let mut req = Request::builder()
        .method(method)
        .uri(uri)
        .header("content-type", "application/json");
    if let Some(t) = token {
        req = req.header("authorization", format!("Bearer {t}"));
    }
    let resp = app
        .clone()
        .oneshot(req.body(Body::from(body.to_owned())).unwrap())
        .await
        .unwrap();
    let status = resp.status();
    let bytes = resp.into_body().collect().await.unwrap().to_bytes();
    (status, String::from_utf8_lossy(&bytes).into_owned())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn endpoints_inventory_config_metrics_events() {
    let mut env = Env::new();
    let agent = env.start(stack_json(STACK)).await;
    let rt = configbot_agent::NodeRuntime::with_agent(agent.clone()).unwrap();
    let app = router(rt, None);

    let (code, body) = call(&app, "GET", "/v1/nodes", "", None).await;
    assert_eq!(code, StatusCode::OK);
    let nodes: serde_json::Value = serde_json::from_str(&body).unwrap();
    assert_eq!(nodes.as_array().unwrap().len(), 2, "{body}");
    assert!(
        nodes[1]["cgroup"]
            .as_str()
            .unwrap()
            .ends_with("node-sleeper"),
        "{body}"
    );

    // Event stream: subscribe, then cause an event.
    let resp = app
        .clone()
        .oneshot(Request::get("/v1/events").body(Body::empty()).unwrap())
        .await
        .unwrap();
    assert_eq!(resp.headers()["content-type"], "application/x-ndjson");
    let mut events = resp.into_body();

    let cases = [
        (r#"{"cpu":{"/sleeper":-1}}"#, StatusCode::BAD_REQUEST),
        (
            r#"{"cpu":{"/sleeper":0.5},"cpuPeriodMicros":10}"#,
            StatusCode::BAD_REQUEST,
        ),
        (r#"{"cpu":{"/ghost":0.5}}"#, StatusCode::NOT_FOUND),
        (r#"{"cpu":{"/../x":0.5}}"#, StatusCode::BAD_REQUEST),
        ("not json", StatusCode::BAD_REQUEST),
        (
            r#"{"cpu":{"/sleeper":0.5},"adaptors":[{"topic":"/scan","subscriber":"/sleeper","rateHz":10}]}"#,
            StatusCode::CONFLICT,
        ),
        (
            r#"{"cpu":{"/sleeper":0.5},"cpuPeriodMicros":50000}"#,
            StatusCode::OK,
        ),
    ];
    for (body, want) in cases {
        let (code, text) = call(&app, "PUT", "/v1/config", body, None).await;
        assert_eq!(code, want, "{body} -> {text}");
        assert!(text.contains("error") || code == StatusCode::OK, "{text}");
    }
    let m = agent.backend().cpu_max(&node("/sleeper")).unwrap();
    assert_eq!((m.quota_us, m.period_us), (Some(25_000), 50_000));

    let frame = tokio::time::timeout(Duration::from_secs(10), events.frame())
        .await
        .unwrap()
        .unwrap()
        .unwrap();
    let line = String::from_utf8_lossy(frame.data_ref().unwrap()).into_owned();
    assert!(line.ends_with('\n'), "{line}");
    let ev: serde_json::Value = serde_json::from_str(line.trim()).unwrap();
    assert!(ev["type"].is_string(), "{line}");

    let (code, text) = call(&app, "GET", "/metrics", "", None).await;
    assert_eq!(code, StatusCode::OK);
    for want in [
        "configbot_agent_node_cpu_limit_cpus{node=\"/sleeper\"} 0.5",
        "configbot_agent_node_cpu_limit_cpus{node=\"/absent\"} -1",
        "configbot_agent_active_monitor{monitor=\"proc_scan\"} 1",
        "configbot_agent_node_cpu_usage_cpus{node=\"/sleeper\"}",
        "configbot_agent_node_throttled_periods{node=\"/sleeper\"}",
    ] {
        assert!(text.contains(want), "missing {want} in\n{text}");
    }
    agent.set_active_monitor("ebpf");
    agent.process_event(&configbot_agent::ProcEvent {
        kind: configbot_agent::ProcEventKind::Exec,
        pid: std::process::id(),
        ppid: Some(1),
        comm: Some("x".into()),
    });
    agent.process_event(&configbot_agent::ProcEvent {
        kind: configbot_agent::ProcEventKind::Exit,
        pid: 1,
        ppid: None,
        comm: None,
    });
    let (_, text) = call(&app, "GET", "/metrics", "", None).await;
    assert!(
        text.contains("configbot_agent_monitor_events_total{kind=\"exit\"} 1"),
        "{text}"
    );
    assert!(
        text.contains("configbot_agent_active_monitor{monitor=\"ebpf\"} 1"),
        "{text}"
    );
    assert!(
        text.contains("configbot_agent_active_monitor{monitor=\"proc_scan\"} 0"),
        "{text}"
    );
    assert!(
        text.contains("configbot_agent_monitor_events_total{kind=\"exec\"} 1"),
        "{text}"
    );

    let (code, _) = call(&app, "POST", "/v1/apps/ghost/stop", "", None).await;
    assert_eq!(code, StatusCode::NOT_FOUND);
    let (code, _) = call(&app, "POST", "/v1/apps/a/stop", "", None).await;
    assert_eq!(code, StatusCode::OK);
    assert!(agent.backend().pids(&node("/sleeper")).unwrap().is_empty());
    let (code, _) = call(&app, "POST", "/v1/apps/a/start", "", None).await;
    assert_eq!(code, StatusCode::OK);
    let (code, _) = call(&app, "POST", "/v1/apps/a/pause", "", None).await;
    assert_eq!(code, StatusCode::NOT_FOUND, "no such action");
    for action in ["freeze", "thaw"] {
        let (code, _) = call(&app, "POST", &format!("/v1/apps/a/{action}"), "", None).await;
        assert_eq!(code, StatusCode::OK, "{action}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tcp_needs_the_bearer_token() {
    let mut env = Env::new();
    let agent = env.start(stack_json(r#"{"apps":[]}"#)).await;
    let rt = configbot_agent::NodeRuntime::with_agent(agent.clone()).unwrap();
    let app = router(rt.clone(), Some("s3cret".into()));
    assert_eq!(
        call(&app, "GET", "/v1/nodes", "", None).await.0,
        StatusCode::UNAUTHORIZED
    );
    assert_eq!(
        call(&app, "GET", "/metrics", "", Some("wrong")).await.0,
        StatusCode::UNAUTHORIZED
    );
    assert_eq!(
        call(&app, "GET", "/v1/nodes", "", Some("s3cret")).await.0,
        StatusCode::OK
    );

    let l = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = l.local_addr().unwrap();
    tokio::spawn(serve_tcp(rt.clone(), l, "s3cret".into()));
    let (no_token, with_token) = tokio::task::spawn_blocking(move || {
        let a = http(
            std::net::TcpStream::connect(addr).unwrap(),
            "GET",
            "/v1/nodes",
            None,
            None,
        );
        let b = http(
            std::net::TcpStream::connect(addr).unwrap(),
            "GET",
            "/v1/nodes",
            None,
            Some("s3cret"),
        );
        (a, b)
    })
    .await
    .unwrap();
    assert_eq!(no_token.0, 401, "{}", no_token.1);
    assert_eq!(with_token.0, 200, "{}", with_token.1);

    let l = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    assert!(
        serve_tcp(rt, l, String::new()).await.is_err(),
        "tcp without a token must be refused"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn unix_socket_is_0600_and_refuses_other_users() {
    let mut env = Env::new();
    let agent = env.start(stack_json(r#"{"apps":[]}"#)).await;
    // The directory is world-searchable, so only the socket's own mode protects it.
    std::fs::set_permissions(env.dir.path(), std::fs::Permissions::from_mode(0o755)).unwrap();
    let path = env.path("agent.sock");
    let listener = bind_unix(&path).unwrap();
    let rt = configbot_agent::NodeRuntime::with_agent(agent).unwrap();
    tokio::spawn(serve_unix(rt, listener));
    let mode = std::fs::metadata(&path).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode, 0o600);

    let p = path.clone();
    let (root_status, nobody_exit) = tokio::task::spawn_blocking(move || {
        let root = http(std::os::unix::net::UnixStream::connect(&p).unwrap(), "GET", "/v1/nodes", None, None);
        let nobody = std::process::Command::new("/usr/bin/python3")
            .args([
                "-c",
                "import socket,sys\ns=socket.socket(socket.AF_UNIX)\ntry:\n s.connect(sys.argv[1])\nexcept PermissionError:\n sys.exit(13)\nsys.exit(0)",
                p.to_str().unwrap(),
            ])
            .uid(65534)
            .gid(65534)
            .status()
            .unwrap();
        (root.0, nobody.code())
    })
    .await
    .unwrap();
    assert_eq!(root_status, 200);
    assert_eq!(nobody_exit, Some(13), "user nobody could connect");
}

/// A PUT of `/v1/stack` with `body`, over `s`; the answer's status line and body.
async fn put_raw<S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin>(
    s: &mut S,
    token: &str,
    body: &[u8],
) -> String {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let head = format!(
        "PUT /v1/stack HTTP/1.1\r\nHost: agent\r\nAuthorization: Bearer {token}\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n",
        body.len()
    );
    s.write_all(head.as_bytes()).await.unwrap();
    s.write_all(body).await.unwrap();
    let mut out = Vec::new();
    tokio::time::timeout(LIMIT_WAIT, s.read_to_end(&mut out))
        .await
        .expect("no answer")
        .unwrap();
    String::from_utf8_lossy(&out).into_owned()
}

/// Streams `len` bytes of body (announced, or chunked without a length) 64
/// KiB at a time from one buffer while reading the answer; the writer must
/// end (the server closes).
async fn put_streamed<S>(s: S, token: &str, len: usize, chunked: bool) -> String
where
    S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Send + 'static,
{
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let (mut r, mut w) = tokio::io::split(s);
    let length = if chunked {
        "Transfer-Encoding: chunked".to_string()
    } else {
        format!("Content-Length: {len}")
    };
    let head = format!(
        "PUT /v1/stack HTTP/1.1\r\nHost: agent\r\nAuthorization: Bearer {token}\r\nContent-Type: application/json\r\n{length}\r\n\r\n"
    );
    let writer = tokio::spawn(async move {
        w.write_all(head.as_bytes()).await?;
        let buf = vec![b' '; 64 << 10];
        let mut left = len;
        while left > 0 {
            let n = left.min(buf.len());
            if chunked {
                w.write_all(format!("{n:x}\r\n").as_bytes()).await?;
            }
            w.write_all(&buf[..n]).await?;
            if chunked {
                w.write_all(b"\r\n").await?;
            }
            left -= n;
        }
        if chunked {
            w.write_all(b"0\r\n\r\n").await?;
        }
        std::io::Result::Ok(())
    });
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
    tokio::time::timeout(LIMIT_WAIT, read)
        .await
        .expect("no answer");
    tokio::time::timeout(LIMIT_WAIT, writer)
        .await
        .expect("the agent kept reading a refused body")
        .unwrap()
        .ok();
    String::from_utf8_lossy(&out).into_owned()
}

const LIMIT_WAIT: Duration = Duration::from_secs(30);

/// Nesting bombs (XML and JSON, 200 000 levels) and a streamed 100 MB body
/// to the agent's TCP and Unix listeners: 400, 400, 413, and the next
/// request is served.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn listeners_refuse_nesting_bombs_and_100_mb_bodies_and_go_on() {
    let mut env = Env::new();
    let agent = env.start(stack_json(r#"{"apps":[]}"#)).await;
    let rt = configbot_agent::NodeRuntime::with_agent(agent).unwrap();
    let l = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = l.local_addr().unwrap();
    tokio::spawn(serve_tcp(rt.clone(), l, "s3cret".into()));
    let path = env.path("agent.sock");
    tokio::spawn(serve_unix(rt, bind_unix(&path).unwrap()));

    let xml_bomb = format!(
        "{}{}",
        "<array>".repeat(200_000),
        "</array>".repeat(200_000)
    );
    let json_bomb = format!("{}{}", "[".repeat(200_000), "]".repeat(200_000));
    let hundred_mb = 100 << 20;
    for unix in [false, true] {
        let tcp = || tokio::net::TcpStream::connect(addr);
        let sock = || tokio::net::UnixStream::connect(&path);
        for bomb in [&xml_bomb, &json_bomb] {
            let r = if unix {
                put_raw(&mut sock().await.unwrap(), "s3cret", bomb.as_bytes()).await
            } else {
                put_raw(&mut tcp().await.unwrap(), "s3cret", bomb.as_bytes()).await
            };
            assert!(r.starts_with("HTTP/1.1 400"), "unix={unix}: {r}");
        }
        for chunked in [false, true] {
            let r = if unix {
                put_streamed(sock().await.unwrap(), "s3cret", hundred_mb, chunked).await
            } else {
                put_streamed(tcp().await.unwrap(), "s3cret", hundred_mb, chunked).await
            };
            assert!(r.starts_with("HTTP/1.1 413"), "unix={unix}: {r}");
            let size = if chunked { "" } else { " (104857600 bytes)" };
            assert!(
                r.contains(&format!(
                    "request body{size} is larger than the 3145728 byte limit"
                )),
                "{r}"
            );
        }
        let ok = if unix {
            put_raw(&mut sock().await.unwrap(), "s3cret", br#"{"apps":[]}"#).await
        } else {
            put_raw(&mut tcp().await.unwrap(), "s3cret", br#"{"apps":[]}"#).await
        };
        assert!(ok.starts_with("HTTP/1.1 200"), "unix={unix}: {ok}");
    }
}

/// The controller's "no stack" (`set_stack(None)`, sent when the last stack
/// is deleted) clears a remote agent's stack: the agent used to refuse it as
/// a RobotStack without name and apps (400) and kept the nodes.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn client_clears_the_stack_with_an_empty_one() {
    let mut env = Env::new();
    let agent = env.start(stack_json(STACK)).await;
    let path = env.path("agent.sock");
    let listener = bind_unix(&path).unwrap();
    let rt = configbot_agent::NodeRuntime::with_agent(agent).unwrap();
    tokio::spawn(serve_unix(rt, listener));
    let client = configbot_agent::client::AgentClient::unix(&path);
    assert_eq!(client.inventory().await.unwrap().len(), 2);
    client.set_stack(None).await.unwrap();
    assert!(client.inventory().await.unwrap().is_empty());
}
