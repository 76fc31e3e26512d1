//! `configbot-agent-bench`: the agent's own CPU use while idle, while
//! supervising 20 `run` nodes, and while tracking 20 adopted `match` nodes.
//! Prints a table and writes JSON (`--json`). Needs root (real cgroups).

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::Parser;
use configbot_agent::{Agent, AgentSettings, StackSpec};
use configbot_cgroups::{Layout, SubtreeRoot, open_backend};

#[derive(Debug, Parser)]
struct Args {
    /// Seconds measured per phase.
    #[arg(long, default_value_t = 10)]
    seconds: u64,
    #[arg(long, default_value_t = 20)]
    nodes: usize,
    /// The agent's scan/sample interval.
    #[arg(long, default_value_t = 500)]
    scan_interval_ms: u64,
    #[arg(long, default_value = "agent-bench.json")]
    json: PathBuf,
}

/// CPU time of this process (all threads), from per-thread schedstat, in ns.
fn own_cpu_ns() -> u64 {
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else {
        return 0;
    };
    tasks
        .filter_map(|t| std::fs::read_to_string(t.ok()?.path().join("schedstat")).ok())
        .filter_map(|s| s.split_whitespace().next()?.parse::<u64>().ok())
        .sum()
}

#[derive(Debug, serde::Serialize)]
#[serde(rename_all = "camelCase")]
struct Phase {
    phase: String,
    nodes: usize,
    /// Processes on the host (a /proc scan reads each of them).
    host_processes: usize,
    seconds: f64,
    agent_cpu_percent: f64,
}

async fn measure(
    name: &str,
    stack: StackSpec,
    nodes: usize,
    args: &Args,
    dir: &std::path::Path,
) -> anyhow::Result<Phase> {
    let root = format!("configbot-bench-{}-{name}", std::process::id());
    let settings = AgentSettings {
        cgroup_root: SubtreeRoot::new(&root)?,
        state_file: dir.join(format!("{name}.json")),
        log_dir: dir.join("logs"),
        scan_interval: Duration::from_millis(args.scan_interval_ms),
        stop_timeout: Duration::from_millis(500),
        ..AgentSettings::default()
    };
    let backend = open_backend(&Layout::detect()?, settings.cgroup_root.clone())?;
    let agent = Agent::start(backend, settings, stack).await?;
    // Let every node start and be adopted before measuring.
    let deadline = Instant::now() + Duration::from_secs(30);
    while agent.inventory().iter().any(|n| n.pids.is_empty()) {
        anyhow::ensure!(Instant::now() < deadline, "nodes did not come up");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    tokio::time::sleep(Duration::from_secs(1)).await;
    let (c0, t0) = (own_cpu_ns(), Instant::now());
    tokio::time::sleep(Duration::from_secs(args.seconds)).await;
    let (c1, dt) = (own_cpu_ns(), t0.elapsed());
    agent.teardown().await?;
    #[allow(clippy::cast_precision_loss)]
    let pct = (c1 - c0) as f64 / dt.as_nanos() as f64 * 100.0;
    let host_processes = std::fs::read_dir("/proc")?
        .filter(|e| {
            e.as_ref().is_ok_and(|e| {
                e.file_name()
                    .to_str()
                    .is_some_and(|n| n.parse::<u32>().is_ok())
            })
        })
        .count();
    Ok(Phase {
        phase: name.to_owned(),
        nodes,
        host_processes,
        seconds: dt.as_secs_f64(),
        agent_cpu_percent: pct,
    })
}

fn stack(json: &str) -> anyhow::Result<StackSpec> {
    Ok(serde_json::from_str(json)?)
}

#[tokio::main(flavor = "current_thread")]
async fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    let dir = tempfile_dir()?;
    let n = args.nodes;
    let run_nodes: Vec<String> = (0..n)
        .map(|i| {
            format!(
                r#"{{"name":"/bench/run{i}","run":{{"command":"/bin/sleep","args":["3600"]}}}}"#
            )
        })
        .collect();
    // sleep sums its arguments: a unique, valid duration tags each target.
    let tag = |i: usize| format!("0.{}{i:03}3", std::process::id());
    let mut targets = Vec::new();
    for i in 0..n {
        targets.push(
            std::process::Command::new("/bin/sleep")
                .args(["3600", &tag(i)])
                .spawn()?,
        );
    }
    let match_nodes: Vec<String> = (0..n)
        .map(|i| {
            let t = tag(i);
            format!(
                r#"{{"name":"/bench/match{i}","match":{{"cmdlineRegex":"^/bin/sleep 3600 {t}$"}}}}"#
            )
        })
        .collect();
    let mut phases = Vec::new();
    let result: anyhow::Result<()> = async {
        phases.push(measure("idle", stack(r#"{"apps":[]}"#)?, 0, &args, &dir).await?);
        let s = stack(&format!(
            r#"{{"apps":[{{"name":"bench","nodes":[{}]}}]}}"#,
            run_nodes.join(",")
        ))?;
        phases.push(measure("run", s, n, &args, &dir).await?);
        let s = stack(&format!(
            r#"{{"apps":[{{"name":"bench","nodes":[{}]}}]}}"#,
            match_nodes.join(",")
        ))?;
        phases.push(measure("match", s, n, &args, &dir).await?);
        Ok(())
    }
    .await;
    for mut t in targets {
        let _ = t.kill();
        let _ = t.wait();
    }
    let _ = std::fs::remove_dir_all(&dir);
    result?;
    println!(
        "{:<8} {:>6} {:>10} {:>9} {:>12}",
        "phase", "nodes", "host procs", "seconds", "agent cpu %"
    );
    for p in &phases {
        println!(
            "{:<8} {:>6} {:>10} {:>9.1} {:>12.3}",
            p.phase, p.nodes, p.host_processes, p.seconds, p.agent_cpu_percent
        );
    }
    let json = serde_json::json!({
        "scanIntervalMs": args.scan_interval_ms,
        "phases": phases,
    });
    std::fs::write(&args.json, serde_json::to_string_pretty(&json)?)
        .with_context(|| format!("cannot write {}", args.json.display()))?;
    println!("wrote {}", args.json.display());
    Ok(())
}

fn tempfile_dir() -> anyhow::Result<PathBuf> {
    let dir = std::env::temp_dir().join(format!("configbot-agent-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    Ok(dir)
}
