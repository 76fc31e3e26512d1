//! The control plane's listeners under hostile input: over the Unix socket
//! and over HTTPS, nesting bombs (XML, JSON and YAML, 200 000 levels; YAML
//! also 60, which overflowed the stack before the loader's depth limit) are
//! answered 400 and streamed 100 MB bodies (announced or chunked) 413, each
//! as a Kubernetes `Status`, and the next request is served.

use std::sync::Arc;
use std::time::Duration;

use configbot_controller::api::MAX_BODY_BYTES;
use configbot_controller::server::{Server, ServerConfig};
use rustls::pki_types::{CertificateDer, ServerName, pem::PemObject};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};

const WAIT: Duration = Duration::from_secs(30);
const HUNDRED_MB: usize = 100 << 20;
const DEPTH: usize = 200_000;
const PATH: &str = "/apis/configbot.dev/v1alpha1/namespaces/default/robotstacks";
const TOKEN: &str = "s3cret";

trait Io: AsyncRead + AsyncWrite + Unpin + Send + 'static {}
impl<T: AsyncRead + AsyncWrite + Unpin + Send + 'static> Io for T {}

struct Fixture {
    dir: tempfile::TempDir,
    server: Option<Server>,
    port: u16,
}

impl Drop for Fixture {
    fn drop(&mut self) {
        if let Some(s) = self.server.take() {
            s.stop();
        }
    }
}

impl Fixture {
    async fn start() -> Fixture {
        let dir = tempfile::tempdir().unwrap();
        let port = configbot_test_support::free_port();
        let cfg = ServerConfig {
            db: dir.path().join("configbot.db"),
            socket: dir.path().join("configbot.sock"),
            tcp: Some((format!("127.0.0.1:{port}"), TOKEN.into())),
        };
        let server = Server::start(&cfg).await.unwrap();
        Fixture {
            dir,
            server: Some(server),
            port,
        }
    }

    async fn unix(&self) -> Box<dyn Io> {
        Box::new(
            tokio::net::UnixStream::connect(self.dir.path().join("configbot.sock"))
                .await
                .unwrap(),
        )
    }

    /// An HTTPS connection that trusts the server's own certificate.
    async fn tls(&self) -> Box<dyn Io> {
        let pem = std::fs::read(self.dir.path().join("tls.crt")).unwrap();
        let mut roots = rustls::RootCertStore::empty();
        for c in CertificateDer::pem_slice_iter(&pem) {
            roots.add(c.unwrap()).unwrap();
        }
        let provider = Arc::new(rustls::crypto::ring::default_provider());
        let cfg = rustls::ClientConfig::builder_with_provider(provider)
            .with_safe_default_protocol_versions()
            .unwrap()
            .with_root_certificates(roots)
            .with_no_client_auth();
        let tcp = tokio::net::TcpStream::connect(("127.0.0.1", self.port))
            .await
            .unwrap();
        let tls = tokio_rustls::TlsConnector::from(Arc::new(cfg))
            .connect(ServerName::try_from("localhost").unwrap(), tcp)
            .await
            .unwrap();
        Box::new(tls)
    }

    async fn connect(&self, tls: bool) -> Box<dyn Io> {
        if tls {
            self.tls().await
        } else {
            self.unix().await
        }
    }
}

/// Sends a POST whose body is `body_len` bytes of `body` (`None`: spaces,
/// streamed 64 KiB at a time from one buffer), announced by Content-Length
/// or chunked, while reading the answer. The writer must end: the server
/// read everything or closed the connection.
async fn post(
    s: Box<dyn Io>,
    content_type: &str,
    body: Option<Vec<u8>>,
    body_len: usize,
    chunked: bool,
) -> String {
    let (mut r, mut w) = tokio::io::split(s);
    let length = if chunked {
        "Transfer-Encoding: chunked".to_string()
    } else {
        format!("Content-Length: {body_len}")
    };
    let head = format!(
        "POST {PATH} HTTP/1.1\r\nHost: configbot\r\nAuthorization: Bearer {TOKEN}\r\nContent-Type: {content_type}\r\n{length}\r\nConnection: close\r\n\r\n"
    );
    let writer = tokio::spawn(async move {
        w.write_all(head.as_bytes()).await?;
        let filler = vec![b' '; 64 << 10];
        let data = body.as_deref().unwrap_or(&filler);
        let mut sent = 0;
        while sent < body_len {
            let n = (body_len - sent).min(64 << 10);
            let part = if body.is_some() {
                &data[sent..sent + n]
            } else {
                &data[..n]
            };
            if chunked {
                w.write_all(format!("{n:x}\r\n").as_bytes()).await?;
            }
            w.write_all(part).await?;
            if chunked {
                w.write_all(b"\r\n").await?;
            }
            sent += n;
        }
        if chunked {
            w.write_all(b"0\r\n\r\n").await?;
        }
        w.flush().await
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
    tokio::time::timeout(WAIT, read).await.expect("no answer");
    tokio::time::timeout(WAIT, writer)
        .await
        .expect("the server kept reading a refused body")
        .unwrap()
        .ok();
    String::from_utf8_lossy(&out).into_owned()
}

fn stack(name: &str) -> Vec<u8> {
    serde_json::json!({"apiVersion": "configbot.dev/v1alpha1", "kind": "RobotStack", "metadata": {"name": name},
        "spec": {"apps": [{"name": "nav", "core": true, "nodes": [{"name": "/nav", "run": {"command": "/bin/true"}}]}]}})
    .to_string()
    .into_bytes()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn listeners_refuse_nesting_bombs_and_100_mb_bodies_and_go_on() {
    let f = Fixture::start().await;
    let bombs = [
        (
            "application/json",
            format!("{}{}", "<array>".repeat(DEPTH), "</array>".repeat(DEPTH)),
        ),
        (
            "application/json",
            format!("{}{}", "[".repeat(DEPTH), "]".repeat(DEPTH)),
        ),
        (
            "application/yaml",
            format!("{}{}", "[".repeat(DEPTH), "]".repeat(DEPTH)),
        ),
        // Under the YAML reader's own budget (64) but deep enough to
        // overflow a 2 MiB stack in a debug build: refused by MAX_NESTING.
        (
            "application/yaml",
            format!("{}{}", "[".repeat(60), "]".repeat(60)),
        ),
    ];
    for tls in [false, true] {
        for (ct, bomb) in &bombs {
            let b = bomb.clone().into_bytes();
            let n = b.len();
            let r = post(f.connect(tls).await, ct, Some(b), n, false).await;
            assert!(r.starts_with("HTTP/1.1 400"), "tls={tls} {ct}: {r}");
            assert!(r.contains(r#""kind":"Status""#), "{r}");
        }
        for chunked in [false, true] {
            let r = post(
                f.connect(tls).await,
                "application/json",
                None,
                HUNDRED_MB,
                chunked,
            )
            .await;
            assert!(
                r.starts_with("HTTP/1.1 413"),
                "tls={tls} chunked={chunked}: {r}"
            );
            let size = if chunked {
                String::new()
            } else {
                format!(" ({HUNDRED_MB} bytes)")
            };
            assert!(
                r.contains(&format!(
                    "request body{size} is larger than the {MAX_BODY_BYTES} byte limit"
                )),
                "{r}"
            );
            assert!(r.contains(r#""reason":"RequestEntityTooLarge""#), "{r}");
        }
        let name = if tls { "after-tls" } else { "after-unix" };
        let body = stack(name);
        let n = body.len();
        let r = post(
            f.connect(tls).await,
            "application/json",
            Some(body),
            n,
            false,
        )
        .await;
        assert!(r.starts_with("HTTP/1.1 201"), "tls={tls}: {r}");
    }
}
