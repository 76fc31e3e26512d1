//! `configbot simnode`: a configurable ROS 1 node that models robot apps
//! with real CPU work. It speaks real TCPROS and the XML-RPC master/slave
//! APIs (rospy, rostopic, rosnode, the real rosmaster and
//! `configbot-ros1-master` all talk to it), publishes
//! `std_msgs/UInt8MultiArray` messages periodically (`--publish`), and
//! answers messages with callbacks (`--on`) served by a shared worker pool
//! (`--workers`) or by a thread per message (`--thread-per-message`).
//! Entry points: [`SimnodeArgs`] (clap) and [`run`].

pub mod burn;
pub mod dispatch;
pub mod msg;
pub mod node;
pub mod publish;
pub mod slave;
pub mod spec;

use std::time::Duration;

pub use spec::{CallbackSpec, PublishSpec};

/// Errors of running a simnode.
#[derive(Debug, thiserror::Error)]
pub enum SimnodeError {
    #[error("bad master uri {0:?} (want http://host:port/)")]
    BadMasterUri(String),
    #[error("bad node name")]
    Name(#[source] spec::SpecError),
    #[error("binding the {what}")]
    Bind {
        what: &'static str,
        #[source]
        source: std::io::Error,
    },
    #[error("starting a simnode thread")]
    Spawn(#[source] std::io::Error),
    #[error("installing the SIGTERM handler")]
    Signal(#[source] std::io::Error),
}

const EXAMPLES: &str = "\
Semantics:
  --publish TOPIC:HZ:BYTES   a timer thread publishes on TOPIC at HZ, each message
                             preceded by --cost-ms-per-msg of real CPU work; a
                             CPU-starved publisher falls behind (missed ticks are
                             skipped, not caught up), as a real driver does.
  --on IN->OUT:cost-ms=C[,bytes=B]
                             on each message of IN, burn C ms of this thread's CPU
                             time, then publish one message on OUT (data size B,
                             default: the input's), carrying the input's stamp.
  --workers N                callbacks share N worker threads (default 1); each
                             callback has a queue of 1 (newest message wins, like
                             queue_size=1) and never runs on two workers at once,
                             so a heavy callback delays a light one in the pool.
  --thread-per-message       every incoming message gets its own thread (up to
                             --max-threads, 0 = unbounded); under a CPU limit the
                             threads pile up and share the CPU (oversubscription).
  --contention-pct P         with --thread-per-message: a message that starts while
                             k others run costs C x (1 + P/100 x k) of CPU, so an
                             oversubscribed detector also does less per CPU second
                             (the paper's compounding penalty, Fig. 2b).
Costs are CPU time (CLOCK_THREAD_CPUTIME_ID), never sleeps: under cgroup throttling
wall time stretches and rates fall. Messages are std_msgs/UInt8MultiArray; the data
array starts with seq (u64 LE) and the source stamp (ns since epoch, u64 LE).
The master is $ROS_MASTER_URI (default http://localhost:11311/); the host in the
node's URIs is $ROS_HOSTNAME, else $ROS_IP, else the machine's host name.

Examples:
  # a 40 Hz LiDAR driver, 4 KiB scans, 2 ms of CPU per scan
  configbot simnode --name /lidar --publish /scan:40:4096 --cost-ms-per-msg 2
  # navigation: two callbacks sharing a pool of 2 workers (Task 1 core, Task 2 debug)
  configbot simnode --name /navigation --workers 2 \\
      --on '/scan->/cmd_vel:cost-ms=9' --on '/image->/goal_image:cost-ms=25'
  # an object detector that spawns a thread per camera frame
  configbot simnode --name /detector --thread-per-message --contention-pct 15 \\
      --on '/image->/detections:cost-ms=150,bytes=256'
  # watch them with the real tools
  rostopic hz /cmd_vel; rosnode info /navigation
";

/// Command line of a simnode (`configbot simnode ...`).
#[derive(Debug, Clone, clap::Args)]
#[command(after_long_help = EXAMPLES)]
pub struct SimnodeArgs {
    /// The node's ROS name (e.g. /lidar); relative names go in the root namespace.
    #[arg(long)]
    pub name: String,
    /// Periodic publisher TOPIC:HZ:BYTES (repeatable), e.g. /scan:40:4096.
    #[arg(long, value_name = "TOPIC:HZ:BYTES")]
    pub publish: Vec<PublishSpec>,
    /// CPU milliseconds of work before each periodic publish.
    #[arg(long, value_name = "MS", default_value_t = 0.0)]
    pub cost_ms_per_msg: f64,
    /// Callback IN->OUT:cost-ms=C[,bytes=B] (repeatable), e.g. /scan->/cmd_vel:cost-ms=9.
    #[arg(long = "on", value_name = "IN->OUT:cost-ms=C")]
    pub on: Vec<CallbackSpec>,
    /// Worker threads shared by all callbacks (default 1).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=1024), conflicts_with = "thread_per_message")]
    pub workers: Option<u32>,
    /// Run each incoming message on its own thread (the paper's object detector).
    #[arg(long)]
    pub thread_per_message: bool,
    /// With --thread-per-message: most threads at once; messages beyond are dropped (0 = unbounded).
    #[arg(long, value_name = "N", default_value_t = 10)]
    pub max_threads: usize,
    /// With --thread-per-message: each message costs PCT % more CPU per other
    /// message thread running when it starts (cache and memory-bandwidth
    /// contention between parallel inference threads).
    #[arg(
        long,
        value_name = "PCT",
        default_value_t = 0.0,
        requires = "thread_per_message"
    )]
    pub contention_pct: f64,
    /// ROS master URI.
    #[arg(
        long,
        env = "ROS_MASTER_URI",
        default_value = "http://localhost:11311/"
    )]
    pub master_uri: String,
    /// Print per-topic and per-callback rates to stderr every SECS seconds.
    #[arg(long, value_name = "SECS")]
    pub stats_secs: Option<f64>,
}

/// The host name other nodes use to reach this one: ROS_HOSTNAME, else
/// ROS_IP, else the machine's host name (pure; inputs passed in).
pub fn advertised_host(
    ros_hostname: Option<&str>,
    ros_ip: Option<&str>,
    hostname: Option<&str>,
) -> String {
    [ros_hostname, ros_ip, hostname]
        .into_iter()
        .flatten()
        .map(str::trim)
        .find(|h| !h.is_empty())
        .unwrap_or("localhost")
        .to_string()
}

impl SimnodeArgs {
    /// Resolves the arguments and the environment into a node config.
    pub fn config(&self) -> Result<node::NodeConfig, SimnodeError> {
        if configbot_ros1::http::parse_uri(&self.master_uri).is_none() {
            return Err(SimnodeError::BadMasterUri(self.master_uri.clone()));
        }
        let env = |k| std::env::var(k).ok();
        let hostname = std::fs::read_to_string("/proc/sys/kernel/hostname").ok();
        Ok(node::NodeConfig {
            name: spec::resolve(&self.name).map_err(SimnodeError::Name)?,
            master_uri: self.master_uri.clone(),
            host: advertised_host(
                env("ROS_HOSTNAME").as_deref(),
                env("ROS_IP").as_deref(),
                hostname.as_deref(),
            ),
            publish: self.publish.clone(),
            cost_ms_per_msg: self.cost_ms_per_msg,
            callbacks: self.on.clone(),
            workers: if self.thread_per_message {
                None
            } else {
                Some(self.workers.unwrap_or(1) as usize)
            },
            max_threads: self.max_threads,
            contention_pct: self.contention_pct,
            stats_every: self
                .stats_secs
                .filter(|s| s.is_finite() && *s > 0.0)
                .map(Duration::from_secs_f64),
            call_timeout: Duration::from_secs(3),
        })
    }
}

/// Runs a simnode until SIGINT, SIGTERM or a slave-API `shutdown`, then
/// unregisters from the master and returns. Needs a tokio runtime (any
/// flavour; CPU work runs on its own threads, never on the runtime's).
pub async fn run(args: SimnodeArgs) -> Result<(), SimnodeError> {
    node::run_node(args.config()?).await
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Debug, Parser)]
    struct Cli {
        #[command(flatten)]
        args: SimnodeArgs,
    }

    #[test]
    fn parses_the_example_command_lines() {
        let c = Cli::try_parse_from([
            "x",
            "--name",
            "/navigation",
            "--workers",
            "2",
            "--on",
            "/scan->/cmd_vel:cost-ms=9",
            "--on",
            "/image->/goal_image:cost-ms=25",
        ])
        .unwrap();
        assert_eq!(c.args.workers, Some(2));
        assert_eq!(c.args.on.len(), 2);
        assert_eq!(c.args.on[1].cost_ms, 25.0);
        let c = Cli::try_parse_from([
            "x",
            "--name",
            "/lidar",
            "--publish",
            "/scan:40:4096",
            "--cost-ms-per-msg",
            "2",
        ])
        .unwrap();
        assert_eq!(c.args.publish[0].hz, 40.0);
        assert_eq!(c.args.cost_ms_per_msg, 2.0);
        let cfg = c.args.config().unwrap();
        assert_eq!(cfg.workers, Some(1));
        assert!(
            Cli::try_parse_from([
                "x",
                "--name",
                "/d",
                "--thread-per-message",
                "--workers",
                "2"
            ])
            .is_err()
        );
        assert!(Cli::try_parse_from(["x", "--name", "/d", "--workers", "0"]).is_err());
        assert!(Cli::try_parse_from(["x", "--name", "/d", "--on", "/a:cost-ms=1"]).is_err());
        let c = Cli::try_parse_from([
            "x",
            "--name",
            "d",
            "--thread-per-message",
            "--master-uri",
            "nope",
        ])
        .unwrap();
        assert!(matches!(
            c.args.config(),
            Err(SimnodeError::BadMasterUri(_))
        ));
    }

    #[derive(Debug, Parser)]
    struct Main {
        #[command(subcommand)]
        cmd: Cmd,
    }

    #[derive(Debug, clap::Subcommand)]
    enum Cmd {
        /// Run a simulated ROS 1 node.
        Simnode(SimnodeArgs),
    }

    #[test]
    fn long_help_teaches_when_used_as_a_subcommand() {
        use clap::CommandFactory;
        let mut c = Main::command();
        let sub = c.find_subcommand_mut("simnode").unwrap();
        let help = sub.render_long_help().to_string();
        assert!(
            help.contains("Examples:") && help.contains("--thread-per-message"),
            "{help}"
        );
        let m = Main::try_parse_from([
            "configbot",
            "simnode",
            "--name",
            "/a",
            "--publish",
            "/t:1:16",
        ])
        .unwrap();
        let Cmd::Simnode(a) = m.cmd;
        assert_eq!(a.publish.len(), 1);
    }

    #[test]
    fn picks_the_advertised_host() {
        assert_eq!(
            advertised_host(Some("a"), Some("1.2.3.4"), Some("h\n")),
            "a"
        );
        assert_eq!(advertised_host(None, Some("1.2.3.4"), Some("h")), "1.2.3.4");
        assert_eq!(advertised_host(Some(""), None, Some("h\n")), "h");
        assert_eq!(advertised_host(None, None, None), "localhost");
    }
}
