//! Command-line entry of the agent daemon, shared by the `configbot-agent`
//! binary and `configbot agent` in the main CLI: starts the full
//! [`NodeRuntime`] (agent + process monitor + ROS 1 master) and serves its API.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

use configbot_cgroups::{CpuWeight, Layout, SubtreeRoot, open_backend};

use configbot_procmon::{MonitorKind, Preference};

use crate::error::{Error, Result};
use crate::runtime::{DEFAULT_BACKEND, DataPlaneOptions, NodeRuntime, RuntimeOptions};
use crate::spec::{AgentSettings, StackSpec};

/// Which process monitor to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum MonitorChoice {
    /// eBPF, then the proc connector, then a /proc scan.
    Auto,
    Ebpf,
    Connector,
    Scan,
    /// No process monitor: `match` nodes are found by the agent's periodic scan.
    None,
}

impl MonitorChoice {
    /// The procmon preference; `None` for no monitor.
    pub fn preference(self) -> Option<Preference> {
        match self {
            Self::Auto => Some(Preference::Auto),
            Self::Ebpf => Some(Preference::Only(MonitorKind::Ebpf)),
            Self::Connector => Some(Preference::Only(MonitorKind::ProcConnector)),
            Self::Scan => Some(Preference::Only(MonitorKind::ProcScan)),
            Self::None => None,
        }
    }
}

/// Arguments of the agent daemon.
#[derive(Debug, Clone, clap::Args)]
pub struct AgentArgs {
    /// Stack to supervise: a RobotStack manifest (YAML or JSON) or a JSON
    /// `StackSpec`. Without it the agent runs the stack last set through the
    /// API (kept in the state file), or none, until `PUT /v1/stack`.
    #[arg(long)]
    pub stack: Option<PathBuf>,
    /// ROS_MASTER_URI of the robot: the agent serves the ROS master here.
    #[arg(long, default_value = "http://localhost:11311/")]
    pub ros_master_uri: String,
    /// Address the ROS master (and parameter server) listens on. The default,
    /// every interface, is what rosmaster does, so nodes on other hosts can
    /// register; 127.0.0.1 keeps it to this host.
    #[arg(long, alias = "ros-bind-host", default_value = configbot_ros1::DEFAULT_MASTER_BIND)]
    pub ros_bind: String,
    /// Address the ROS rate adaptors (slave XML-RPC and TCPROS) listen on.
    /// Only adapted subscribers on this host connect to them, at localhost,
    /// so the default is loopback.
    #[arg(long, default_value = configbot_ros1::DEFAULT_ADAPTOR_BIND)]
    pub ros_adaptor_bind: String,
    /// SQLite file of the ROS master (registrations, parameters, adaptors).
    #[arg(long, default_value = "/var/lib/configbot/ros1.db")]
    pub ros_db: PathBuf,
    /// Run without the ROS data plane (no master, no adaptors, no topic rates).
    #[arg(long)]
    pub no_ros: bool,
    /// Process monitor.
    #[arg(long, value_enum, default_value_t = MonitorChoice::Auto)]
    pub monitor: MonitorChoice,
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
    /// Also serve the API on TCP at this address, e.g. 127.0.0.1:9443 (needs
    /// --token). Without it the API is only on the Unix socket.
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
    /// CPU weight of the robot's nodes together against the host's other
    /// services (1–10000, cgroup v2 units; a service has 100; v1 cpu.shares =
    /// weight × 10.24). Unset: the kernel's default.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=10_000))]
    pub subtree_cpu_weight: Option<u32>,
    /// Largest rosbag a remediation's recording writes, in MB; rosbag stops
    /// recording there (it keeps the first part: the moments after the
    /// pause). 0: no cap.
    #[arg(long, default_value_t = 1024)]
    pub recording_max_mb: u64,
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
            subtree_cpu_weight: self.subtree_cpu_weight.map(CpuWeight::new).transpose()?,
            recording_max_mb: self.recording_max_mb,
            ..AgentSettings::default()
        })
    }
}

/// Logs the crates' `tracing` events to stderr, filtered by `RUST_LOG`
/// (default `info`; e.g. `RUST_LOG=configbot_ros1=debug`). Called once by
/// each binary that runs the agent or the control plane; a second call is a
/// no-op.
pub fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let _ = tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_env_filter(filter)
        .try_init();
}

/// Reads a stack file: a JSON `StackSpec` (has top-level `apps`) or a
/// RobotStack manifest (YAML or JSON, validated by `configbot_manifests`).
pub fn read_stack(path: &Path) -> Result<StackSpec> {
    let text = std::fs::read_to_string(path).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })?;
    if let Ok(v) = serde_json::from_str::<serde_json::Value>(&text)
        && v.get("apps").is_some()
    {
        return serde_json::from_value(v).map_err(|source| Error::State {
            path: path.to_path_buf(),
            source,
        });
    }
    let name = path.display().to_string();
    let docs = configbot_manifests::load(&name, &text).map_err(|e| Error::Manifest {
        source_name: name.clone(),
        message: e.to_string(),
    })?;
    let mut stacks = docs.iter().filter_map(|d| match &d.manifest {
        configbot_manifests::Manifest::RobotStack(s) => Some(s),
        _ => None,
    });
    match (stacks.next(), stacks.next()) {
        (Some(s), None) => StackSpec::from_manifest(s),
        _ => Err(Error::Manifest {
            source_name: name,
            message: "want exactly one RobotStack".into(),
        }),
    }
}

/// The runtime options these arguments describe.
pub fn options(args: &AgentArgs) -> Result<RuntimeOptions> {
    if let Some(addr) = args.tcp
        && args.token.as_deref().is_none_or(|t| t.trim().is_empty())
    {
        return Err(Error::InvalidConfig(format!(
            "--tcp {addr} needs a bearer token (not blank): pass --token or set CONFIGBOT_AGENT_TOKEN"
        )));
    }
    Ok(RuntimeOptions {
        settings: args.settings()?,
        data_plane: (!args.no_ros).then(|| DataPlaneOptions {
            backend: DEFAULT_BACKEND.into(),
            uri: args.ros_master_uri.clone(),
            bind_host: args.ros_bind.clone(),
            adaptor_bind_host: args.ros_adaptor_bind.clone(),
            db_path: args.ros_db.clone(),
            policy: configbot_api::policy::PolicyConfig::default(),
            refresh_period: None,
        }),
        monitor: args.monitor.preference(),
    })
}

/// Runs the node runtime until SIGINT or SIGTERM, then shuts down
/// (processes keep running).
pub async fn run(args: AgentArgs) -> Result<()> {
    let opts = options(&args)?;
    let stack = match &args.stack {
        Some(p) => read_stack(p)?,
        None => crate::state::load(&opts.settings.state_file)?
            .and_then(|s| s.stack)
            .unwrap_or_default(),
    };
    let layout = Layout::detect().map_err(io_on("/proc/self/mountinfo"))?;
    let backend = open_backend(&layout, opts.settings.cgroup_root.clone())?;
    let rt = NodeRuntime::start(backend, opts, stack).await?;
    tracing::info!(
        monitor = %rt.monitor_status(),
        ros_master = rt.master_uri().as_deref().unwrap_or("disabled"),
        "node agent started"
    );
    // However serving ends, the runtime shuts down (and lifts limits when
    // asked to).
    let served = serve(&rt, &args).await;
    rt.shutdown().await;
    served
}

/// Serves the API on the Unix socket (and on TCP when asked) until SIGINT,
/// SIGTERM or a server's failure, which names its address; then removes the
/// socket.
async fn serve(rt: &NodeRuntime, args: &AgentArgs) -> Result<()> {
    let unix = crate::api::bind_unix(&args.socket).map_err(io_on(&args.socket))?;
    let served = async {
        let mut servers = tokio::task::JoinSet::new();
        let socket = args.socket.clone();
        let api = crate::api::serve_unix(rt.clone(), unix);
        servers.spawn(async move { (socket, api.await) });
        if let Some(addr) = args.tcp {
            let token = args.token.clone().unwrap_or_default();
            let at = PathBuf::from(addr.to_string());
            let l = tokio::net::TcpListener::bind(addr)
                .await
                .map_err(io_on(&at))?;
            let api = crate::api::serve_tcp(rt.clone(), l, token);
            servers.spawn(async move { (at, api.await) });
        }
        let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
            .map_err(io_on("SIGTERM"))?;
        tokio::select! {
            _ = tokio::signal::ctrl_c() => Ok(()),
            _ = term.recv() => Ok(()),
            Some(res) = servers.join_next() => match res {
                Ok((path, Err(source))) => Err(Error::Io { path, source }),
                _ => Ok(()),
            },
        }
    }
    .await;
    let _ = std::fs::remove_file(&args.socket);
    served
}

/// An IO error's mapping that names `path`.
fn io_on(path: impl AsRef<Path>) -> impl FnOnce(std::io::Error) -> Error {
    let path = path.as_ref().to_path_buf();
    move |source| Error::Io { path, source }
}

#[cfg(test)]
mod tests {
    use clap::Parser;

    use super::*;

    #[derive(Parser)]
    struct Cmd {
        #[command(flatten)]
        agent: AgentArgs,
    }

    fn args(argv: &[&str]) -> AgentArgs {
        Cmd::try_parse_from(std::iter::once("agent").chain(argv.iter().copied()))
            .unwrap()
            .agent
    }

    /// A TCP API without a token is refused before anything starts, and the
    /// error names the address and both ways to give one.
    #[test]
    fn tcp_without_a_token_is_refused_up_front() {
        let mut a = args(&["--tcp", "127.0.0.1:9443"]);
        a.token = None; // whatever CONFIGBOT_AGENT_TOKEN the test runs with
        let msg = options(&a).expect_err("refused").to_string();
        assert!(msg.contains("--tcp 127.0.0.1:9443"), "{msg}");
        assert!(
            msg.contains("--token") && msg.contains("CONFIGBOT_AGENT_TOKEN"),
            "{msg}"
        );
        a.token = Some(String::new());
        assert!(options(&a).is_err(), "an empty token is no token");
        a.token = Some(" \t\n".into());
        assert!(options(&a).is_err(), "a blank token is no token");
        a.token = Some("s3cret".into());
        assert!(options(&a).is_ok());
        let mut unix_only = args(&[]);
        unix_only.token = None;
        assert!(options(&unix_only).is_ok());
    }
}
