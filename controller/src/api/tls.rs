//! TLS for the TCP listener. kubectl (client-go) sends bearer tokens only over
//! TLS, so TCP is always HTTPS: a self-signed certificate for localhost and
//! 127.0.0.1 is created on first start beside the database and reused after.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use axum::Router;
use std::time::Duration;

use hyper_util::rt::{TokioExecutor, TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use rustls::pki_types::{CertificateDer, PrivateKeyDer, pem::PemObject};

use super::limits::HEADER_TIMEOUT;

/// Paths of the serving certificate and key.
#[derive(Debug, Clone)]
pub struct TlsFiles {
    pub cert: PathBuf,
    pub key: PathBuf,
}

impl TlsFiles {
    pub fn in_dir(dir: &Path) -> TlsFiles {
        TlsFiles {
            cert: dir.join("tls.crt"),
            key: dir.join("tls.key"),
        }
    }

    /// Create a self-signed certificate unless both files exist.
    pub fn ensure(&self) -> std::io::Result<()> {
        if self.cert.exists() && self.key.exists() {
            return Ok(());
        }
        let names = vec![
            "localhost".to_string(),
            "127.0.0.1".to_string(),
            "::1".to_string(),
        ];
        let cert = rcgen::generate_simple_self_signed(names).map_err(std::io::Error::other)?;
        write_private(&self.key, cert.key_pair.serialize_pem().as_bytes())?;
        std::fs::write(&self.cert, cert.cert.pem())
    }

    fn server_config(&self) -> std::io::Result<rustls::ServerConfig> {
        let bad =
            |what: &Path, e: String| std::io::Error::other(format!("{}: {e}", what.display()));
        let certs: Vec<CertificateDer<'static>> = CertificateDer::pem_file_iter(&self.cert)
            .map_err(|e| bad(&self.cert, e.to_string()))?
            .collect::<Result<_, _>>()
            .map_err(|e| bad(&self.cert, e.to_string()))?;
        let key =
            PrivateKeyDer::from_pem_file(&self.key).map_err(|e| bad(&self.key, e.to_string()))?;
        rustls::ServerConfig::builder_with_provider(Arc::new(
            rustls::crypto::ring::default_provider(),
        ))
        .with_safe_default_protocol_versions()
        .map_err(|e| std::io::Error::other(e.to_string()))?
        .with_no_client_auth()
        .with_single_cert(certs, key)
        .map_err(|e| bad(&self.cert, e.to_string()))
    }
}

fn write_private(path: &Path, data: &[u8]) -> std::io::Result<()> {
    use std::io::Write;
    use std::os::unix::fs::OpenOptionsExt;
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(true)
        .mode(0o600)
        .open(path)?;
    f.write_all(data)
}

/// Serve HTTPS on `listener` until the task is dropped.
pub async fn serve(
    router: Router,
    listener: tokio::net::TcpListener,
    files: &TlsFiles,
) -> std::io::Result<()> {
    let acceptor = tokio_rustls::TlsAcceptor::from(Arc::new(files.server_config()?));
    loop {
        // An accept error (such as too many open files) is transient: the
        // listener goes on once connections close.
        let tcp = match listener.accept().await {
            Ok((tcp, _)) => tcp,
            Err(_) => {
                tokio::time::sleep(Duration::from_millis(50)).await;
                continue;
            }
        };
        let acceptor = acceptor.clone();
        let router = router.clone();
        tokio::spawn(async move {
            let Ok(Ok(tls)) = tokio::time::timeout(HEADER_TIMEOUT, acceptor.accept(tcp)).await
            else {
                return;
            };
            let service = TowerToHyperService::new(router);
            let mut builder = hyper_util::server::conn::auto::Builder::new(TokioExecutor::new());
            builder
                .http1()
                .timer(TokioTimer::new())
                .header_read_timeout(HEADER_TIMEOUT);
            let _ = builder
                .serve_connection_with_upgrades(TokioIo::new(tls), service)
                .await;
        });
    }
}
