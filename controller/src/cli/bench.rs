//! `configbot bench`: the paper's comparison on this machine. For each example
//! stack it measures, over the same fixed window, the default config, three
//! random configs from the knob space, ConfigBot with CPU knobs only
//! (adaptors off) and full ConfigBot, each tuning run on a fresh robot so no
//! library entry carries over. It prints a table like the paper's Table III,
//! writes `bench.json` and, per stack, the tuning progress and the histogram
//! of the core rate (default vs full ConfigBot) as SVG.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use clap::Args;
use configbot_manifests::{Kind, PerformanceSpec, RobotStack};
use serde::Serialize;
use serde_json::Value;

use super::demo::{
    PrivateRobot, example, histogram_chart, measure_defs, print_eval, progress_chart, wait_for_flow,
};
use crate::tuning::knobs;
use crate::tuning::measure::{self, Evaluation, MetricDef};
use crate::tuning::robot::Robot;

#[derive(Debug, Args)]
pub struct BenchArgs {
    /// Stacks to run (comma-separated).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "basic-nav,intermed-nav,terrain-nav"
    )]
    stacks: Vec<String>,
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
    /// For CI: Basic-NAV only, 5 s windows, one random config, at most 6 trials.
    /// Checks the shape of the output, not the numbers.
    #[arg(long)]
    quick: bool,
    /// Give up a tuning run after this many seconds.
    #[arg(long, default_value_t = 900)]
    timeout_secs: u64,
}

/// One measured method on one stack.
#[derive(Debug, Clone, Serialize)]
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
}

/// What a tuning run cost.
#[derive(Debug, Clone, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct TuningCost {
    pub phase: String,
    pub trials: u64,
    /// 1-based trial number of the first feasible trial.
    pub first_feasible_trial: Option<u64>,
    /// 1-based trial number of the config finally applied.
    pub final_trial: Option<u64>,
    pub seconds: f64,
    pub trial_history: Value,
}

pub async fn run(a: &BenchArgs) -> anyhow::Result<ExitCode> {
    let (stacks, window, random) = if a.quick {
        (vec!["basic-nav".to_owned()], 5, 1)
    } else {
        (a.stacks.clone(), a.window_secs, a.random)
    };
    std::fs::create_dir_all(&a.out)?;
    let mut results = Vec::new();
    for name in &stacks {
        let (stack, mut spec) = example(name)?;
        if a.quick {
            spec.spec.tuning.max_trials = spec.spec.tuning.max_trials.min(6);
            spec.spec.tuning.trial_seconds = spec.spec.tuning.trial_seconds.min(3.0);
        }
        let defs = measure::metric_defs(&stack.spec, &spec.spec);
        println!("==> {name}: default and {random} random configs ({window} s each)");
        results.extend(untuned(a, name, &stack, &spec, &defs, window, random).await?);
        for (method, adaptors) in [("cgroup-only", false), ("configbot", true)] {
            println!("==> {name}: {method}");
            let mut s = spec.clone();
            s.spec.knobs.adaptors.enabled = adaptors;
            results.push(tuned(a, name, method, &stack, &s, &defs, window).await?);
        }
        write_plots(&a.out, name, &defs, &results)?;
    }
    println!("\n{}", table(&results));
    let path = a.out.join("bench.json");
    std::fs::write(
        &path,
        serde_json::to_string_pretty(&serde_json::json!({
            "quick": a.quick, "windowSeconds": window, "seed": a.seed, "results": results,
        }))?,
    )?;
    println!("results: {}", path.display());
    Ok(ExitCode::SUCCESS)
}

fn fresh_dir(out: &Path, stack: &str, method: &str) -> anyhow::Result<PathBuf> {
    let d = out.join("state").join(format!("{stack}-{method}"));
    if d.exists() {
        std::fs::remove_dir_all(&d)?;
    }
    Ok(d)
}

async fn start(
    out: &Path,
    name: &str,
    method: &str,
    stack: &RobotStack,
    defs: &[MetricDef],
) -> anyhow::Result<PrivateRobot> {
    let robot = PrivateRobot::start(&fresh_dir(out, name, method)?).await?;
    robot
        .apply(&serde_json::to_value(stack)?, Kind::RobotStack)
        .await?;
    anyhow::ensure!(
        wait_for_flow(robot.robot.as_ref(), defs, Duration::from_secs(60)).await,
        "{name}: topics did not flow within 60 s"
    );
    Ok(robot)
}

fn result(
    stack: &str,
    method: &str,
    defs: &[MetricDef],
    r: &configbot_agent::measure::MeasureReport,
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
    MethodResult {
        stack: stack.into(),
        method: method.into(),
        satisfaction: e.satisfaction,
        metrics: e.means,
        config,
        tuning,
        core_series,
    }
}

/// Default and random configs, on one robot.
async fn untuned(
    a: &BenchArgs,
    name: &str,
    stack: &RobotStack,
    spec: &PerformanceSpec,
    defs: &[MetricDef],
    window: u64,
    random: usize,
) -> anyhow::Result<Vec<MethodResult>> {
    let robot = start(&a.out, name, "untuned", stack, defs).await?;
    let out = async {
        let mut out = Vec::new();
        let r = measure_defs(robot.robot.as_ref(), defs, window).await?;
        out.push(result(name, "default", defs, &r, Value::Null, None));
        let graph = robot.robot.graph().await?;
        let rates = measure::topic_rates(
            &robot
                .robot
                .measure(&measure::request(
                    &[],
                    &graph.topics.keys().cloned().collect::<Vec<_>>(),
                    2000,
                    1000,
                ))
                .await?,
        );
        let space = knobs::derive(
            &stack.spec,
            &spec.spec,
            &graph,
            &rates,
            stack.spec.robot.cpus.unwrap_or(2.0),
        )?;
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
    robot.close().await?;
    out
}

/// A tuning run on a fresh robot, then a measurement of what it applied.
async fn tuned(
    a: &BenchArgs,
    name: &str,
    method: &str,
    stack: &RobotStack,
    spec: &PerformanceSpec,
    defs: &[MetricDef],
    window: u64,
) -> anyhow::Result<MethodResult> {
    let robot = start(&a.out, name, method, stack, defs).await?;
    let out = async {
        let started = Instant::now();
        robot
            .apply(&serde_json::to_value(spec)?, Kind::PerformanceSpec)
            .await?;
        let st = super::demo::wait_for_outcome(
            &robot,
            &spec.metadata.name,
            Duration::from_secs(a.timeout_secs),
        )
        .await?;
        let seconds = started.elapsed().as_secs_f64();
        tokio::time::sleep(Duration::from_secs(2)).await;
        let r = measure_defs(robot.robot.as_ref(), defs, window).await?;
        let history = st["trialHistory"].clone();
        let first_feasible = history
            .as_array()
            .into_iter()
            .flatten()
            .find(|t| t["feasible"].as_bool() == Some(true))
            .and_then(|t| t["index"].as_u64())
            .map(|i| i + 1);
        let cost = TuningCost {
            phase: st["phase"].as_str().unwrap_or("").into(),
            trials: st["trials"].as_u64().unwrap_or(0),
            first_feasible_trial: first_feasible,
            final_trial: st["bestTrial"].as_u64().map(|i| i + 1),
            seconds,
            trial_history: history,
        };
        anyhow::Ok(result(
            name,
            method,
            defs,
            &r,
            st["bestConfig"].clone(),
            Some(cost),
        ))
    }
    .await;
    robot.close().await?;
    out
}

/// The Table III-like summary (pure).
pub fn table(results: &[MethodResult]) -> String {
    let mut rows = Vec::new();
    for r in results {
        let noncore: Vec<String> = r
            .metrics
            .iter()
            .map(|(k, v)| format!("{k}={v:.1}"))
            .collect();
        rows.push(vec![
            r.stack.clone(),
            r.method.clone(),
            format!("{:.1}%", r.satisfaction * 100.0),
            noncore.join(" "),
            r.tuning
                .as_ref()
                .map_or("-".into(), |t| format!("{} ({})", t.trials, t.phase)),
            r.tuning
                .as_ref()
                .map_or("-".into(), |t| format!("{:.0}", t.seconds)),
        ]);
    }
    let h = [
        "STACK",
        "METHOD",
        "SATISFACTION",
        "METRICS (Hz)",
        "TRIALS",
        "TUNING S",
    ]
    .map(String::from);
    crate::table::render(&h, &rows)
}

fn write_plots(
    out: &Path,
    name: &str,
    defs: &[MetricDef],
    results: &[MethodResult],
) -> anyhow::Result<()> {
    let of = |m: &str| results.iter().find(|r| r.stack == name && r.method == m);
    if let Some(t) = of("configbot").and_then(|r| r.tuning.as_ref()) {
        let trials = t.trial_history.as_array().cloned().unwrap_or_default();
        let mut c = progress_chart(&trials);
        c.title = format!("{name}: tuning progress");
        std::fs::write(out.join(format!("{name}-progress.svg")), c.to_svg())?;
    }
    if let (Some(core), Some(d), Some(c)) =
        (defs.iter().find(|d| d.core), of("default"), of("configbot"))
    {
        let report = |v: &[f64]| configbot_agent::measure::MeasureReport {
            started_unix_ms: 0,
            duration_ms: v.len() as u64 * 1000,
            sub_window_ms: 1000,
            series: vec![configbot_agent::measure::ProbeSeries {
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
