//! `serve`'s robot: none, the node runtime embedded in this process, or a
//! node agent running alone.

use std::path::Path;
use std::sync::Arc;

use configbot_agent::NodeRuntime;
use configbot_agent::runtime::{DEFAULT_BACKEND, DataPlaneOptions, RuntimeOptions};
use configbot_cgroups::{CpuWeight, Layout, SubtreeRoot, open_backend};

use super::RobotArgs;
use configbot_controller::robot::{EmbeddedRobot, RemoteRobot};
use configbot_controller::server::{Server, ServerConfig};

/// The runtime options of an embedded agent whose files live in `dir`.
pub fn runtime_options(dir: &Path, args: &RobotArgs) -> anyhow::Result<RuntimeOptions> {
    Ok(RuntimeOptions {
        settings: configbot_agent::AgentSettings {
            cgroup_root: SubtreeRoot::new(&args.cgroup_root)?,
            state_file: dir.join("agent-state.json"),
            log_dir: dir.join("logs"),
            subtree_cpu_weight: args.subtree_cpu_weight.map(CpuWeight::new).transpose()?,
            ..configbot_agent::AgentSettings::default()
        },
        data_plane: (!args.no_ros).then(|| DataPlaneOptions {
            backend: DEFAULT_BACKEND.into(),
            uri: args.ros_master_uri.clone(),
            bind_host: args.ros_bind.clone(),
            adaptor_bind_host: args.ros_adaptor_bind.clone(),
            db_path: dir.join("ros1.db"),
            policy: configbot_api::policy::PolicyConfig::default(),
            refresh_period: None,
        }),
        monitor: args.monitor.preference(),
    })
}

/// Starts the embedded node runtime with the stack it ran before (if any).
pub async fn start_runtime(dir: &Path, args: &RobotArgs) -> anyhow::Result<NodeRuntime> {
    std::fs::create_dir_all(dir)?;
    let opts = runtime_options(dir, args)?;
    let stack = configbot_agent::state::load(&opts.settings.state_file)?
        .and_then(|s| s.stack)
        .unwrap_or_default();
    let layout = Layout::detect()?;
    let backend = open_backend(&layout, opts.settings.cgroup_root.clone())?;
    Ok(NodeRuntime::start(backend, opts, stack).await?)
}

/// Starts the control plane with the robot `args` asks for; returns the
/// embedded runtime too, so the caller can shut it down.
pub async fn start_server(
    cfg: &ServerConfig,
    args: &RobotArgs,
) -> anyhow::Result<(Server, Option<NodeRuntime>)> {
    if args.agent {
        let dir = cfg.db.parent().unwrap_or(Path::new(".")).to_path_buf();
        let rt = start_runtime(&dir, args).await?;
        eprintln!(
            "configbot: node agent embedded ({}; ROS master {})",
            rt.monitor_status(),
            rt.master_uri().as_deref().unwrap_or("disabled")
        );
        let robot = Arc::new(EmbeddedRobot::new(rt.clone()));
        let server = Server::start_with_robot(cfg, robot).await?;
        let agent = rt.clone();
        server
            .state
            .metrics
            .add_source(Box::new(move || agent.render_metrics().unwrap_or_default()));
        Ok((server, Some(rt)))
    } else if let Some(sock) = &args.agent_socket {
        let robot = Arc::new(RemoteRobot::new(
            configbot_agent::client::AgentClient::unix(sock),
        ));
        Ok((Server::start_with_robot(cfg, robot).await?, None))
    } else {
        Ok((Server::start(cfg).await?, None))
    }
}
