//! The `configbot` program: argument definitions and dispatch of every
//! command, the control plane (`serve`, from `configbot-controller`), the
//! node agent (`agent`, from `configbot-agent`), the client commands against
//! the API (`apply`, `get`, `describe`, `delete`; [`client`]), the offline
//! `validate`, and the `demo` and `bench` with their reports ([`report`]).

mod apply;
mod bench;
pub mod client;
mod delete;
mod demo;
mod get;
mod output;
pub mod report;
mod robot;
mod stale;

use std::path::PathBuf;

use crate::client::{Client, Endpoint};
use clap::{Args, Parser, Subcommand};

const AFTER_HELP: &str = "\
Examples:
  configbot serve                                  # control plane on /run/configbot/configbot.sock
  configbot apply -f manifests/examples/           # apply every manifest in a folder
  configbot get rs                                 # list RobotStacks
  configbot get pspec basic-nav -o yaml            # one PerformanceSpec with its status
  configbot get pspec -w                           # watch changes
  configbot describe pspec basic-nav               # conditions and recent events
  configbot validate -f my-stack.yaml              # offline check, no server needed
  kubectl --server https://127.0.0.1:8443 --certificate-authority /var/lib/configbot/tls.crt \\
          --token \"$(cat token)\" get rs         # stock kubectl works too (serve --listen)

Kinds: robotstack (rs), performancespec (pspec), configprofile (cprof).";

/// ConfigBot finds and keeps a resource configuration (CPU limits, data-flow
/// rates) that makes a ROS robot stack meet its PerformanceSpec.
#[derive(Debug, Parser)]
#[command(name = "configbot", version, after_help = AFTER_HELP)]
pub struct Cli {
    /// Control plane socket: unix:///path/to.sock (remote access: kubectl over HTTPS).
    #[arg(
        long,
        global = true,
        env = "CONFIGBOT_SERVER",
        default_value = "unix:///run/configbot/configbot.sock"
    )]
    server: String,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run the control plane (API server, store and reconcilers).
    Serve(ServeArgs),
    /// Create or update objects from YAML files, folders or standard input.
    #[command(
        after_help = "Every document is validated before anything is sent: a bad file applies nothing.\n\nExamples:\n  configbot apply -f manifests/examples/\n  cat stack.yaml | configbot apply -f -\n  configbot apply -f fleet/ --prune -l fleet=lab   # delete labelled objects not in fleet/"
    )]
    Apply(apply::ApplyArgs),
    /// List objects or show one.
    #[command(
        after_help = "Examples:\n  configbot get rs\n  configbot get pspec basic-nav -o yaml\n  configbot get pspec -w"
    )]
    Get(get::GetArgs),
    /// Show an object's spec summary, conditions and recent events.
    Describe(get::DescribeArgs),
    /// Delete objects: by name, by label selector (-l) or as named in files (-f).
    #[command(
        after_help = "Examples:\n  configbot delete pspec basic-nav\n  configbot delete rs -l fleet=lab\n  configbot delete -f manifests/examples/basic-nav.yaml --dry-run"
    )]
    Delete(delete::DeleteArgs),
    /// Check manifests offline (no server needed); exits 1 on any error.
    Validate(ValidateArgs),
    /// Run an example stack on this machine, show the default config failing,
    /// tune it live and print a before/after table with plots.
    Demo(demo::DemoArgs),
    /// Reproduce the paper's comparison: default, random, CPU-only and full
    /// ConfigBot configs on each example stack (table, JSON, plots).
    #[command(
        after_help = "Examples:\n  configbot bench                       # all stacks, 30 s windows (about 30 min)\n  configbot bench --stacks basic-nav --window-secs 10\n  configbot bench --quick --out /tmp/b  # CI: shape of the output only"
    )]
    Bench(bench::BenchArgs),
    /// Run the node agent alone on a robot: per-node cgroups, process
    /// supervision, the process monitor and the robot's ROS 1 master.
    #[command(
        after_help = "The control plane drives it over its API (Unix socket, or TCP with --token).\n\nExamples:\n  configbot agent --stack stack.yaml                  # supervise a RobotStack\n  configbot agent --ros-master-uri http://localhost:11311/ --tcp 0.0.0.0:9443 --token \"$TOKEN\""
    )]
    Agent(configbot_agent::cli::AgentArgs),
    /// Print a shell completion script (bash, zsh, fish, elvish or powershell).
    #[command(
        after_help = "Examples:\n  source <(configbot completion bash)\n  configbot completion zsh > \"${fpath[1]}/_configbot\"\n  configbot completion fish > ~/.config/fish/completions/configbot.fish"
    )]
    Completion { shell: clap_complete::Shell },
    /// Run a simulated ROS 1 node (periodic publishers, CPU-costed callbacks);
    /// the example stacks are made of these.
    Simnode(configbot_simnode::SimnodeArgs),
}

#[derive(Debug, Args)]
struct ServeArgs {
    /// Database file (SQLite); created if missing.
    #[arg(
        long,
        env = "CONFIGBOT_DB",
        default_value = "/var/lib/configbot/configbot.db"
    )]
    db: PathBuf,
    /// Unix socket to serve on (mode 0600).
    #[arg(long, default_value = "/run/configbot/configbot.sock")]
    socket: PathBuf,
    /// Also listen on HTTPS at this address (requires --token-file), e.g.
    /// 127.0.0.1:8443 for this host only or 0.0.0.0:8443 for every interface.
    /// Without it the API is only on the Unix socket.
    #[arg(long, requires = "token_file")]
    listen: Option<String>,
    /// File holding the bearer token TCP clients must send.
    #[arg(long)]
    token_file: Option<PathBuf>,
    #[command(flatten)]
    robot: RobotArgs,
}

/// Which robot `serve` drives; without `--agent` or `--agent-socket` it
/// stores and validates manifests but tunes nothing.
#[derive(Debug, Args)]
pub struct RobotArgs {
    /// Run the node agent in this process (one-robot setup): it runs the newest
    /// RobotStack's nodes in their cgroups and is the robot's ROS master. Its
    /// files live beside the database (agent-state.json, ros1.db, logs/).
    #[arg(long)]
    pub agent: bool,
    /// Drive a node agent that runs alone (`configbot agent`) at this Unix socket.
    #[arg(long, conflicts_with = "agent")]
    pub agent_socket: Option<PathBuf>,
    /// With --agent: the agent's subtree in the cpu cgroup hierarchies.
    #[arg(long, default_value = "configbot")]
    pub cgroup_root: String,
    /// With --agent: the robot's ROS_MASTER_URI, served by the agent.
    #[arg(long, default_value = "http://localhost:11311/")]
    pub ros_master_uri: String,
    /// With --agent: address the ROS master listens on. The default, every
    /// interface, is what rosmaster does, so nodes on other hosts can
    /// register; 127.0.0.1 keeps it to this host.
    #[arg(long, default_value = configbot_ros1::DEFAULT_MASTER_BIND)]
    pub ros_bind: String,
    /// With --agent: address the ROS rate adaptors (slave XML-RPC and TCPROS)
    /// listen on; adapted subscribers on this host reach them at localhost,
    /// so the default is loopback.
    #[arg(long, default_value = configbot_ros1::DEFAULT_ADAPTOR_BIND)]
    pub ros_adaptor_bind: String,
    /// With --agent: no ROS data plane (CPU knobs only).
    #[arg(long)]
    pub no_ros: bool,
    /// With --agent: the process monitor.
    #[arg(long, value_enum, default_value_t = configbot_agent::cli::MonitorChoice::Auto)]
    pub monitor: configbot_agent::cli::MonitorChoice,
    /// With --agent: CPU weight of the robot's nodes together against the
    /// host's other services (1–10000, cgroup v2 units; a service has 100;
    /// v1 cpu.shares = weight × 10.24). Unset: the kernel's default.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=10_000))]
    pub subtree_cpu_weight: Option<u32>,
}

#[derive(Debug, Args)]
struct ValidateArgs {
    /// Files or folders (recursive); `-` for standard input.
    #[arg(short = 'f', long = "filename", required = true)]
    files: Vec<String>,
}

pub fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    configbot_agent::cli::init_logging();
    let rt = match tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("error: cannot start the runtime: {e}");
            return std::process::ExitCode::FAILURE;
        }
    };
    match rt.block_on(run(cli)) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn client(cli: &Cli) -> anyhow::Result<Client> {
    Ok(Client::new(
        Endpoint::parse(&cli.server).map_err(anyhow::Error::msg)?,
    ))
}

async fn run(cli: Cli) -> anyhow::Result<std::process::ExitCode> {
    use std::process::ExitCode;
    match &cli.command {
        Command::Serve(a) => {
            let tcp = match (&a.listen, &a.token_file) {
                (Some(addr), Some(f)) => {
                    let token = std::fs::read_to_string(f)
                        .map_err(|e| anyhow::anyhow!("token file {}: {e}", f.display()))?
                        .trim()
                        .to_string();
                    anyhow::ensure!(!token.is_empty(), "token file {} is empty", f.display());
                    Some((addr.clone(), token))
                }
                _ => None,
            };
            let cfg = configbot_controller::server::ServerConfig {
                db: a.db.clone(),
                socket: a.socket.clone(),
                tcp,
            };
            let (server, runtime) = robot::start_server(&cfg, &a.robot).await?;
            eprintln!(
                "configbot: serving on {} (database {})",
                a.socket.display(),
                a.db.display()
            );
            if let Some(addr) = &a.listen {
                eprintln!(
                    "configbot: also serving on https://{addr} (bearer token required; certificate {})",
                    a.db.with_file_name("tls.crt").display()
                );
            }
            shutdown_signal().await;
            server.stop();
            if let Some(rt) = runtime {
                // Nodes keep running: a restarted server re-adopts them.
                rt.shutdown().await;
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Apply(a) => apply::run(&client(&cli)?, a).await,
        Command::Get(a) => get::get(&client(&cli)?, a).await,
        Command::Describe(a) => get::describe(&client(&cli)?, a).await,
        Command::Delete(a) => delete::run(&client(&cli)?, a).await,
        Command::Validate(a) => match apply::load_all(&a.files, "validate") {
            Ok(loaded) => {
                for l in &loaded {
                    println!(
                        "{}: document {}: {} {:?} is valid",
                        l.source,
                        l.document,
                        l.manifest.kind(),
                        l.manifest.metadata().name
                    );
                }
                Ok(ExitCode::SUCCESS)
            }
            Err(e) => {
                eprintln!("{e}");
                Ok(ExitCode::FAILURE)
            }
        },
        Command::Completion { shell } => {
            use clap::CommandFactory;
            use std::io::Write;
            // Into a buffer first: clap_complete panics when its writer fails
            // (e.g. `configbot completion bash | head`).
            let mut script = Vec::new();
            clap_complete::generate(*shell, &mut Cli::command(), "configbot", &mut script);
            match std::io::stdout().write_all(&script) {
                Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => {
                    Err(anyhow::anyhow!("writing the completion script: {e}"))
                }
                _ => Ok(ExitCode::SUCCESS),
            }
        }
        Command::Demo(a) => demo::run(a).await,
        Command::Bench(a) => bench::run(a).await,
        Command::Simnode(a) => {
            configbot_simnode::run(a.clone()).await?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Agent(a) => {
            configbot_agent::cli::run(a.clone()).await?;
            Ok(ExitCode::SUCCESS)
        }
    }
}

/// Resolves on Ctrl-C or SIGTERM.
pub(crate) async fn shutdown_signal() {
    let mut term = match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
        Ok(s) => s,
        Err(_) => return std::future::pending().await,
    };
    tokio::select! {
        _ = tokio::signal::ctrl_c() => {}
        _ = term.recv() => {}
    }
}
