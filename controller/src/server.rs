//! Wiring of the control plane: open the store, start the reconcilers, serve
//! the API on a Unix socket (and optionally TCP with a token).

use std::path::PathBuf;
use std::sync::Arc;

use crate::api::{self, AppState};
use crate::metrics::Metrics;
use crate::reconcile::{self, Context};
use crate::store::Store;
use crate::tuning::robot::{Clock, Robot, SystemClock};
use crate::tuning::runner::{RunnerCtx, TuningManager};

/// Where and how the control plane serves.
#[derive(Debug, Clone)]
pub struct ServerConfig {
    pub db: PathBuf,
    pub socket: PathBuf,
    /// `host:port` and bearer token for an additional HTTPS listener
    /// (certificate `tls.crt`/`tls.key` beside the database, created if missing).
    pub tcp: Option<(String, String)>,
}

/// A running control plane.
#[derive(Debug)]
pub struct Server {
    pub state: AppState,
    /// Tuning runners (with a robot attached).
    pub tuning: Option<Arc<TuningManager>>,
    tasks: Vec<tokio::task::JoinHandle<()>>,
}

impl Server {
    /// Start the control plane in the current tokio runtime (no robot: specs
    /// are validated and resolved, not tuned).
    pub async fn start(cfg: &ServerConfig) -> anyhow::Result<Server> {
        Self::start_inner(cfg, None).await
    }

    /// Start the control plane with a robot: every valid PerformanceSpec gets
    /// a tuning runner driving `robot` (wall-clock time).
    pub async fn start_with_robot(
        cfg: &ServerConfig,
        robot: Arc<dyn Robot>,
    ) -> anyhow::Result<Server> {
        Self::start_inner(cfg, Some((robot, Arc::new(SystemClock)))).await
    }

    /// As [`Server::start_with_robot`], on an injected clock (simulated robots).
    pub async fn start_with_robot_and_clock(
        cfg: &ServerConfig,
        robot: Arc<dyn Robot>,
        clock: Arc<dyn Clock>,
    ) -> anyhow::Result<Server> {
        Self::start_inner(cfg, Some((robot, clock))).await
    }

    async fn start_inner(
        cfg: &ServerConfig,
        robot: Option<(Arc<dyn Robot>, Arc<dyn Clock>)>,
    ) -> anyhow::Result<Server> {
        if let Some(dir) = cfg.db.parent() {
            std::fs::create_dir_all(dir)?;
        }
        let store = Arc::new(Store::open(&cfg.db)?);
        let metrics = Arc::new(Metrics::new());
        let state = AppState {
            store: store.clone(),
            metrics: metrics.clone(),
        };
        let mut tasks = Vec::new();
        if let Some((robot, _)) = &robot {
            tasks.push(tokio::spawn(crate::robot::sync_stacks(
                store.clone(),
                robot.clone(),
            )));
        }
        let tuning = robot.map(|(robot, clock)| {
            Arc::new(TuningManager::new(RunnerCtx {
                robot,
                clock,
                store: store.clone(),
                metrics: metrics.clone(),
            }))
        });
        tasks.push(tokio::spawn(reconcile::run(Context {
            store,
            metrics,
            tuning: tuning.clone(),
        })));
        let router = api::router(state.clone());
        let socket = cfg.socket.clone();
        if let Some(dir) = socket.parent() {
            std::fs::create_dir_all(dir)?;
        }
        let r = router.clone();
        // Bind before returning so clients can connect as soon as start() returns.
        let (ready_tx, ready_rx) = tokio::sync::oneshot::channel();
        tasks.push(tokio::spawn(async move {
            let serve = api::serve_unix(r, &socket);
            let _ = ready_tx.send(());
            if let Err(e) = serve.await {
                tracing::error!(socket = %socket.display(), error = %e, "API listener stopped");
            }
        }));
        let _ = ready_rx.await;
        wait_for_socket(&cfg.socket).await?;
        if let Some((addr, token)) = &cfg.tcp {
            let listener = tokio::net::TcpListener::bind(addr).await?;
            let token = token.clone();
            let tls =
                api::tls::TlsFiles::in_dir(cfg.db.parent().unwrap_or(std::path::Path::new(".")));
            tls.ensure()?;
            tasks.push(tokio::spawn(async move {
                if let Err(e) = api::serve_tcp(router, listener, token, &tls).await {
                    tracing::error!(error = %e, "API TCP listener stopped");
                }
            }));
        }
        Ok(Server {
            state,
            tuning,
            tasks,
        })
    }

    /// Stop serving and reconciling.
    pub fn stop(self) {
        for t in self.tasks {
            t.abort();
        }
        drop(self.tuning);
    }
}

async fn wait_for_socket(path: &std::path::Path) -> anyhow::Result<()> {
    let deadline = tokio::time::Instant::now() + std::time::Duration::from_secs(10);
    while tokio::net::UnixStream::connect(path).await.is_err() {
        if tokio::time::Instant::now() > deadline {
            anyhow::bail!(
                "the API socket {} did not come up within 10 s",
                path.display()
            );
        }
        tokio::time::sleep(std::time::Duration::from_millis(10)).await;
    }
    Ok(())
}
