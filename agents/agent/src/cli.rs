//! Command-line entry of the agent daemon, shared by the `configbot-agent`
//! binary and (later) `configbot agent` in the main CLI.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use configbot_cgroups::{Layout, SubtreeRoot, open_backend};

use crate::agent::Agent;
use crate::error::{Error, Result};
use crate::spec::{AgentSettings, StackSpec};

/// Arguments of the agent daemon.
#[derive(Debug, Clone, clap::Args)]
pub struct AgentArgs {
    /// Stack to supervise (JSON `StackSpec`: apps → nodes → run/match).
    #[arg(long)]
    pub stack: PathBuf,
    /// The agent's subtree in the cpu cgroup hierarchies.
    #[arg(long, default_value = "configbot")]
    pub cgroup_root: String,
    #[arg(long, default_value = "/var/lib/configbot/agent-state.json")]
    pub state_file: PathBuf,
    #[arg(long, default_value = "/var/log/configbot")]
    pub log_dir: PathBuf,
    /// Unix socket of the API (mode 0600).
    #[arg(long, default_value = "/run/configbot/agent.sock")]
    pub socket: PathBuf,
    /// Also serve the API on TCP (needs --token).
    #[arg(long)]
    pub tcp: Option<SocketAddr>,
    /// Bearer token for TCP.
    #[arg(long, env = "CONFIGBOT_AGENT_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    #[arg(long, default_value_t = 5000)]
    pub stop_timeout_ms: u64,
    #[arg(long, default_value_t = 800)]
    pub backoff_initial_ms: u64,
    #[arg(long, default_value_t = 30_000)]
    pub backoff_max_ms: u64,
    #[arg(long, default_value_t = 500)]
    pub scan_interval_ms: u64,
    /// Lift every CPU limit when the agent stops on SIGINT/SIGTERM.
    #[arg(long)]
    pub lift_limits_on_shutdown: bool,
}

impl AgentArgs {
    /// The settings these arguments describe.
    pub fn settings(&self) -> Result<AgentSettings> {
        Ok(AgentSettings {
            cgroup_root: SubtreeRoot::new(&self.cgroup_root)?,
            state_file: self.state_file.clone(),
            log_dir: self.log_dir.clone(),
            stop_timeout: Duration::from_millis(self.stop_timeout_ms),
            backoff_initial: Duration::from_millis(self.backoff_initial_ms),
            backoff_max: Duration::from_millis(self.backoff_max_ms),
            scan_interval: Duration::from_millis(self.scan_interval_ms),
            lift_limits_on_shutdown: self.lift_limits_on_shutdown,
            ..AgentSettings::default()
        })
    }
}

/// Runs the agent until SIGINT or SIGTERM, then shuts down (processes keep running).
pub async fn run(args: AgentArgs) -> Result<()> {
    let io = |path: &PathBuf| {
        let path = path.clone();
        move |source| Error::Io { path, source }
    };
    let text = std::fs::read_to_string(&args.stack).map_err(io(&args.stack))?;
    let stack: StackSpec = serde_json::from_str(&text).map_err(|source| Error::State {
        path: args.stack.clone(),
        source,
    })?;
    let layout = Layout::detect().map_err(io(&PathBuf::from("/proc/self/mountinfo")))?;
    let settings = args.settings()?;
    let backend = open_backend(&layout, settings.cgroup_root.clone())?;
    let agent = Agent::start(backend, settings, stack).await?;

    let unix = crate::api::bind_unix(&args.socket).map_err(io(&args.socket))?;
    let mut servers = tokio::task::JoinSet::new();
    servers.spawn(crate::api::serve_unix(agent.clone(), unix));
    if let Some(addr) = args.tcp {
        let token = args.token.clone().unwrap_or_default();
        let l = tokio::net::TcpListener::bind(addr)
            .await
            .map_err(io(&PathBuf::from(addr.to_string())))?;
        servers.spawn(crate::api::serve_tcp(agent.clone(), l, token));
    }
    let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
        .map_err(io(&PathBuf::from("SIGTERM")))?;
    tokio::select! {
        _ = tokio::signal::ctrl_c() => {}
        _ = term.recv() => {}
        Some(res) = servers.join_next() => {
            if let Ok(Err(e)) = res {
                agent.shutdown().await;
                return Err(Error::Io { path: args.socket.clone(), source: e });
            }
        }
    }
    agent.shutdown().await;
    let _ = std::fs::remove_file(&args.socket);
    Ok(())
}
