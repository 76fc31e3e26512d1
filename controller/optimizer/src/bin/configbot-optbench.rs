//! Benchmark and driveable CLI for the constrained Bayesian optimizer.
//!
//! - `configbot-optbench` (no arguments): the full comparison — this optimizer
//!   vs random search vs a Sobol sequence over 20 seeds per problem, the
//!   proposal-time measurement (100 observations, 10 dimensions), the UNSAT
//!   check and the safe-exploration check on the robot model; prints tables
//!   and writes `optbench.json` (best-feasible-so-far per evaluation).
//!   `--quick` shrinks seeds and budgets for CI; `--out PATH` moves the JSON;
//!   `--skip-compare` runs only the timing, UNSAT and safety parts.
//! - `--timing [--reps R] [--out PATH]`: the numerics' speed alone — a full
//!   GP fit (hyperparameters by multi-start L-BFGS) at 30 and 100 observations
//!   in 10 dimensions (and its held-out error, so a faster fit that fits worse
//!   shows), the mean proposal time at 100 observations, and the normal CDF
//!   (erfc) per call; times are this thread's CPU time (not wall clock), each
//!   the median of R repetitions; prints a table and writes
//!   `optbench-timing.json`.
//! - `--problem P --seed S --budget N [--method bo|random|sobol] [--safe] --json`:
//!   one run, printing its trace as JSON (for other tools).
//! - `--search-best P [--samples N] [--bo-runs K]`: large random search (plus
//!   the best configs of K optimizer runs) + coordinate refinement, to
//!   establish a problem's best-known feasible value.

use std::time::Instant;

use anyhow::{Context, Result, bail};
use configbot_optimizer::acquisition::norm_cdf;
use configbot_optimizer::design::Sobol;
use configbot_optimizer::gp::{FitOptions, Gp};
use configbot_optimizer::problems::{self, TestProblem};
use configbot_optimizer::rng::Rng;
use configbot_optimizer::{
    Constraint, Goal, Knob, Objective, Observation, Optimizer, Outcome, Problem, Proposal,
    SafetyFloor, Scalarization, Settings, Space,
};
use serde::Serialize;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
enum Method {
    Bo,
    Random,
    Sobol,
}

#[derive(Debug, Serialize)]
struct Trace {
    problem: String,
    method: Method,
    seed: u64,
    /// Best feasible scalar after each evaluation (null until one is feasible).
    best_so_far: Vec<Option<f64>>,
    /// Evaluations until within 5 % of the best-known value (null: not reached).
    evals_to_5pct: Option<usize>,
    outcome: Option<Outcome>,
    /// Safe mode: proposals whose true core metric was below the floor.
    floor_violations: usize,
    /// Proposal times (fit + acquisition), ms.
    ask_ms: Vec<f64>,
}

fn bo_settings(seed: u64, budget: usize, safe: bool) -> Settings {
    Settings {
        seed,
        max_trials: budget,
        safety: safe.then_some(SafetyFloor {
            fraction_of_target: 0.8,
            beta: 3.0,
        }),
        unsat_when_pof_below: Some(0.01),
        ..Settings::default()
    }
}

fn run(p: &TestProblem, method: Method, seed: u64, budget: usize, safe: bool) -> Result<Trace> {
    let mut best: Option<f64> = None;
    let mut trace = Trace {
        problem: p.name.to_owned(),
        method,
        seed,
        best_so_far: Vec::new(),
        evals_to_5pct: None,
        outcome: None,
        floor_violations: 0,
        ask_ms: Vec::new(),
    };
    let floor = SafetyFloor {
        fraction_of_target: 0.8,
        beta: 3.0,
    };
    let mut record = |trace: &mut Trace, obs: &configbot_optimizer::Observation| {
        if safe
            && p.problem
                .constraints
                .iter()
                .zip(&obs.constraints)
                .any(|(c, &v)| !floor.holds(c, v))
        {
            trace.floor_violations += 1;
        }
        if p.problem.is_feasible(obs) {
            let v = p.problem.scalarize(&obs.objectives);
            best = Some(best.map_or(v, |b: f64| b.max(v)));
        }
        trace.best_so_far.push(best);
        if trace.evals_to_5pct.is_none() && best.is_some_and(|b| p.within(b, 0.05)) {
            trace.evals_to_5pct = Some(trace.best_so_far.len());
        }
    };
    let dim = p.problem.space.dim();
    match method {
        Method::Bo => {
            let mut opt = Optimizer::new(
                p.problem.clone(),
                bo_settings(seed, budget, safe),
                &p.current,
            )?;
            loop {
                let t = Instant::now();
                let prop = opt.ask()?;
                trace.ask_ms.push(t.elapsed().as_secs_f64() * 1e3);
                match prop {
                    Proposal::Try(x) => {
                        let obs = p.evaluate(&x);
                        record(&mut trace, &obs);
                        opt.tell(obs)?;
                    }
                    Proposal::Stop(_) => break,
                }
            }
            trace.outcome = Some(opt.outcome());
        }
        Method::Random => {
            let mut rng = Rng::seed_from_u64(seed);
            for i in 0..budget {
                let u: Vec<f64> = (0..dim).map(|_| rng.uniform()).collect();
                let x = if i == 0 {
                    p.current.clone()
                } else {
                    p.problem.space.from_unit(&u)
                };
                record(&mut trace, &p.evaluate(&x));
            }
        }
        Method::Sobol => {
            let mut rng = Rng::seed_from_u64(seed);
            let s = Sobol::scrambled(dim, &mut rng);
            for i in 0..budget {
                let x = if i == 0 {
                    p.current.clone()
                } else {
                    p.problem.space.from_unit(&s.point(i as u64 - 1))
                };
                record(&mut trace, &p.evaluate(&x));
            }
        }
    }
    Ok(trace)
}

/// Random search + coordinate refinement for a best-known value; the best
/// configs of `bo_runs` optimizer runs (budget 200, seeds 1000..) join the refinement starts.
fn search_best(p: &TestProblem, samples: usize, bo_runs: u64) -> Result<(f64, Vec<f64>)> {
    let dim = p.problem.space.dim();
    let mut rng = Rng::seed_from_u64(12345);
    let mut tops: Vec<(f64, Vec<f64>)> = Vec::new();
    for _ in 0..samples {
        let u: Vec<f64> = (0..dim).map(|_| rng.uniform()).collect();
        let x = p.problem.space.from_unit(&u);
        if let Some(v) = p.feasible_value(&x) {
            tops.push((v, u));
            if tops.len() > 400 {
                tops.sort_by(|a, b| b.0.total_cmp(&a.0));
                tops.truncate(20);
            }
        }
    }
    tops.sort_by(|a, b| b.0.total_cmp(&a.0));
    tops.truncate(20);
    for seed in 0..bo_runs {
        let mut opt = Optimizer::new(
            p.problem.clone(),
            bo_settings(1000 + seed, 200, false),
            &p.current,
        )?;
        while let Proposal::Try(x) = opt.ask()? {
            opt.tell(p.evaluate(&x))?;
        }
        if let Outcome::Best { best, .. } = opt.outcome() {
            tops.push((best.value, p.problem.space.to_unit(&best.x)));
        }
    }
    let mut best = (f64::NEG_INFINITY, Vec::new());
    for (mut v, mut u) in tops {
        let mut step = 0.05;
        while step > 1e-7 {
            let mut improved = false;
            for k in 0..dim {
                for dir in [-1.0, 1.0] {
                    let mut t = u.clone();
                    t[k] = (t[k] + dir * step).clamp(0.0, 1.0);
                    if let Some(tv) = p.feasible_value(&p.problem.space.from_unit(&t))
                        && tv > v
                    {
                        v = tv;
                        u = t;
                        improved = true;
                    }
                }
            }
            if !improved {
                step *= 0.5;
            }
        }
        if v > best.0 {
            best = (v, p.problem.space.from_unit(&u));
        }
    }
    Ok(best)
}

fn arg(args: &[String], name: &str) -> Option<String> {
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1).cloned())
}

fn load(name: &str) -> Result<TestProblem> {
    problems::by_name(name)
        .with_context(|| format!("unknown problem {name:?}; known: {:?}", problems::NAMES))?
        .map_err(Into::into)
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if let Some(name) = arg(&args, "--search-best") {
        let p = load(&name)?;
        let samples = arg(&args, "--samples").map_or(Ok(200_000), |s| s.parse())?;
        let bo_runs = arg(&args, "--bo-runs").map_or(Ok(0), |s| s.parse())?;
        let (v, x) = search_best(&p, samples, bo_runs)?;
        println!(
            "{name}: best feasible scalar {v:.6} at {x:?} (stated best-known {:?})",
            p.best_known
        );
        return Ok(());
    }
    if let Some(name) = arg(&args, "--problem") {
        let p = load(&name)?;
        let seed = arg(&args, "--seed").map_or(Ok(0), |s| s.parse())?;
        let budget = arg(&args, "--budget").map_or(Ok(60), |s| s.parse())?;
        let method = match arg(&args, "--method").as_deref() {
            None | Some("bo") => Method::Bo,
            Some("random") => Method::Random,
            Some("sobol") => Method::Sobol,
            Some(m) => bail!("unknown method {m:?}; use bo, random or sobol"),
        };
        let trace = run(&p, method, seed, budget, args.iter().any(|a| a == "--safe"))?;
        if args.iter().any(|a| a == "--json") {
            println!("{}", serde_json::to_string(&trace)?);
        } else {
            println!(
                "{name} {method:?} seed {seed}: evals to 5% {:?}, final best {:?}",
                trace.evals_to_5pct,
                trace.best_so_far.last()
            );
        }
        return Ok(());
    }
    if args.iter().any(|a| a == "--timing") {
        return timing(&args);
    }
    full(&args)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    if v.is_empty() {
        return f64::NAN;
    }
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

fn percentile(mut v: Vec<f64>, q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(((v.len() as f64 - 1.0) * q).round() as usize)
        .copied()
        .unwrap_or(f64::NAN)
}

/// Median evaluations to 5 %, counting a run that never got there as budget + 1.
fn median_evals(traces: &[Trace], budget: usize) -> (f64, usize) {
    let reached = traces.iter().filter(|t| t.evals_to_5pct.is_some()).count();
    (
        median(
            traces
                .iter()
                .map(|t| t.evals_to_5pct.unwrap_or(budget + 1) as f64)
                .collect(),
        ),
        reached,
    )
}

fn fmt_median(m: f64, budget: usize) -> String {
    if m > budget as f64 {
        format!(">{budget}")
    } else {
        format!("{m:.1}")
    }
}

#[derive(Serialize)]
struct Report {
    comparison: Vec<Trace>,
    proposal_ms: ProposalTime,
    unsat: Vec<Trace>,
    safe: Vec<Trace>,
}

#[derive(Serialize)]
struct ProposalTime {
    dims: usize,
    observations: String,
    samples: usize,
    mean_ms: f64,
    p50_ms: f64,
    p99_ms: f64,
    max_ms: f64,
}

const TIMING_DIMS: usize = 10;

/// What the timings count: wall-clock time (the full run, as a user waits), or
/// this thread's CPU time (`--timing`), which a loaded machine inflates far
/// less: waiting for a core is not counted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Clock {
    Wall,
    Cpu,
}

impl Clock {
    /// Milliseconds since some fixed origin.
    fn now_ms(self) -> Result<f64> {
        static ORIGIN: std::sync::OnceLock<Instant> = std::sync::OnceLock::new();
        match self {
            Clock::Wall => Ok(ORIGIN.get_or_init(Instant::now).elapsed().as_secs_f64() * 1e3),
            Clock::Cpu => {
                // The first field is the time spent on a CPU, in nanoseconds.
                let path = "/proc/thread-self/schedstat";
                let text =
                    std::fs::read_to_string(path).with_context(|| format!("reading {path}"))?;
                let ns: f64 = text
                    .split_whitespace()
                    .next()
                    .and_then(|f| f.parse().ok())
                    .with_context(|| format!("no CPU time in {path}: {text:?}"))?;
                Ok(ns * 1e-6)
            }
        }
    }
}

/// The 10-knob problem the timings use: a smooth objective with some ripple
/// and one linear constraint.
fn timing_problem() -> Result<Problem> {
    let knobs = (0..TIMING_DIMS)
        .map(|i| Knob::linear(&format!("k{i}"), 0.0, 1.0))
        .collect();
    Ok(Problem::new(
        Space::new(knobs)?,
        vec![Objective::raw("f", Goal::Maximize)],
        vec![Constraint::at_most("load", 6.0)],
        Scalarization::MaxMin,
    )?)
}

fn timing_eval(x: &[f64]) -> Observation {
    let f = -x
        .iter()
        .enumerate()
        .map(|(i, v)| (v - 0.3 - 0.04 * i as f64).powi(2))
        .sum::<f64>()
        + 0.1 * (7.0 * x[0]).sin() * (5.0 * x[3]).cos();
    Observation {
        x: x.to_vec(),
        objectives: vec![f],
        constraints: vec![x.iter().sum()],
        censored: false,
    }
}

/// Proposal time with ~100 observations in 10 dimensions (asks at n = 100..120).
fn proposal_time(seeds: u64, asks: usize, clock: Clock) -> Result<ProposalTime> {
    let dim = TIMING_DIMS;
    let problem = timing_problem()?;
    let mut times = Vec::new();
    for seed in 0..seeds {
        let settings = Settings {
            seed,
            max_trials: 100 + asks,
            ..Settings::default()
        };
        let mut opt = Optimizer::new(problem.clone(), settings, &vec![0.5; dim])?;
        let mut rng = Rng::seed_from_u64(seed);
        let s = Sobol::scrambled(dim, &mut rng);
        for i in 0..99 {
            opt.tell(timing_eval(&s.point(i)))?;
        }
        opt.ask()?; // fits the hyperparameters once, as the previous step of a run would have
        opt.tell(timing_eval(&s.point(99)))?;
        for _ in 0..asks {
            let t = clock.now_ms()?;
            let p = opt.ask()?;
            times.push(clock.now_ms()? - t);
            match p {
                Proposal::Try(x) => opt.tell(timing_eval(&x))?,
                Proposal::Stop(_) => break,
            }
        }
    }
    Ok(ProposalTime {
        dims: dim,
        observations: format!("100..{}", 100 + asks),
        samples: times.len(),
        mean_ms: times.iter().sum::<f64>() / times.len().max(1) as f64,
        p50_ms: percentile(times.clone(), 0.5),
        p99_ms: percentile(times.clone(), 0.99),
        max_ms: percentile(times, 1.0),
    })
}

/// Full GP fits (fresh hyperparameters, default [`FitOptions`]) on `n`
/// Sobol points of the timing problem, one per seed in `0..fits`: the mean
/// CPU time per fit (ms; timed as one batch, as the CPU clock ticks coarsely)
/// and the median root-mean-square error of the fitted mean on 200 random
/// held-out points (the fits' quality, deterministic).
fn gp_fit(n: usize, fits: u64) -> Result<(f64, f64)> {
    let data: Vec<(Vec<Vec<f64>>, Vec<f64>, Rng)> = (0..fits)
        .map(|seed| {
            let mut rng = Rng::seed_from_u64(seed);
            let x = Sobol::scrambled(TIMING_DIMS, &mut rng).points(0, n);
            let y = x.iter().map(|u| timing_eval(u).objectives[0]).collect();
            (x, y, rng)
        })
        .collect();
    let t = Clock::Cpu.now_ms()?;
    let gps = data
        .iter()
        .map(|(x, y, rng)| Gp::fit(x, y, &FitOptions::default(), None, &mut rng.clone()))
        .collect::<configbot_optimizer::Result<Vec<Gp>>>()?;
    let per_fit = (Clock::Cpu.now_ms()? - t) / fits as f64;
    let errors = gps
        .iter()
        .zip(data)
        .map(|(gp, (_, _, mut rng))| {
            let held_out: Vec<Vec<f64>> = (0..200)
                .map(|_| (0..TIMING_DIMS).map(|_| rng.uniform()).collect())
                .collect();
            let sq: f64 = gp
                .predict_many(&held_out)
                .iter()
                .zip(&held_out)
                .map(|((m, _), u)| (m - timing_eval(u).objectives[0]).powi(2))
                .sum();
            (sq / held_out.len() as f64).sqrt()
        })
        .collect();
    Ok((per_fit, median(errors)))
}

/// Nanoseconds per call of the normal CDF (the erfc behind every probability
/// of feasibility and EI), over arguments spread across its range.
fn norm_cdf_ns(calls: usize) -> Result<f64> {
    let t = Clock::Cpu.now_ms()?;
    let mut sum = 0.0;
    for i in 0..calls {
        sum += norm_cdf(std::hint::black_box(-12.0 + 16.0 * i as f64 / calls as f64));
    }
    std::hint::black_box(sum);
    Ok((Clock::Cpu.now_ms()? - t) * 1e6 / calls as f64)
}

#[derive(Serialize)]
struct Timing {
    reps: usize,
    dims: usize,
    /// Per metric: the median over the repetitions, then every repetition.
    gp_fit_n30_ms: (f64, Vec<f64>),
    gp_fit_n100_ms: (f64, Vec<f64>),
    /// Held-out RMSE of the fits (identical in every repetition).
    gp_fit_n30_rmse: f64,
    gp_fit_n100_rmse: f64,
    proposal_mean_ms: (f64, Vec<f64>),
    norm_cdf_ns: (f64, Vec<f64>),
}

fn timing(args: &[String]) -> Result<()> {
    let reps = arg(args, "--reps").map_or(Ok(5), |s| s.parse())?;
    let out = arg(args, "--out").unwrap_or_else(|| "optbench-timing.json".into());
    let mut cols: [Vec<f64>; 4] = Default::default();
    let (mut rmse30, mut rmse100) = (f64::NAN, f64::NAN);
    for _ in 0..reps {
        let (t, e) = gp_fit(30, 200)?;
        cols[0].push(t);
        rmse30 = e;
        let (t, e) = gp_fit(100, 20)?;
        cols[1].push(t);
        rmse100 = e;
        cols[2].push(proposal_time(2, 5, Clock::Cpu)?.mean_ms);
        cols[3].push(norm_cdf_ns(2_000_000)?);
    }
    let [a, b, c, d] = cols.map(|v| (median(v.clone()), v));
    println!(
        "numerics timing (this thread's CPU time), {TIMING_DIMS} dims, median of {reps} repetitions"
    );
    for (name, (m, all)) in [
        ("gp fit, 30 observations (ms per fit)", &a),
        ("gp fit, 100 observations (ms per fit)", &b),
        ("proposal, 100..105 observations (ms)", &c),
        ("normal cdf per call (ns)", &d),
    ] {
        let all: Vec<String> = all.iter().map(|v| format!("{v:.2}")).collect();
        println!("{name:<42} {m:>9.2}   [{}]", all.join(", "));
    }
    println!("gp fit held-out rmse, 30 / 100 observations  {rmse30:.6} / {rmse100:.6}");
    let report = Timing {
        reps,
        dims: TIMING_DIMS,
        gp_fit_n30_ms: a,
        gp_fit_n100_ms: b,
        gp_fit_n30_rmse: rmse30,
        gp_fit_n100_rmse: rmse100,
        proposal_mean_ms: c,
        norm_cdf_ns: d,
    };
    std::fs::write(&out, serde_json::to_string_pretty(&report)?)
        .with_context(|| format!("writing {out}"))?;
    println!("wrote {out}");
    Ok(())
}

fn full(args: &[String]) -> Result<()> {
    let quick = args.iter().any(|a| a == "--quick");
    let out = arg(args, "--out").unwrap_or_else(|| "optbench.json".into());
    let seeds: u64 = if quick { 3 } else { 20 };
    let baseline_budget = if quick { 500 } else { 3000 };
    let mut comparison = Vec::new();
    println!(
        "median evaluations to reach within 5% of the best-known feasible value ({seeds} seeds)"
    );
    println!(
        "{:<16} {:>6} {:>12} {:>12} {:>12} {:>14} {:>14} {:>10}",
        "problem", "dims", "bo", "random", "sobol", "random/bo", "sobol/bo", "bo reached"
    );
    let names: &[&str] = if args.iter().any(|a| a == "--skip-compare") {
        &[]
    } else {
        &[
            "gardner",
            "gramacy",
            "branin",
            "pressure-vessel",
            "welded-beam",
            "robot",
        ]
    };
    for &name in names {
        let p = load(name)?;
        let bo_budget = match (quick, p.problem.space.dim()) {
            (true, _) => 30,
            (false, d) if d <= 2 => 60,
            (false, d) if d <= 4 => 100,
            (false, _) => 200,
        };
        let per = |m: Method, budget: usize| -> Result<Vec<Trace>> {
            (0..seeds).map(|s| run(&p, m, s, budget, false)).collect()
        };
        let bo = per(Method::Bo, bo_budget)?;
        let rnd = per(Method::Random, baseline_budget)?;
        let sob = per(Method::Sobol, baseline_budget)?;
        let (mb, rb) = median_evals(&bo, bo_budget);
        let (mr, _) = median_evals(&rnd, baseline_budget);
        let (ms, _) = median_evals(&sob, baseline_budget);
        let ratio = |base: f64| {
            if mb > bo_budget as f64 {
                "n/a".to_owned()
            } else {
                format!(
                    "{}{:.1}x",
                    if base > baseline_budget as f64 {
                        ">"
                    } else {
                        ""
                    },
                    base / mb
                )
            }
        };
        println!(
            "{:<16} {:>6} {:>12} {:>12} {:>12} {:>14} {:>14} {:>7}/{}",
            name,
            p.problem.space.dim(),
            fmt_median(mb, bo_budget),
            fmt_median(mr, baseline_budget),
            fmt_median(ms, baseline_budget),
            ratio(mr),
            ratio(ms),
            rb,
            seeds
        );
        comparison.extend(bo.into_iter().chain(rnd).chain(sob));
    }

    let pt = proposal_time(
        if quick { 2 } else { 10 },
        if quick { 5 } else { 20 },
        Clock::Wall,
    )?;
    println!(
        "\nproposal time (fit + acquisition), {} dims, {} observations: p50 {:.1} ms, p99 {:.1} ms, max {:.1} ms ({} samples)",
        pt.dims, pt.observations, pt.p50_ms, pt.p99_ms, pt.max_ms, pt.samples
    );

    let inf = load("gramacy-infeasible")?;
    let unsat: Vec<Trace> = (0..seeds)
        .map(|s| run(&inf, Method::Bo, s, 40, false))
        .collect::<Result<_>>()?;
    let n_unsat = unsat
        .iter()
        .filter(|t| matches!(t.outcome, Some(Outcome::Unsat { .. })))
        .count();
    let trials = median(unsat.iter().map(|t| t.best_so_far.len() as f64).collect());
    println!(
        "\ninfeasible problem (gramacy-infeasible, budget 40): UNSAT in {n_unsat}/{seeds} runs, median trials used {trials:.0}"
    );
    if let Some(Some(Outcome::Unsat { unsat: u, reason })) =
        unsat.first().map(|t| t.outcome.clone())
    {
        println!(
            "  seed 0 evidence: reason {reason:?}, nearest violation {:.4} at {:?}, p_any_feasible {:?}",
            u.nearest_violation,
            u.nearest.map(|o| o.x),
            u.p_any_feasible
        );
    }

    let robot = load("robot")?;
    let safe_budget = if quick { 30 } else { 60 };
    let safe: Vec<Trace> = (0..seeds)
        .map(|s| run(&robot, Method::Bo, s, safe_budget, true))
        .collect::<Result<_>>()?;
    let violations: usize = safe.iter().map(|t| t.floor_violations).sum();
    let proposals: usize = safe.iter().map(|t| t.best_so_far.len()).sum();
    let (ms, reached) = median_evals(&safe, safe_budget);
    println!(
        "\nsafe exploration on robot (floor 0.8 x target, beta 3): {violations} floor violations in {proposals} proposals; median evals to 5% {} ({reached}/{seeds} reached)",
        fmt_median(ms, safe_budget)
    );

    let report = Report {
        comparison,
        proposal_ms: pt,
        unsat,
        safe,
    };
    std::fs::write(&out, serde_json::to_string(&report)?)
        .with_context(|| format!("writing {out}"))?;
    println!("\nwrote {out}");
    Ok(())
}
