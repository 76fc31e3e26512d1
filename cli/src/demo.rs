//! `configbot demo`: on any Linux machine with root, start a private control
//! plane with its embedded node agent, run the Basic-NAV stack with the object
//! detector (simulated ROS nodes doing real CPU work), show the default config
//! failing its core constraint, tune it live, and end with a before/after
//! table and plots. Everything it starts is stopped and removed at the end.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::time::{Duration, Instant};

use clap::Args;
use configbot_agent::agent::NodeStatus;
use configbot_api::graph::Graph;
use configbot_api::measure::MeasureReport;
use configbot_manifests::performance_spec::TrialStatus;
use configbot_manifests::{
    Kind, Manifest, PerformanceSpec, PerformanceSpecStatus, Phase, RobotStack, decode_status,
};
use serde_json::{Value, json};

use super::RobotArgs;
use crate::client::{Client, Endpoint};
use crate::report::svg::{Chart, Mark, Rule, Series, colors};
use configbot_controller::robot::EmbeddedRobot;
use configbot_controller::server::{Server, ServerConfig};
use configbot_controller::tuning::robot::{NodeApi, Robot};
use configbot_tuning::measure::{self, MetricDef};

/// The example stacks, embedded so the demo runs from any directory.
pub const EXAMPLES: [(&str, &str); 6] = [
    (
        "basic-nav.yaml",
        include_str!("../../manifests/examples/basic-nav.yaml"),
    ),
    (
        "intermed-nav.yaml",
        include_str!("../../manifests/examples/intermed-nav.yaml"),
    ),
    (
        "terrain-nav.yaml",
        include_str!("../../manifests/examples/terrain-nav.yaml"),
    ),
    (
        "real-perception.yaml",
        include_str!("../../manifests/examples/real/perception.yaml"),
    ),
    (
        "real-nodelets.yaml",
        include_str!("../../manifests/examples/real/nodelets.yaml"),
    ),
    (
        "real-two-paths.yaml",
        include_str!("../../manifests/examples/real/two-paths.yaml"),
    ),
];

#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Example stack to run: basic-nav, intermed-nav or terrain-nav.
    #[arg(long, default_value = "basic-nav")]
    stack: String,
    /// Where to write the report (summary.json and the plots); default: a new
    /// folder under the system's temp dir.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Seconds of measurement before and after tuning.
    #[arg(long, default_value_t = 15)]
    window_secs: u64,
    /// Give up tuning after this many seconds.
    #[arg(long, default_value_t = 600)]
    timeout_secs: u64,
    /// Leave the stack running afterwards (until Ctrl-C).
    #[arg(long)]
    keep: bool,
    /// CPU weight of the robot's nodes together against this machine's other
    /// work (1–10000, cgroup v2 units; a service has 100). Unset: the
    /// kernel's default, as the stack was calibrated with. A high weight
    /// shields the nodes from other work. On cgroup v1 the data plane's
    /// threads (meters, adaptor relays) are in the subtree with them; on v2
    /// they stay in this process's cgroup and fall behind (measured while
    /// they were outside on v1 too: the Basic-NAV default read 55 %
    /// satisfaction at 6400 instead of 10 %).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=10_000))]
    subtree_cpu_weight: Option<u32>,
}

/// The stack and spec of an example, with `command: configbot` pointed at this program.
pub fn example(name: &str) -> anyhow::Result<(RobotStack, PerformanceSpec)> {
    let file = format!("{name}.yaml");
    let (_, text) = EXAMPLES.iter().find(|(f, _)| *f == file).ok_or_else(|| {
        anyhow::anyhow!("no example stack {name:?} (basic-nav, intermed-nav, terrain-nav, real-perception, real-nodelets, real-two-paths)")
    })?;
    let exe = std::env::current_exe()?;
    let text = text.replace(
        "command: configbot\n",
        &format!("command: {}\n", exe.display()),
    );
    let mut stack = None;
    let mut spec = None;
    for l in configbot_manifests::load(&file, &text)? {
        match l.manifest {
            Manifest::RobotStack(s) => stack = Some(s),
            Manifest::PerformanceSpec(s) => spec = Some(s),
            _ => {}
        }
    }
    match (stack, spec) {
        (Some(a), Some(b)) => Ok((a, b)),
        _ => anyhow::bail!("{file} needs a RobotStack and a PerformanceSpec"),
    }
}

/// A private robot: control plane + embedded agent in a temp dir, with its
/// own cgroup subtree (of CPU weight `cpu_weight`, default the kernel's) and
/// ROS master port. `close` removes everything; `start` first removes the
/// roots a killed demo or bench left ([`crate::stale`]).
pub struct PrivateRobot {
    pub dir: PathBuf,
    pub server: Server,
    pub robot: Arc<EmbeddedRobot>,
    pub client: Client,
    pub master_uri: String,
}

impl PrivateRobot {
    pub async fn start(dir: &Path, cpu_weight: Option<u32>) -> anyhow::Result<PrivateRobot> {
        std::fs::create_dir_all(dir)?;
        sweep_stale_roots().await;
        let port = std::net::TcpListener::bind("127.0.0.1:0")?
            .local_addr()?
            .port();
        let master_uri = format!("http://localhost:{port}/");
        let args = RobotArgs {
            agent: true,
            agent_socket: None,
            cgroup_root: crate::stale::private_root(std::process::id()),
            ros_master_uri: master_uri.clone(),
            // A private robot: its master is for this host's nodes only.
            ros_bind: "127.0.0.1".into(),
            ros_adaptor_bind: configbot_ros1::DEFAULT_ADAPTOR_BIND.into(),
            no_ros: false,
            monitor: configbot_agent::cli::MonitorChoice::Auto,
            subtree_cpu_weight: cpu_weight,
        };
        let rt = super::robot::start_runtime(&dir.join("agent"), &args).await?;
        let robot = Arc::new(EmbeddedRobot::new(rt));
        let cfg = ServerConfig {
            db: dir.join("configbot.db"),
            socket: dir.join("configbot.sock"),
            tcp: None,
        };
        let server = Server::start_with_robot(&cfg, robot.clone()).await?;
        Ok(PrivateRobot {
            dir: dir.to_path_buf(),
            server,
            robot,
            client: Client::new(Endpoint::Unix(cfg.socket)),
            master_uri,
        })
    }

    /// Stops the control plane, every node, and removes the cgroups.
    pub async fn close(self) -> anyhow::Result<()> {
        self.server.stop();
        self.robot.runtime().agent().teardown().await?;
        self.robot.runtime().shutdown().await;
        Ok(())
    }

    pub async fn apply(&self, obj: &Value, kind: Kind) -> anyhow::Result<()> {
        super::apply::apply_one(&self.client, obj, kind, false).await?;
        Ok(())
    }
}

/// Removes what a killed demo or bench left in the cgroups ([`crate::stale`]),
/// saying so; a root that cannot be removed is a warning, not a failure.
async fn sweep_stale_roots() {
    let swept = match tokio::task::spawn_blocking(crate::stale::sweep).await {
        Ok(Ok(s)) => s,
        Ok(Err(e)) => {
            eprintln!("warning: looking for stale cgroup roots: {e:#}");
            return;
        }
        Err(e) => {
            eprintln!("warning: looking for stale cgroup roots: {e}");
            return;
        }
    };
    for (root, done) in swept {
        match done {
            Ok(()) => eprintln!("    removed the cgroup root {root}: its demo or bench is gone"),
            Err(e) => eprintln!("warning: cannot remove the stale cgroup root {root}: {e:#}"),
        }
    }
}

impl PrivateRobot {
    /// The stack as the agent sees it, for an error about topics that do
    /// not flow: [`describe_stack`] of its nodes and ROS graph.
    pub async fn describe(&self) -> String {
        let rt = self.robot.runtime();
        let (nodes, graph) = (rt.inventory().await, rt.graph().await);
        let mut text = describe_stack(
            nodes.as_deref().unwrap_or_default(),
            graph.as_ref().unwrap_or(&Graph::default()),
        );
        if let Err(e) = nodes {
            text += &format!("\n    (no node inventory: {e})");
        }
        if let Err(e) = graph {
            text += &format!("\n    (no ROS graph: {e})");
        }
        text
    }
}

/// Each node's processes and restarts, and each topic's registered
/// publishers and subscribers (pure): tells a node that died or never
/// registered from a connection that never formed.
pub fn describe_stack(nodes: &[NodeStatus], graph: &Graph) -> String {
    let mut out = String::new();
    for n in nodes {
        let state = match (n.stopped, n.frozen, n.main_pid) {
            (true, _, _) => "stopped".to_string(),
            (_, true, _) => "frozen".to_string(),
            (_, _, Some(pid)) => format!("pid {pid}"),
            (_, _, None) => "no process".to_string(),
        };
        out += &format!(
            "\n    node {} ({}): {state}, {} restarts, {:.2} CPU",
            n.name, n.app, n.restarts, n.cpu_usage_cpus
        );
    }
    for t in graph.topics.values() {
        let names = |s: &std::collections::BTreeSet<String>| {
            s.iter().map(String::as_str).collect::<Vec<_>>().join(" ")
        };
        out += &format!(
            "\n    topic {}: published by [{}], subscribed by [{}]",
            t.name,
            names(&t.publishers),
            names(&t.subscribers)
        );
    }
    out
}

/// Measures `defs` for `secs` seconds in 1 s windows.
pub async fn measure_defs(
    robot: &dyn Robot,
    defs: &[MetricDef],
    secs: u64,
) -> anyhow::Result<MeasureReport> {
    let mut req = measure::request(defs, &[], secs * 1000, 1000);
    req.probes.extend(measure::latency_probes(defs));
    Ok(robot.measure(&req).await?)
}

/// Waits until every `defs` topic delivers messages (the stack is up).
pub async fn wait_for_flow(robot: &dyn Robot, defs: &[MetricDef], timeout: Duration) -> bool {
    let deadline = Instant::now() + timeout;
    while Instant::now() < deadline {
        if let Ok(r) = measure_defs(robot, defs, 1).await
            && defs
                .iter()
                .all(|d| r.series.iter().any(|s| s.probe == d.probe && s.mean > 0.0))
        {
            return true;
        }
    }
    false
}

pub async fn run(a: &DemoArgs) -> anyhow::Result<ExitCode> {
    let (stack, spec) = example(&a.stack)?;
    let out = a.out.clone().unwrap_or_else(|| {
        std::env::temp_dir().join(format!("configbot-demo-{}", std::process::id()))
    });
    println!(
        "==> ConfigBot demo: {} on this machine ({} CPUs)",
        a.stack,
        configbot_controller::tuning::runner::machine_cpus()
    );
    println!("    report folder {}", out.display());
    // A fresh robot every time: no stack, registrations or library from a previous run.
    let state = out.join("state");
    if state.exists() {
        std::fs::remove_dir_all(&state)?;
    }
    let robot = PrivateRobot::start(&state, a.subtree_cpu_weight).await?;
    // Ctrl-C or SIGTERM mid-run still stops the nodes and removes the cgroups.
    let result = tokio::select! {
        r = demo(a, &robot, &stack, &spec, &out) => r,
        _ = super::shutdown_signal() => Err(anyhow::anyhow!("interrupted")),
    };
    if a.keep && result.is_ok() {
        println!(
            "\nThe stack keeps running: configbot --server unix://{} get trials {}   (ROS_MASTER_URI={}; Ctrl-C to stop)",
            robot.dir.join("configbot.sock").display(),
            spec.metadata.name,
            robot.master_uri
        );
        super::shutdown_signal().await;
    }
    println!("==> stopping the stack and removing its cgroups");
    robot.close().await?;
    result
}

async fn demo(
    a: &DemoArgs,
    robot: &PrivateRobot,
    stack: &RobotStack,
    spec: &PerformanceSpec,
    out: &Path,
) -> anyhow::Result<ExitCode> {
    let defs = measure::metric_defs(&stack.spec, &spec.spec);
    println!(
        "==> starting {} nodes ({}) with Linux's defaults (no limits); ROS_MASTER_URI={}",
        stack.spec.nodes().count(),
        stack
            .spec
            .apps
            .iter()
            .map(|x| x.name.as_str())
            .collect::<Vec<_>>()
            .join(", "),
        robot.master_uri
    );
    robot
        .apply(&serde_json::to_value(stack)?, Kind::RobotStack)
        .await?;
    if !wait_for_flow(robot.robot.as_ref(), &defs, Duration::from_secs(60)).await {
        anyhow::bail!(
            "the stack's topics did not start flowing within 60 s (logs: {}):{}",
            robot.dir.join("agent/logs").display(),
            robot.describe().await
        );
    }
    println!("==> measuring the default config for {} s", a.window_secs);
    let before = measure_defs(robot.robot.as_ref(), &defs, a.window_secs).await?;
    print_eval("default", &defs, &before);

    println!("==> applying the PerformanceSpec: ConfigBot tunes the live stack");
    let started = Instant::now();
    robot
        .apply(&serde_json::to_value(spec)?, Kind::PerformanceSpec)
        .await?;
    let name = &spec.metadata.name;
    let status = wait_for_outcome(robot, name, Duration::from_secs(a.timeout_secs)).await?;
    let tuning_secs = started.elapsed().as_secs_f64();
    println!(
        "\n==> {} after {} trials in {tuning_secs:.0} s",
        status.phase, status.trials
    );
    if let Some(r) = &status.reason {
        println!("    {r}");
    }
    println!("==> measuring the tuned config for {} s", a.window_secs);
    let after = measure_defs(robot.robot.as_ref(), &defs, a.window_secs).await?;
    print_eval("configbot", &defs, &after);

    let s = spec.spec.tuning.scalarization;
    let (eb, ea) = (
        measure::evaluate(&defs, &before, s),
        measure::evaluate(&defs, &after, s),
    );
    println!("\n{}", before_after_table(&defs, &eb, &ea));
    std::fs::create_dir_all(out)?;
    let plots = write_plots(out, &defs, &before, &after, &status)?;
    let summary = json!({
        "stack": a.stack, "phase": status.phase, "tuningSeconds": tuning_secs,
        "trials": status.trials, "bestConfig": status.best_config,
        "before": eb, "after": ea, "plots": plots,
    });
    let summary_path = out.join("summary.json");
    std::fs::write(&summary_path, serde_json::to_string_pretty(&summary)?)?;
    println!("report: {}", summary_path.display());
    for p in &plots {
        println!("plot:   {p}");
    }
    Ok(if ea.satisfaction >= 0.99 {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}

/// Polls the spec's status, printing each new trial, until it is settled.
pub async fn wait_for_outcome(
    robot: &PrivateRobot,
    name: &str,
    timeout: Duration,
) -> anyhow::Result<PerformanceSpecStatus> {
    let path = crate::client::path(Kind::PerformanceSpec, Some("default"), Some(name));
    let deadline = Instant::now() + timeout;
    let (mut shown, mut rejected) = (0usize, 0usize);
    loop {
        let st: PerformanceSpecStatus = decode_status(&robot.client.get(&path).await?)?;
        for t in st.trial_history.iter().skip(shown) {
            print_trial(&st, t);
        }
        shown = st.trial_history.len();
        for i in st.rejected_trials.iter().skip(rejected) {
            println!(
                "    trial {} failed verification (a longer window after a settle); looking for a config with margin",
                i + 1
            );
        }
        rejected = st.rejected_trials.len();
        if settled(&st) {
            if let (Some(i), Some(f)) = (st.best_trial, st.best_trial_backoff) {
                println!(
                    "    trial {} holds with its non-core knobs backed off (as safe as all at {:.0} %): {}",
                    i + 1,
                    f * 100.0,
                    configbot_controller::tuning::view::config_text(
                        &st.best_config.clone().unwrap_or_default()
                    )
                );
            }
            return Ok(st);
        }
        anyhow::ensure!(
            Instant::now() < deadline,
            "tuning did not finish within {} s (phase {:?})",
            timeout.as_secs(),
            st.phase.as_str()
        );
        tokio::time::sleep(Duration::from_millis(500)).await;
    }
}

/// One line per measured trial, as the demo and the bench show them.
pub fn print_trial(st: &PerformanceSpecStatus, t: &TrialStatus) {
    println!(
        "    trial {:>2}/{}  satisfaction {:>5.1}%  objective {:>5}  {}  {}",
        t.index + 1,
        st.max_trials.unwrap_or(0),
        t.satisfaction * 100.0,
        t.objective.map_or("-".into(), |o| format!("{o:.3}")),
        if t.feasible {
            "feasible  "
        } else {
            "infeasible"
        },
        configbot_controller::tuning::view::config_text(&t.config),
    );
}

/// Whether a spec's status shows the run's outcome: Unsat, or a monitored best config.
pub fn settled(st: &PerformanceSpecStatus) -> bool {
    match st.phase {
        Phase::Unsat => true,
        Phase::Monitoring | Phase::Satisfied => st.best_config.is_some(),
        _ => false,
    }
}

pub fn print_eval(label: &str, defs: &[MetricDef], r: &MeasureReport) {
    let e = measure::evaluate(defs, r, Default::default());
    let parts: Vec<String> = defs
        .iter()
        .map(|d| {
            format!(
                "{} {:.1}",
                d.name,
                e.means.get(&d.name).copied().unwrap_or(0.0)
            )
        })
        .collect();
    println!(
        "    {label}: constraint satisfaction {:.1}%  ({}){}",
        e.satisfaction * 100.0,
        parts.join(", "),
        latency_text(&measure::latency_peaks(defs, r))
    );
}

/// "; latency peak corners-rate 133 ms (2 windows ≥ 100 ms)" for the core
/// metrics whose messages were seen late (pure); empty when none were.
pub fn latency_text(peaks: &std::collections::BTreeMap<String, Vec<f64>>) -> String {
    let parts: Vec<String> = peaks
        .iter()
        .filter_map(|(name, v)| {
            let peak = v.iter().copied().fold(0.0, f64::max);
            (peak > 0.0).then(|| {
                let late = v.iter().filter(|&&x| x >= 0.1).count();
                format!("{name} {:.0} ms ({late} windows ≥ 100 ms)", peak * 1000.0)
            })
        })
        .collect();
    if parts.is_empty() {
        String::new()
    } else {
        format!("; latency peak {}", parts.join(", "))
    }
}

/// The before/after table (pure).
pub fn before_after_table(
    defs: &[MetricDef],
    before: &measure::Evaluation,
    after: &measure::Evaluation,
) -> String {
    let mut rows = vec![vec![
        "satisfaction (core, 1 s windows)".to_owned(),
        "100%".to_owned(),
        format!("{:.1}%", before.satisfaction * 100.0),
        format!("{:.1}%", after.satisfaction * 100.0),
    ]];
    for d in defs {
        let v = |e: &measure::Evaluation| e.means.get(&d.name).copied().unwrap_or(0.0);
        rows.push(vec![
            format!("{} ({})", d.name, if d.core { "core" } else { "non-core" }),
            d.target_text(),
            format!("{:.1}", v(before)),
            format!("{:.1}", v(after)),
        ]);
    }
    let headers = ["METRIC", "TARGET", "DEFAULT", "CONFIGBOT"].map(String::from);
    configbot_controller::table::render(&headers, &rows)
}

/// Writes progress.svg (each trial, best so far) and core-rate.svg (per-second
/// core rates before and after); returns their paths.
fn write_plots(
    out: &Path,
    defs: &[MetricDef],
    before: &MeasureReport,
    after: &MeasureReport,
    status: &PerformanceSpecStatus,
) -> anyhow::Result<Vec<String>> {
    let mut paths = Vec::new();
    let progress = crate::report::progress::chart(&status.trial_history, &status.rejected_trials);
    let p = out.join("progress.svg");
    std::fs::write(&p, progress.to_svg())?;
    paths.push(p.display().to_string());
    if let Some(core) = defs.iter().find(|d| d.core) {
        let chart = histogram_chart(core, before, after);
        let p = out.join("core-rate.svg");
        std::fs::write(&p, chart.to_svg())?;
        paths.push(p.display().to_string());
    }
    Ok(paths)
}

/// Histogram of the per-second core rate, default vs tuned, as in Fig. 6 (pure).
pub fn histogram_chart(core: &MetricDef, before: &MeasureReport, after: &MeasureReport) -> Chart {
    let values = |r: &MeasureReport| {
        r.series
            .iter()
            .find(|s| s.probe == core.probe)
            .map(|s| s.values.clone())
            .unwrap_or_default()
    };
    let width = 2.0;
    let bins = |v: &[f64]| {
        let mut counts = std::collections::BTreeMap::<i64, f64>::new();
        for x in v {
            *counts.entry((x / width).floor() as i64).or_default() += 1.0;
        }
        counts
            .into_iter()
            .map(|(b, c)| (b as f64 * width, c))
            .collect::<Vec<_>>()
    };
    Chart {
        title: format!("{}: per-second rate", core.name),
        x_label: "Hz (1 s windows)".into(),
        y_label: "windows".into(),
        series: vec![
            Series {
                name: "default".into(),
                mark: Mark::Bar,
                color: colors::INFEASIBLE,
                points: bins(&values(before)),
            },
            Series {
                name: "configbot".into(),
                mark: Mark::Bar,
                color: colors::CORE,
                points: bins(&values(after)),
            },
        ],
        rules: vec![Rule {
            label: format!("target {}", core.target_text()),
            value: core.target,
            vertical: true,
        }],
        bar_width: width,
        y_from_zero: true,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn latency_is_printed_only_for_metrics_seen_late() {
        let peaks: std::collections::BTreeMap<String, Vec<f64>> = [
            ("corners-rate".to_owned(), vec![0.033, 0.133, 0.1]),
            ("edges-rate".to_owned(), vec![0.0, 0.0]),
        ]
        .into();
        assert_eq!(
            latency_text(&peaks),
            "; latency peak corners-rate 133 ms (2 windows ≥ 100 ms)"
        );
        assert_eq!(latency_text(&Default::default()), "");
    }

    #[test]
    fn every_example_loads_with_this_program_as_its_command() {
        for (file, _) in EXAMPLES {
            let (stack, spec) = example(file.trim_end_matches(".yaml")).unwrap();
            assert_eq!(stack.metadata.name, spec.spec.stack_ref.name);
            let exe = std::env::current_exe().unwrap();
            for (_, n) in stack.spec.nodes() {
                let command = &n.run.as_ref().unwrap().command;
                if file.starts_with("real-") {
                    // Real stacks run Debian's programs, by absolute path.
                    assert!(command.starts_with("/usr/"), "{file}: {command}");
                } else {
                    assert_eq!(*command, exe.display().to_string());
                }
            }
        }
        assert!(example("nope").is_err());
    }

    #[test]
    fn a_stack_that_does_not_flow_is_described_by_its_nodes_and_registrations() {
        let node = |name: &str, pid: Option<u32>, restarts: u32| -> NodeStatus {
            serde_json::from_value(json!({
                "name": name, "app": "nav", "kind": "run", "core": true,
                "pids": pid.into_iter().collect::<Vec<_>>(), "mainPid": pid,
                "cgroup": "/sys/fs/cgroup/cpu/x", "cpuUsageCpus": 0.5, "cpuLimit": null,
                "stats": configbot_cgroups::CpuStats::default(), "restarts": restarts, "stopped": false,
            }))
            .unwrap()
        };
        let mut graph = Graph::default();
        graph.topics.insert(
            "/scan".into(),
            configbot_api::graph::TopicInfo {
                name: "/scan".into(),
                msg_type: "*".into(),
                publishers: ["/lidar".to_string()].into(),
                subscribers: ["/navigation".to_string()].into(),
            },
        );
        let text = describe_stack(
            &[node("lidar", None, 3), node("navigation", Some(42), 0)],
            &graph,
        );
        assert!(
            text.contains("node /lidar (nav): no process, 3 restarts"),
            "{text}"
        );
        assert!(
            text.contains("node /navigation (nav): pid 42, 0 restarts, 0.50 CPU"),
            "{text}"
        );
        assert!(
            text.contains("topic /scan: published by [/lidar], subscribed by [/navigation]"),
            "{text}"
        );
    }
}
