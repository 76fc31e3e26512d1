//! The data-plane backends the runtime can start, by name. A backend is a
//! crate implementing [`DataPlane`] (`configbot-ros1` today); a second
//! middleware is one more crate and one more entry in [`BACKENDS`].

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use configbot_api::policy::{AppOf, PolicyConfig};
use configbot_dataplane::{DataPlane, ThreadHooks};
use configbot_ros1::{Ros1Config, Ros1DataPlane, placement_from_apps};
use prometheus::Registry;

use crate::contract::BoxFuture;
use crate::error::{Error, Result};

/// The backend used unless told otherwise.
pub const DEFAULT_BACKEND: &str = "ros1";

/// How to start the data plane.
#[derive(Debug, Clone)]
pub struct DataPlaneOptions {
    /// The backend: a name in [`BACKENDS`].
    pub backend: String,
    /// Where nodes find the data plane (ROS 1: the master URI; its port is
    /// where the master listens).
    pub uri: String,
    /// Address the data plane's server binds to (ROS 1: the master).
    pub bind_host: String,
    /// Address the adaptors' servers bind to.
    pub adaptor_bind_host: String,
    /// The backend's persisted state (ROS 1: the SQLite file of
    /// registrations, parameters and adaptor settings).
    pub db_path: PathBuf,
    /// Adaptor placement policy (include/exclude lists; the rate rule is
    /// the tuner's business).
    pub policy: PolicyConfig,
    /// Period of the full graph refresh; `None`: the backend's default.
    pub refresh_period: Option<Duration>,
}

/// A backend's error while starting.
type StartError = Box<dyn std::error::Error + Send + Sync>;

/// Starts a backend: its options, the stack's apps as the adaptor placement
/// reads them, the registry its metrics go to and what each of its threads
/// runs as it starts, by the thread's job.
type StartFn = for<'a> fn(
    &'a DataPlaneOptions,
    Arc<dyn AppOf + Send + Sync>,
    &'a Registry,
    ThreadHooks,
) -> BoxFuture<'a, std::result::Result<Arc<dyn DataPlane>, StartError>>;

/// One backend the runtime can start.
#[derive(Debug)]
pub struct Backend {
    /// Its name in [`DataPlaneOptions::backend`].
    pub name: &'static str,
    /// Its name in messages.
    pub title: &'static str,
    start: StartFn,
}

/// Every backend, by name.
pub const BACKENDS: &[Backend] = &[Backend {
    name: "ros1",
    title: "ros 1",
    start: start_ros1,
}];

/// Starts the backend `opts` names.
pub(super) async fn start(
    opts: &DataPlaneOptions,
    apps: Arc<dyn AppOf + Send + Sync>,
    registry: &Registry,
    threads: ThreadHooks,
) -> Result<Arc<dyn DataPlane>> {
    let backend = BACKENDS
        .iter()
        .find(|b| b.name == opts.backend)
        .ok_or_else(|| Error::UnknownDataPlane {
            name: opts.backend.clone(),
            known: BACKENDS
                .iter()
                .map(|b| b.name)
                .collect::<Vec<_>>()
                .join(", "),
        })?;
    (backend.start)(opts, apps, registry, threads)
        .await
        .map_err(|source| Error::DataPlane {
            backend: backend.title,
            uri: opts.uri.clone(),
            source,
        })
}

fn start_ros1<'a>(
    opts: &'a DataPlaneOptions,
    apps: Arc<dyn AppOf + Send + Sync>,
    registry: &'a Registry,
    threads: ThreadHooks,
) -> BoxFuture<'a, std::result::Result<Arc<dyn DataPlane>, StartError>> {
    Box::pin(async move {
        let defaults = Ros1Config::default();
        let cfg = Ros1Config {
            master_uri: opts.uri.clone(),
            bind_host: opts.bind_host.clone(),
            adaptor_bind_host: opts.adaptor_bind_host.clone(),
            refresh_period: opts.refresh_period.unwrap_or(defaults.refresh_period),
            placement: Some(placement_from_apps(apps, opts.policy.clone())),
            threads,
            ..defaults
        };
        let dp = Ros1DataPlane::start(cfg, &opts.db_path, registry).await?;
        Ok(Arc::new(dp) as Arc<dyn DataPlane>)
    })
}
