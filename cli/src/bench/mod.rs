//! `configbot bench`: the paper's comparison on this machine. For each example
//! stack it measures, over the same fixed window, the default config, three
//! random configs from the knob space, ConfigBot with CPU knobs only
//! (adaptors off) and full ConfigBot, each tuning run on a fresh robot so no
//! library entry carries over. It prints a table like the paper's Table III,
//! writes `bench.json` (after each stack, so a stopped run keeps what it
//! measured; `complete` once it ran to its end) and, per stack, the tuning
//! progress and the histogram of the core rate (default vs full ConfigBot)
//! as SVG. Then the paper's Table IV ([`cross`]: each stack's best config
//! on the other stacks) and Fig. 7 ([`timeline`]: Basic-NAV → Terrain-NAV →
//! Basic-NAV on one robot). Tuning cost is counted in trials and in seconds
//! from applying the spec, read from the spec's status as the run publishes
//! it ([`follow`]).
//! `--stacks real` measures the real Debian ROS 1 stacks instead ([`real`]:
//! launch and per-node defaults, cgroup-only, ConfigBot per seed, the oracle).

mod cross;
mod owner;
pub mod real;
mod timeline;

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use clap::Args;
use configbot_manifests::performance_spec::TrialStatus;
use configbot_manifests::{
    Kind, PerformanceSpec, PerformanceSpecStatus, Phase, RobotStack, decode_status,
};
use serde::{Deserialize, Serialize};
use serde_json::Value;

use self::owner::Current;
use super::demo::{
    PrivateRobot, example, histogram_chart, measure_defs, print_eval, print_trial, settled,
};
use configbot_controller::tuning::robot::{NodeApi, Robot};
use configbot_tuning::knobs::{self, KnobSpace};
use configbot_tuning::measure::{self, Evaluation, MetricDef};
use configbot_tuning::startup::flowing;

#[derive(Debug, Args)]
pub struct BenchArgs {
    /// Stacks to run (comma-separated). `real` means the real Debian ROS 1
    /// stacks (real-perception, real-nodelets, real-two-paths), each of which
    /// can also be named alone.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "basic-nav,intermed-nav,terrain-nav"
    )]
    stacks: Vec<String>,
    /// Real stacks: seconds each row is measured for after tuning (at least 60
    /// for the README's numbers).
    #[arg(long, default_value_t = 60)]
    real_window_secs: u64,
    /// Real stacks: one ConfigBot run per seed; the `configbot` row is the
    /// run with the median objective.
    #[arg(long, value_delimiter = ',', default_value = "1,2,3")]
    seeds: Vec<u64>,
    /// Real stacks: the rows to measure, in their fixed order: launch-default,
    /// default (the per-node default), cgroup-only, configbot (one run per
    /// seed) and oracle. Naming some runs only those, e.g. `--real-methods
    /// oracle` to measure a stack's yardstick alone.
    #[arg(
        long,
        value_delimiter = ',',
        value_enum,
        default_value = "launch-default,default,cgroup-only,configbot,oracle"
    )]
    real_methods: Vec<real::Method>,
    /// Real stacks: configs the oracle measures (0: no oracle). It measures
    /// the corners of the knob space and a Sobol design, each from a drained
    /// state, then verifies the best over a full window.
    #[arg(long, default_value_t = 50)]
    oracle_configs: usize,
    /// Real stacks: seconds the oracle measures each config for.
    #[arg(long, default_value_t = 6)]
    oracle_window_secs: u64,
    /// Real stacks: take each stack's oracle from DIR/oracle-<stack>.json,
    /// written by an earlier bench, instead of measuring it (about 20 min per
    /// stack). The oracle is the yardstick of a stack on a machine class:
    /// the bench stops before it starts anything when a file is missing,
    /// was measured for other manifests (its stack digest) or on another
    /// class of machine (CPUs and model). VMs of one class differ, so the
    /// bench measures each oracle's best config again on this machine (row
    /// `oracle-here`, column X HERE) and warns when it misses the core
    /// targets or gives less than 0.9 of its recorded objective.
    #[arg(long, value_name = "DIR")]
    oracle_from: Option<PathBuf>,
    /// Seconds each config is measured for.
    #[arg(long, default_value_t = 30)]
    window_secs: u64,
    /// Random configs per stack.
    #[arg(long, default_value_t = 3)]
    random: usize,
    /// Seed of the random configs.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Output folder (bench.json and plots).
    #[arg(long, default_value = "bench-results")]
    out: PathBuf,
    /// Stacks each stack's best config is cross-evaluated on (Table IV).
    #[arg(long, value_delimiter = ',')]
    cross_on: Option<Vec<String>>,
    /// Seconds after the timeline starts at which the robot switches from
    /// Basic-NAV to Terrain-NAV (later if Basic-NAV is still tuning).
    #[arg(long, default_value_t = 50)]
    switch_at_secs: u64,
    /// Seconds the timeline stays in each context after its config holds.
    #[arg(long, default_value_t = 20)]
    hold_secs: u64,
    /// For CI: Basic-NAV only, 5 s windows, one random config, at most 6
    /// trials of at most 3 s (settling at most 1 s, a bursty run's record at
    /// most 10 s); Basic-NAV's config cross-evaluated on
    /// Terrain-NAV only; a short timeline (switch at 15 s, at most 4 trials
    /// per run). With real stacks in `--stacks`: those only, 5 s windows,
    /// one seed, at most 4 trials (a record of at most 10 s), an oracle of 3 configs. Checks the shape
    /// of the output, not the numbers.
    #[arg(long)]
    quick: bool,
    /// Give up a tuning run after this many seconds: its row is recorded
    /// as unfinished (nothing measured, ranked below every measured seed)
    /// and the bench goes on; the timeline, whose later steps need it
    /// settled, stops with an error.
    #[arg(long, default_value_t = 900)]
    timeout_secs: u64,
    /// CPU weight of each robot's nodes together against this machine's
    /// other work (see `configbot demo --help`). Unset: the kernel's default.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=10_000))]
    subtree_cpu_weight: Option<u32>,
}

/// One measured method on one stack.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct MethodResult {
    pub stack: String,
    pub method: String,
    pub satisfaction: f64,
    /// Mean of every metric over the window.
    pub metrics: std::collections::BTreeMap<String, f64>,
    pub config: Value,
    /// Tuning runs only.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tuning: Option<TuningCost>,
    /// Per-second values of the first core metric (for the histogram).
    pub core_series: Vec<f64>,
    /// Per core metric whose messages carry a stamp: per second, the peak
    /// latency (s, a lower bound: the agent's latency classes) of its
    /// messages after their stamp. Empty for stacks whose topics carry none
    /// and in files from before it was measured.
    #[serde(default, skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub core_latency: std::collections::BTreeMap<String, Vec<f64>>,
}

/// What a tuning run cost. Seconds count from applying the PerformanceSpec
/// to the moment the spec's status first showed the event (polled every
/// [`POLL`]; the run writes status right after each step).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct TuningCost {
    pub phase: Phase,
    pub trials: u32,
    /// 1-based trial number of the first feasible trial.
    pub first_feasible_trial: Option<u32>,
    /// When the first feasible trial's measurement was done.
    pub first_feasible_seconds: Option<f64>,
    /// 1-based trial number of the config finally applied.
    pub final_trial: Option<u32>,
    /// When the final config's trial was measured.
    pub final_trial_seconds: Option<f64>,
    /// When the run settled: the final config applied and verified
    /// (Monitoring), or Unsat.
    pub final_config_seconds: f64,
    pub trial_history: Vec<TrialStatus>,
    /// Indices of trials whose config failed verification (status `rejectedTrials`).
    pub rejected_trials: Vec<u32>,
    /// The run had not settled within `--timeout-secs`: `phase` and
    /// `trials` say where it stood then, and its row measured nothing
    /// (see [`unfinished_row`]).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub unfinished: bool,
}

/// Status poll interval while following a tuning run.
pub const POLL: Duration = Duration::from_millis(200);

/// The cost of a run from its settled status, the seconds at which each
/// trial first appeared in the status (by index) and when it settled (pure).
pub fn tuning_cost(status: &PerformanceSpecStatus, seen: &[f64], settled_secs: f64) -> TuningCost {
    let first_feasible = status
        .trial_history
        .iter()
        .find(|t| t.feasible)
        .map(|t| t.index);
    let best = status.best_trial;
    let at = |i: Option<u32>| i.and_then(|i| seen.get(i as usize).copied());
    TuningCost {
        phase: status.phase.clone(),
        trials: status.trials,
        first_feasible_trial: first_feasible.map(|i| i + 1),
        first_feasible_seconds: at(first_feasible),
        final_trial: best.map(|i| i + 1),
        final_trial_seconds: at(best),
        final_config_seconds: settled_secs,
        trial_history: status.trial_history.clone(),
        rejected_trials: status.rejected_trials.clone(),
        unfinished: false,
    }
}

/// The row of a tuning run that had not settled when its time ran out
/// (pure): nothing measured, satisfaction 0 and no metrics (it delivered
/// no config in its time; [`real::objective`] is 0), the best config its
/// status showed, and the cost so far marked `unfinished`. Session 63: a
/// real-nodelets seed still lifting at `--timeout-secs` ended the whole
/// bench, and the seeds after it never ran.
pub fn unfinished_row(stack: &str, method: &str, f: &Followed) -> MethodResult {
    let mut cost = tuning_cost(&f.status, &f.seen, f.secs);
    cost.unfinished = true;
    MethodResult {
        stack: stack.into(),
        method: method.into(),
        satisfaction: 0.0,
        metrics: Default::default(),
        config: serde_json::to_value(&f.status.best_config).unwrap_or(Value::Null),
        tuning: Some(cost),
        core_series: Vec::new(),
        core_latency: Default::default(),
    }
}

impl MethodResult {
    /// A tuning run that had not settled in its time ([`unfinished_row`]).
    pub fn unfinished(&self) -> bool {
        self.tuning.as_ref().is_some_and(|t| t.unfinished)
    }
}

/// Whether the run has reached its outcome with the config it keeps applied:
/// the demo's settled check, and for Unsat also the safest config applied
/// (status shows it as `bestConfig` once it is monitored) (pure).
pub fn outcome(st: &PerformanceSpecStatus) -> bool {
    settled(st) && st.best_config.is_some()
}

/// Where a followed tuning run stood when [`follow`] returned.
#[derive(Debug, Clone)]
pub struct Followed {
    /// The spec's status: settled, or the last one read before the timeout.
    pub status: PerformanceSpecStatus,
    /// Seconds from `started` at which each trial first appeared (by index).
    pub seen: Vec<f64>,
    /// Seconds from `started` to the outcome, or to the timeout.
    pub secs: f64,
    /// Whether the run reached its [`outcome`] in time.
    pub settled: bool,
}

impl Followed {
    /// The settled seconds, or an error naming the spec when the run ran
    /// out of time (a run the caller cannot go on without).
    pub fn settled_secs(&self, name: &str) -> anyhow::Result<f64> {
        anyhow::ensure!(
            self.settled,
            "{name}: tuning did not finish within {:.0} s (phase {:?})",
            self.secs,
            self.status.phase.as_str()
        );
        Ok(self.secs)
    }
}

/// Follows a spec's tuning run from `started` (when it was applied):
/// prints each new trial, notes when each trial first appears in the
/// status, and returns once the run settles or `timeout` has passed.
pub async fn follow(
    robot: &PrivateRobot,
    name: &str,
    started: Instant,
    timeout: Duration,
) -> anyhow::Result<Followed> {
    let path = crate::client::path(Kind::PerformanceSpec, Some("default"), Some(name));
    let mut seen: Vec<f64> = Vec::new();
    loop {
        let obj = robot.client.get(&path).await?;
        let now = started.elapsed().as_secs_f64();
        let st: PerformanceSpecStatus = decode_status(&obj)?;
        for t in st.trial_history.iter().skip(seen.len()) {
            print_trial(&st, t);
            seen.push(now);
        }
        let settled = outcome(&st);
        if settled || started.elapsed() >= timeout {
            return Ok(Followed {
                status: st,
                seen,
                secs: now,
                settled,
            });
        }
        tokio::time::sleep(POLL).await;
    }
}

/// The settings a run uses (`--quick` overrides the flags).
#[derive(Debug, Clone)]
struct Plan {
    stacks: Vec<String>,
    cross_on: Vec<String>,
    window: u64,
    random: usize,
    switch_at: u64,
    hold: u64,
    max_trials: Option<u32>,
    /// Trial cap of the timeline's runs (fewer in `--quick`).
    timeline_trials: Option<u32>,
}

fn plan(a: &BenchArgs) -> Plan {
    let stacks = real::expand(&a.stacks);
    if a.quick && stacks.iter().any(|s| real::is_real(s)) {
        return Plan {
            stacks: stacks.into_iter().filter(|s| real::is_real(s)).collect(),
            cross_on: Vec::new(),
            window: 5,
            random: 0,
            switch_at: 0,
            hold: 0,
            max_trials: Some(4),
            timeline_trials: None,
        };
    }
    if a.quick {
        Plan {
            stacks: vec!["basic-nav".into()],
            cross_on: vec!["basic-nav".into(), "terrain-nav".into()],
            window: 5,
            random: 1,
            switch_at: 15,
            hold: 4,
            max_trials: Some(6),
            timeline_trials: Some(4),
        }
    } else {
        let sim: Vec<String> = stacks
            .iter()
            .filter(|s| !real::is_real(s))
            .cloned()
            .collect();
        Plan {
            cross_on: a.cross_on.clone().unwrap_or_else(|| sim.clone()),
            stacks,
            window: a.window_secs,
            random: a.random,
            switch_at: a.switch_at_secs,
            hold: a.hold_secs,
            max_trials: None,
            timeline_trials: None,
        }
    }
}

/// `--quick`'s cap on a bursty run's record (`tuning.recordSeconds`):
/// Basic-NAV's 3 s quick trials burst, and the full two minutes per
/// verification overran the quick bench's budget in CI's e2e test.
pub(super) const QUICK_RECORD_SECONDS: f64 = 10.0;

/// An example stack and spec, shortened for `--quick`.
fn example_for(name: &str, p: &Plan) -> anyhow::Result<(RobotStack, PerformanceSpec)> {
    let (stack, mut spec) = example(name)?;
    if let Some(m) = p.max_trials {
        spec.spec.tuning.max_trials = spec.spec.tuning.max_trials.min(m);
        spec.spec.tuning.trial_seconds = spec.spec.tuning.trial_seconds.min(3.0);
        spec.spec.tuning.settle_seconds = spec.spec.tuning.settle_seconds.min(1.0);
        spec.spec.tuning.record_seconds = spec.spec.tuning.record_seconds.min(QUICK_RECORD_SECONDS);
    }
    Ok((stack, spec))
}

/// Exit status of a bench interrupted by Ctrl-C or SIGTERM (128 + SIGINT).
const INTERRUPTED: u8 = 130;

/// Runs the bench; on Ctrl-C or SIGTERM stops the current robot's nodes,
/// removes its cgroups and exits with [`INTERRUPTED`].
pub async fn run(a: &BenchArgs) -> anyhow::Result<ExitCode> {
    let mut cur = Current::new(a.subtree_cpu_weight);
    let result = tokio::select! {
        r = bench(a, &mut cur) => Some(r),
        _ = crate::shutdown_signal() => None,
    };
    if result.is_none() {
        eprintln!(
            "configbot bench: interrupted{}",
            if cur.is_open() {
                "; stopping the robot's nodes and removing its cgroups"
            } else {
                ""
            }
        );
    }
    let closed = cur.close().await;
    match result {
        Some(r) => {
            closed?;
            r
        }
        None => {
            if let Err(e) = closed {
                eprintln!("configbot bench: stopping the robot: {e:#}");
            }
            eprintln!("configbot bench: interrupted, results incomplete");
            Ok(ExitCode::from(INTERRUPTED))
        }
    }
}

/// The settings of the real-stack rows.
fn real_plan(a: &BenchArgs, p: &Plan) -> real::RealPlan {
    if a.quick {
        real::RealPlan {
            window: p.window,
            seeds: a.seeds.iter().take(1).copied().collect(),
            methods: a.real_methods.clone(),
            oracle_configs: a.oracle_configs.min(3),
            oracle_window: 3,
            max_trials: p.max_trials,
        }
    } else {
        real::RealPlan {
            window: a.real_window_secs,
            seeds: a.seeds.clone(),
            methods: a.real_methods.clone(),
            oracle_configs: a.oracle_configs,
            oracle_window: a.oracle_window_secs,
            max_trials: None,
        }
    }
}

/// The whole bench; every step runs on a robot borrowed from `cur`.
async fn bench(a: &BenchArgs, cur: &mut Current) -> anyhow::Result<ExitCode> {
    let p = plan(a);
    let rp = real_plan(a, &p);
    // Checked before anything in the output folder changes.
    let mut earlier = match &a.oracle_from {
        Some(_) if !rp.methods.contains(&real::Method::Oracle) => {
            anyhow::bail!("--oracle-from gives the oracle row, which --real-methods leaves out")
        }
        Some(dir) => real::load_oracles(dir, &p.stacks)?,
        None => Default::default(),
    };
    std::fs::create_dir_all(&a.out)?;
    // A bench.json left by an earlier run in this folder is not this run's.
    match std::fs::remove_file(a.out.join("bench.json")) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(e.into()),
        _ => {}
    }
    let mut results = Vec::new();
    let mut oracles = Vec::new();
    for name in p.stacks.iter().filter(|s| real::is_real(s)) {
        let (rows, oracle) = real::run_stack(cur, a, &rp, name, earlier.remove(name)).await?;
        let (stack, spec) = super::demo::example(name)?;
        let defs = measure::metric_defs(&stack.spec, &spec.spec);
        results.extend(rows);
        write_plots(&a.out, name, &defs, &results)?;
        if let Some(o) = oracle {
            real::write_oracle(&a.out, &o)?;
            oracles.push(o);
        }
        write_results(a, &p, &results, &[], None, &oracles, false)?;
    }
    if !oracles.is_empty() || p.stacks.iter().any(|s| real::is_real(s)) {
        let defs_of = |name: &str| {
            super::demo::example(name)
                .map(|(st, sp)| measure::metric_defs(&st.spec, &sp.spec))
                .unwrap_or_default()
        };
        println!("\n{}", real::summary(&defs_of, &results));
        for o in &oracles {
            if let Some(h) = o.here.as_ref().filter(|h| !h.stands) {
                println!("{}: {}", o.stack, h.said());
            }
        }
    }
    for name in p.stacks.iter().filter(|s| !real::is_real(s)) {
        let (stack, spec) = example_for(name, &p)?;
        let defs = measure::metric_defs(&stack.spec, &spec.spec);
        println!(
            "==> {name}: default and {} random configs ({} s each)",
            p.random, p.window
        );
        results.extend(untuned(cur, a, &p, name, &stack, &spec, &defs).await?);
        for (method, adaptors) in [("cgroup-only", false), ("configbot", true)] {
            println!("==> {name}: {method}");
            let mut s = spec.clone();
            s.spec.knobs.adaptors.enabled = adaptors;
            results.push(tuned(cur, a, name, method, &stack, &s, p.window).await?);
        }
        write_plots(&a.out, name, &defs, &results)?;
        write_results(a, &p, &results, &[], None, &oracles, false)?;
    }
    println!("\n{}", table(&results));
    let simulated = p.stacks.iter().any(|s| !real::is_real(s));
    let cross = if simulated {
        let c = cross::run(cur, a, &p, &results).await?;
        println!("\n{}", cross::matrix_table(&c));
        write_results(a, &p, &results, &c, None, &oracles, false)?;
        c
    } else {
        Default::default()
    };
    let timeline = if simulated {
        let t = timeline::run(cur, a, &p).await?;
        println!("\n{}", timeline::summary(&t));
        Some(t)
    } else {
        None
    };
    let path = write_results(a, &p, &results, &cross, timeline.as_ref(), &oracles, true)?;
    println!("results: {}", path.display());
    Ok(ExitCode::SUCCESS)
}

/// Writes `bench.json` with every result measured so far; `complete` is
/// false until the bench's last step. The bench rewrites it after each
/// stack and after the cross-evaluation, so a run stopped midway (Ctrl-C,
/// a failed step) keeps the stacks it finished. The file is replaced by a
/// rename, so a reader never sees half of it.
fn write_results(
    a: &BenchArgs,
    p: &Plan,
    results: &[MethodResult],
    cross: &[cross::CrossEntry],
    timeline: Option<&timeline::Timeline>,
    oracles: &[real::Oracle],
    complete: bool,
) -> anyhow::Result<PathBuf> {
    let path = a.out.join("bench.json");
    let tmp = a.out.join("bench.json.partial");
    std::fs::write(
        &tmp,
        serde_json::to_string_pretty(&serde_json::json!({
            "complete": complete, "quick": a.quick, "windowSeconds": p.window, "seed": a.seed,
            "results": results, "crossEvaluation": cross, "timeline": timeline, "oracles": oracles,
        }))?,
    )?;
    std::fs::rename(&tmp, &path)?;
    Ok(path)
}

fn fresh_dir(out: &Path, stack: &str, method: &str) -> anyhow::Result<PathBuf> {
    let d = out.join("state").join(format!("{stack}-{method}"));
    if d.exists() {
        std::fs::remove_dir_all(&d)?;
    }
    Ok(d)
}

/// A fresh robot in `cur` running `stack`, once every metric's topic has
/// delivered messages (the previous robot is closed first; on failure the
/// caller's owner closes this one).
async fn start<'a>(
    cur: &'a mut Current,
    out: &Path,
    name: &str,
    method: &str,
    stack: &RobotStack,
    defs: &[MetricDef],
) -> anyhow::Result<&'a PrivateRobot> {
    let robot = cur.start(&fresh_dir(out, name, method)?).await?;
    robot
        .apply(&serde_json::to_value(stack)?, Kind::RobotStack)
        .await?;
    let silent = wait_until_up(robot.robot.as_ref(), defs, FLOW_TIMEOUT).await;
    let core_silent: Vec<&String> = silent
        .iter()
        .filter(|n| defs.iter().any(|d| d.core && &d.name == *n))
        .collect();
    if !core_silent.is_empty() {
        anyhow::bail!(
            "{name}: no messages on {} within {} s (logs: {}):{}",
            silent.join(", "),
            FLOW_TIMEOUT.as_secs(),
            robot.dir.join("agent/logs").display(),
            robot.describe().await
        );
    }
    if !silent.is_empty() {
        // A silent non-core metric may be a node the default config starves;
        // a node that never registered is one that cannot start (a missing
        // package, say), and numbers measured without it mean nothing.
        let graph = robot.robot.graph().await?;
        let missing = configbot_tuning::startup::missing(stack, &graph);
        if !missing.is_empty() {
            anyhow::bail!(
                "{name}: {} never registered with the master and {} stayed silent (logs: {}):{}",
                missing.join(", "),
                silent.join(", "),
                robot.dir.join("agent/logs").display(),
                robot.describe().await
            );
        }
        println!(
            "    {name}: no messages yet on {} (non-core; starved by the default config?)",
            silent.join(", ")
        );
    }
    Ok(robot)
}

/// How long a fresh stack may take until every core metric's topic has flowed.
pub(super) const FLOW_TIMEOUT: Duration = Duration::from_secs(90);
/// How long to wait for non-core topics once the core ones flow: a default
/// config may starve a non-core app for good (Terrain-NAV's dashboard).
const NON_CORE_GRACE: Duration = Duration::from_secs(20);

/// Measures 1 s windows until each of `defs` has delivered messages in at
/// least one of them (a loaded machine may starve a topic for a second, so
/// not all in the same window), or the core ones have and the non-core ones
/// had [`NON_CORE_GRACE`], or `timeout` passed; returns the metrics that
/// never did.
pub(super) async fn wait_until_up(
    robot: &dyn Robot,
    defs: &[MetricDef],
    timeout: Duration,
) -> Vec<String> {
    let started = Instant::now();
    let mut flowed = std::collections::BTreeSet::new();
    loop {
        match measure_defs(robot, defs, 1).await {
            Ok(r) => flowed.extend(flowing(defs, &r)),
            Err(_) => tokio::time::sleep(Duration::from_secs(1)).await,
        }
        let silent: Vec<&MetricDef> = defs.iter().filter(|d| !flowed.contains(&d.name)).collect();
        let core_up = silent.iter().all(|d| !d.core);
        let waited = started.elapsed();
        if silent.is_empty() || (core_up && waited >= NON_CORE_GRACE) || waited >= timeout {
            return silent.iter().map(|d| d.name.clone()).collect();
        }
    }
}

/// The knob space a tuning run would derive on the robot as it runs now:
/// from its live graph and every topic's rate over 2 s.
pub(super) async fn live_space(
    robot: &dyn Robot,
    stack: &RobotStack,
    spec: &PerformanceSpec,
) -> anyhow::Result<KnobSpace> {
    let graph = robot.graph().await?;
    let topics: Vec<String> = graph.topics.keys().cloned().collect();
    let rates = measure::topic_rates(
        &robot
            .measure(&measure::request(&[], &topics, 2000, 1000))
            .await?,
    );
    Ok(knobs::derive(
        &stack.spec,
        &spec.spec,
        &graph,
        &rates,
        stack.spec.robot.cpus.unwrap_or(2.0),
    )?)
}

fn result(
    stack: &str,
    method: &str,
    defs: &[MetricDef],
    r: &configbot_api::measure::MeasureReport,
    config: Value,
    tuning: Option<TuningCost>,
) -> MethodResult {
    let e: Evaluation = measure::evaluate(defs, r, Default::default());
    let core_series = defs
        .iter()
        .find(|d| d.core)
        .and_then(|d| r.series.iter().find(|s| s.probe == d.probe))
        .map(|s| s.values.clone())
        .unwrap_or_default();
    print_eval(method, defs, r);
    let core_latency = measure::latency_peaks(defs, r)
        .into_iter()
        .filter(|(_, v)| v.iter().any(|&x| x > 0.0))
        .collect();
    MethodResult {
        stack: stack.into(),
        method: method.into(),
        satisfaction: e.satisfaction,
        metrics: e.means,
        config,
        tuning,
        core_series,
        core_latency,
    }
}

/// Default and random configs, on one robot.
async fn untuned(
    cur: &mut Current,
    a: &BenchArgs,
    p: &Plan,
    name: &str,
    stack: &RobotStack,
    spec: &PerformanceSpec,
    defs: &[MetricDef],
) -> anyhow::Result<Vec<MethodResult>> {
    let (window, random) = (p.window, p.random);
    let robot = start(cur, &a.out, name, "untuned", stack, defs).await?;
    let out = async {
        let mut out = Vec::new();
        let r = measure_defs(robot.robot.as_ref(), defs, window).await?;
        out.push(result(name, "default", defs, &r, Value::Null, None));
        let space = live_space(robot.robot.as_ref(), stack, spec).await?;
        let mut rng = configbot_optimizer::rng::Rng::seed_from_u64(a.seed);
        for i in 0..random {
            let x: Vec<f64> = space
                .knobs
                .iter()
                .map(|k| rng.range(k.min, k.max))
                .collect();
            let cfg = space.to_config(&x);
            robot.robot.apply(&cfg).await?;
            tokio::time::sleep(Duration::from_secs(2)).await;
            let r = measure_defs(robot.robot.as_ref(), defs, window).await?;
            out.push(result(
                name,
                &format!("random-{}", i + 1),
                defs,
                &r,
                serde_json::to_value(&cfg)?,
                None,
            ));
        }
        anyhow::Ok(out)
    }
    .await;
    cur.close().await?;
    out
}

/// A tuning run on a fresh robot, then a measurement of what it applied.
async fn tuned(
    cur: &mut Current,
    a: &BenchArgs,
    name: &str,
    method: &str,
    stack: &RobotStack,
    spec: &PerformanceSpec,
    window: u64,
) -> anyhow::Result<MethodResult> {
    let defs = &measure::metric_defs(&stack.spec, &spec.spec);
    let robot = start(cur, &a.out, name, method, stack, defs).await?;
    let out = async {
        let started = Instant::now();
        robot
            .apply(&serde_json::to_value(spec)?, Kind::PerformanceSpec)
            .await?;
        let f = follow(
            robot,
            &spec.metadata.name,
            started,
            Duration::from_secs(a.timeout_secs),
        )
        .await?;
        if !f.settled {
            println!(
                "    {method}: not settled within {} s (phase {}, {} trials): recorded as unfinished, not measured",
                a.timeout_secs,
                f.status.phase.as_str(),
                f.status.trials
            );
            return anyhow::Ok(unfinished_row(name, method, &f));
        }
        let cost = tuning_cost(&f.status, &f.seen, f.secs);
        tokio::time::sleep(Duration::from_secs(2)).await;
        let r = measure_defs(robot.robot.as_ref(), defs, window).await?;
        anyhow::Ok(result(
            name,
            method,
            defs,
            &r,
            serde_json::to_value(&f.status.best_config)?,
            Some(cost),
        ))
    }
    .await;
    cur.close().await?;
    out
}

/// `trial 3 @ 21 s` (or `-`).
fn at_trial(trial: Option<u32>, secs: Option<f64>) -> String {
    match (trial, secs) {
        (Some(t), Some(s)) => format!("{t} @ {s:.0} s"),
        (Some(t), None) => format!("{t}"),
        _ => "-".into(),
    }
}

/// A row's satisfaction as the tables show it: `unfinished` for a run that
/// measured nothing.
pub fn satisfaction(r: &MethodResult) -> String {
    if r.unfinished() {
        "unfinished".into()
    } else {
        format!("{:.1}%", r.satisfaction * 100.0)
    }
}

/// The Table III-like summary with the tuning cost (pure).
pub fn table(results: &[MethodResult]) -> String {
    let mut rows = Vec::new();
    for r in results {
        let metrics: Vec<String> = r
            .metrics
            .iter()
            .map(|(k, v)| format!("{k}={v:.1}"))
            .collect();
        let t = r.tuning.as_ref();
        rows.push(vec![
            r.stack.clone(),
            r.method.clone(),
            satisfaction(r),
            metrics.join(" "),
            t.map_or("-".into(), |t| {
                let late = if t.unfinished { ", unfinished" } else { "" };
                format!("{} ({}{late})", t.trials, t.phase)
            }),
            t.map_or("-".into(), |t| {
                at_trial(t.first_feasible_trial, t.first_feasible_seconds)
            }),
            t.map_or("-".into(), |t| {
                at_trial(t.final_trial, t.final_trial_seconds)
            }),
            t.filter(|t| !t.unfinished)
                .map_or("-".into(), |t| format!("{:.0}", t.final_config_seconds)),
        ]);
    }
    let h = [
        "STACK",
        "METHOD",
        "SATISFACTION",
        "METRICS (Hz)",
        "TRIALS",
        "1ST FEASIBLE",
        "FINAL TRIAL",
        "SETTLED S",
    ]
    .map(String::from);
    configbot_controller::table::render(&h, &rows)
}

fn write_plots(
    out: &Path,
    name: &str,
    defs: &[MetricDef],
    results: &[MethodResult],
) -> anyhow::Result<()> {
    let of = |m: &str| results.iter().find(|r| r.stack == name && r.method == m);
    if let Some(t) = of("configbot").and_then(|r| r.tuning.as_ref()) {
        let mut c = crate::report::progress::chart(&t.trial_history, &t.rejected_trials);
        c.title = format!("{name}: tuning progress");
        std::fs::write(out.join(format!("{name}-progress.svg")), c.to_svg())?;
    }
    if let (Some(core), Some(d), Some(c)) = (
        defs.iter().find(|d| d.core),
        of("default"),
        of("configbot").filter(|c| !c.unfinished()),
    ) {
        let report = |v: &[f64]| configbot_api::measure::MeasureReport {
            started_unix_ms: 0,
            duration_ms: v.len() as u64 * 1000,
            sub_window_ms: 1000,
            series: vec![configbot_api::measure::ProbeSeries {
                probe: core.probe.clone(),
                values: v.to_vec(),
                mean: 0.0,
            }],
        };
        let mut chart = histogram_chart(core, &report(&d.core_series), &report(&c.core_series));
        chart.title = format!("{name}: {}", chart.title);
        std::fs::write(out.join(format!("{name}-core-rate.svg")), chart.to_svg())?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn trial(index: u32, feasible: bool) -> TrialStatus {
        TrialStatus {
            index,
            feasible,
            ..TrialStatus::default()
        }
    }

    fn settled_status() -> PerformanceSpecStatus {
        PerformanceSpecStatus {
            phase: Phase::Monitoring,
            trials: 4,
            best_trial: Some(3),
            best_config: Some(Default::default()),
            rejected_trials: vec![1],
            trial_history: vec![
                trial(0, false),
                trial(1, true),
                trial(2, false),
                trial(3, true),
            ],
            ..PerformanceSpecStatus::default()
        }
    }

    #[test]
    fn cost_takes_trial_numbers_and_seconds_from_the_status() {
        let c = tuning_cost(&settled_status(), &[4.0, 9.4, 14.0, 19.2], 30.0);
        assert_eq!(c.phase, Phase::Monitoring);
        assert_eq!(c.trials, 4);
        assert_eq!(
            (c.first_feasible_trial, c.first_feasible_seconds),
            (Some(2), Some(9.4))
        );
        assert_eq!(
            (c.final_trial, c.final_trial_seconds),
            (Some(4), Some(19.2))
        );
        assert_eq!(c.final_config_seconds, 30.0);
        assert_eq!(c.rejected_trials, [1]);
        // Unsat: no best trial, no feasible one.
        let unsat = PerformanceSpecStatus {
            phase: Phase::Unsat,
            trials: 1,
            trial_history: vec![trial(0, false)],
            ..PerformanceSpecStatus::default()
        };
        let u = tuning_cost(&unsat, &[3.0], 8.0);
        assert_eq!((u.first_feasible_trial, u.final_trial), (None, None));
        assert_eq!(
            (u.first_feasible_seconds, u.final_trial_seconds),
            (None, None)
        );
    }

    #[test]
    fn a_run_past_its_timeout_is_a_row_that_measured_nothing() {
        let lifting = PerformanceSpecStatus {
            phase: Phase::Satisfied,
            ..settled_status()
        };
        let f = Followed {
            status: lifting,
            seen: vec![4.0, 9.4, 14.0, 19.2],
            secs: 1500.2,
            settled: false,
        };
        let e = f.settled_secs("nav").unwrap_err().to_string();
        assert!(e.contains("nav") && e.contains("1500 s"), "{e}");
        let r = unfinished_row("real-nodelets", "configbot-seed-1", &f);
        assert!(r.unfinished());
        assert_eq!((r.satisfaction, r.metrics.len()), (0.0, 0));
        assert!(!r.config.is_null(), "the best config so far is kept");
        let t = r.tuning.as_ref().unwrap();
        assert_eq!((t.phase.clone(), t.trials), (Phase::Satisfied, 4));
        let shown = table(std::slice::from_ref(&r));
        assert!(
            shown.contains("unfinished") && shown.contains("4 (Satisfied, unfinished)"),
            "{shown}"
        );
        assert!(
            shown.lines().nth(1).unwrap().trim_end().ends_with('-'),
            "never settled: {shown}"
        );
        // A settled run's cost says nothing of it, in memory or in JSON.
        let done = Followed {
            settled: true,
            ..f.clone()
        };
        assert_eq!(done.settled_secs("nav").unwrap(), 1500.2);
        let c = tuning_cost(&settled_status(), &[4.0], 30.0);
        assert!(!c.unfinished);
        let json = serde_json::to_value(&c).unwrap();
        assert!(json.get("unfinished").is_none(), "{json}");
        let back: TuningCost = serde_json::from_value(json).unwrap();
        assert!(!back.unfinished);
        let json = serde_json::to_value(r.tuning.as_ref().unwrap()).unwrap();
        assert_eq!(json["unfinished"], true);
    }

    #[test]
    fn unsat_is_an_outcome_once_its_config_is_applied() {
        let status = |phase: Phase, best_config: Option<configbot_manifests::ResourceConfig>| {
            PerformanceSpecStatus {
                phase,
                best_config,
                ..PerformanceSpecStatus::default()
            }
        };
        assert!(outcome(&settled_status()));
        assert!(!outcome(&status(Phase::Unsat, None)));
        assert!(outcome(&status(Phase::Unsat, Some(Default::default()))));
        // Still measuring trials: a best config left from before is no outcome.
        assert!(!outcome(&status(Phase::Tuning, Some(Default::default()))));
    }

    #[test]
    fn a_topic_flows_when_its_probe_saw_messages() {
        use configbot_api::measure::{MeasureReport, Probe, ProbeSeries};
        let def = |name: &str, topic: &str| MetricDef::rate_at_least(name, "a", topic, 1.0, true);
        let defs = [
            def("cmd", "/cmd_vel"),
            def("det", "/det"),
            def("web", "/web"),
        ];
        let series = |topic: &str, mean: f64| ProbeSeries {
            probe: Probe::TopicRate {
                topic: topic.into(),
                subscriber: None,
            },
            values: vec![mean],
            mean,
        };
        let r = MeasureReport {
            started_unix_ms: 0,
            duration_ms: 1000,
            sub_window_ms: 1000,
            series: vec![series("/cmd_vel", 40.0), series("/det", 0.0)],
        };
        assert_eq!(flowing(&defs, &r), ["cmd"]);
    }

    #[test]
    fn table_shows_cost_for_tuned_rows_only() {
        let row = |method: &str, tuning: Option<TuningCost>| MethodResult {
            stack: "basic-nav".into(),
            method: method.into(),
            satisfaction: 0.5,
            metrics: [("cmd".to_string(), 30.0)].into_iter().collect(),
            config: Value::Null,
            tuning,
            core_series: Vec::new(),
            core_latency: Default::default(),
        };
        let c = tuning_cost(&settled_status(), &[4.0, 9.4, 14.0, 19.2], 30.0);
        let t = table(&[row("default", None), row("configbot", Some(c))]);
        let lines: Vec<&str> = t.lines().collect();
        assert!(lines[0].contains("1ST FEASIBLE"), "{t}");
        assert!(
            lines[1].contains("50.0%") && lines[1].contains("cmd=30.0"),
            "{t}"
        );
        assert!(lines[1].trim_end().ends_with('-'), "{t}");
        assert!(lines[2].contains("4 (Monitoring)"), "{t}");
        assert!(
            lines[2].contains("2 @ 9 s") && lines[2].contains("4 @ 19 s"),
            "{t}"
        );
        assert!(lines[2].trim_end().ends_with("30"), "{t}");
        assert_eq!(at_trial(Some(2), None), "2");
        assert_eq!(at_trial(None, Some(1.0)), "-");
    }
}
