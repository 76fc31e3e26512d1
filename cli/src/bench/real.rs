//! `configbot bench --stacks real`: the real Debian ROS 1 stacks of
//! `manifests/examples/real/`, robot software nobody here wrote. For each
//! stack, every row is an independent measurement of `--window-secs`
//! (60 s by default for real stacks) on a fresh robot:
//!
//! - `launch-default`: every node started by the bench as one launch
//!   session, as roslaunch runs them: no cgroup of their own, no limits;
//! - `default`: the agent's per-node default (each node its own cgroup,
//!   equal weights, no limits);
//! - `cgroup-only` and `configbot`: a tuning run (adaptors off / on), then
//!   the config it keeps measured again; ConfigBot runs once per seed
//!   (`--seeds`), each row `configbot-seed-N`, and `configbot` is the run
//!   with the median objective;
//! - `oracle`: `--oracle-configs` space-filling configs of the same knob
//!   space ([`oracle`]), each from a drained state, and the best one that
//!   holds ≥ 99.5 % over a full window; a candidate whose window missed in
//!   bursts is verified again with the core nodes weighted, as a tuning
//!   run would verify it. The oracle is the yardstick of a stack on a
//!   machine class: `--oracle-from DIR` takes it from an earlier bench's
//!   `oracle-<stack>.json` instead of measuring it again (about 20 min per
//!   stack), when that file was measured for the same manifests on a
//!   machine of the same class ([`reusable`]);
//! - `oracle-here`, with `--oracle-from`: the reused oracle's best config
//!   measured again on this machine, the check that the oracle stands for
//!   it ([`stands_here`]): VMs of one class differ, and one VM from hour
//!   to hour. It is measured first, before the other rows of its stack,
//!   and its row is listed after the oracle's.

use std::path::Path;
use std::process::Stdio;
use std::time::Duration;

use configbot_manifests::{PerformanceSpec, ResourceConfig, RobotStack};
use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::owner::Current;
use super::{BenchArgs, FLOW_TIMEOUT, MethodResult, result, start, tuned, wait_until_up};
use crate::demo::{example, measure_defs};
use configbot_controller::tuning::robot::Robot;
use configbot_tuning::knobs::KnobSpace;
use configbot_tuning::library;
use configbot_tuning::measure::{self, MetricDef};
use configbot_tuning::outcome;
use configbot_tuning::settle;

/// The real stacks, by the name `--stacks` takes (`real` means all of them).
pub const STACKS: [&str; 3] = ["real-perception", "real-nodelets", "real-two-paths"];

/// Satisfaction the oracle's best config must hold over a full window.
pub const ORACLE_HOLDS: f64 = 0.995;

/// Whether `name` is a real stack.
pub fn is_real(name: &str) -> bool {
    STACKS.contains(&name)
}

/// `--stacks` with `real` expanded to every real stack.
pub fn expand(stacks: &[String]) -> Vec<String> {
    let mut out = Vec::new();
    for s in stacks {
        if s == "real" {
            out.extend(STACKS.iter().map(|s| s.to_string()));
        } else {
            out.push(s.clone());
        }
    }
    out
}

/// The rows of a real stack (`--real-methods`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Method {
    LaunchDefault,
    Default,
    CgroupOnly,
    Configbot,
    Oracle,
}

/// The settings of the real-stack rows (`--quick` shortens them).
#[derive(Debug, Clone)]
pub struct RealPlan {
    pub window: u64,
    pub seeds: Vec<u64>,
    pub methods: Vec<Method>,
    pub oracle_configs: usize,
    pub oracle_window: u64,
    pub max_trials: Option<u32>,
}

/// Every row of one real stack, in order; `earlier` is the stack's oracle
/// taken from `--oracle-from` ([`load_oracles`]), reported instead of
/// measuring one.
pub async fn run_stack(
    cur: &mut Current,
    a: &BenchArgs,
    p: &RealPlan,
    name: &str,
    earlier: Option<Oracle>,
) -> anyhow::Result<(Vec<MethodResult>, Option<Oracle>)> {
    let (stack, mut spec) = example(name)?;
    if let Some(m) = p.max_trials {
        spec.spec.tuning.max_trials = spec.spec.tuning.max_trials.min(m);
        spec.spec.tuning.record_seconds = spec
            .spec
            .tuning
            .record_seconds
            .min(super::QUICK_RECORD_SECONDS);
    }
    let defs = measure::metric_defs(&stack.spec, &spec.spec);
    let mut rows = Vec::new();
    let runs_row = |m: Method| p.methods.contains(&m);
    // A reused oracle's best config is measured on this machine first, so
    // a machine that no longer gives what the oracle recorded says so
    // before the rows that would be read against it (session 63: on the VM
    // of session 62, three hours later, real-nodelets' oracle config held
    // 90 % and real-perception's gave 0.76x; the check came after the
    // seeds, 40 minutes in). Its row still goes after the oracle's.
    let mut here = None;
    if let Some(best) = earlier
        .as_ref()
        .filter(|o| o.reused_from.is_some())
        .and_then(|o| o.best.as_ref())
    {
        println!(
            "==> {name}: the oracle's best config, measured on this machine ({} s)",
            p.window
        );
        let row = best_here(cur, a, name, &stack, &spec, &defs, best, p.window).await?;
        let check = stands_here(&defs, best, &row);
        println!("    {name}: {}", check.said());
        here = Some((row, check));
    }
    if runs_row(Method::LaunchDefault) {
        println!("==> {name}: launch default ({} s)", p.window);
        rows.push(launch_default(cur, a, name, &stack, &defs, p.window).await?);
    }
    if runs_row(Method::Default) {
        println!("==> {name}: per-node default ({} s)", p.window);
        rows.push(per_node_default(cur, a, name, &stack, &defs, p.window).await?);
    }
    if runs_row(Method::CgroupOnly) {
        println!("==> {name}: cgroup-only");
        let mut cg = spec.clone();
        cg.spec.knobs.adaptors.enabled = false;
        rows.push(tuned(cur, a, name, "cgroup-only", &stack, &cg, p.window).await?);
    }
    let mut runs = Vec::new();
    let seeds = if runs_row(Method::Configbot) {
        p.seeds.as_slice()
    } else {
        &[]
    };
    for &seed in seeds {
        println!("==> {name}: configbot, seed {seed}");
        let mut s = spec.clone();
        s.spec.tuning.seed = seed;
        let method = format!("configbot-seed-{seed}");
        runs.push(tuned(cur, a, name, &method, &stack, &s, p.window).await?);
    }
    if let Some(mut median) = median_run(&defs, &runs) {
        median.method = "configbot".into();
        rows.extend(runs);
        rows.push(median);
    }
    let mut oracle = if let Some(o) = earlier {
        println!(
            "==> {name}: oracle from {} (measured {}), not measured again",
            o.reused_from.as_deref().unwrap_or("an earlier bench"),
            o.measured_at.as_deref().unwrap_or("at an unrecorded time")
        );
        Some(o)
    } else if p.oracle_configs > 0 && runs_row(Method::Oracle) {
        println!(
            "==> {name}: oracle, {} configs of {} s",
            p.oracle_configs, p.oracle_window
        );
        Some(oracle(cur, a, p, name, &stack, &spec, &defs).await?)
    } else {
        None
    };
    if let Some(o) = oracle.as_mut()
        && let Some(best) = o.best.clone()
    {
        rows.push(best);
        if let Some((row, check)) = here {
            o.here = Some(check);
            rows.push(row);
        }
    }
    Ok((rows, oracle))
}

/// Share of its recorded objective the oracle's best config must give when
/// measured again on this machine for the oracle to stand for it
/// ([`stands_here`]).
pub const HERE_KEEPS: f64 = 0.9;

/// Whether an oracle taken from an earlier bench is a yardstick of this
/// machine (pure): its best config, `here` measured again in this run
/// (row `oracle-here`), held ≥ [`ORACLE_HOLDS`] and gave ≥ [`HERE_KEEPS`]
/// of the objective it was recorded with (`recorded`). Two VMs of one
/// machine class (model name and CPU count) differed 1.7× on
/// real-perception (sessions 50 and 51): the class check alone let a
/// faster VM's oracle stand. The note says how it compared and, when it
/// does not stand, why the ratios against it say little here.
pub fn stands_here(defs: &[MetricDef], recorded: &MethodResult, here: &MethodResult) -> Here {
    let (was, is) = (objective(defs, recorded), objective(defs, here));
    let ratio = if was > 0.0 { is / was } else { 1.0 };
    let said = format!(
        "its best config gave {:.1} %, objective {is:.3} here against {:.1} %, {was:.3} where it was measured ({ratio:.2}x)",
        here.satisfaction * 100.0,
        recorded.satisfaction * 100.0,
    );
    let fails = |note: String| Here {
        stands: false,
        note,
    };
    if here.satisfaction < ORACLE_HOLDS {
        return fails(format!(
            "{said}: it misses the core targets on this machine, so the oracle is no yardstick here; measure the oracle here (--real-methods oracle, without --oracle-from)"
        ));
    }
    if ratio < HERE_KEEPS {
        return fails(format!(
            "{said}: this machine gives less than the one it was measured on, so X ORACLE understates every row here, and X HERE (against that config measured beside them, no search of this machine) may overstate them; measure the oracle here (--real-methods oracle, without --oracle-from)"
        ));
    }
    Here {
        stands: true,
        note: said,
    }
}

/// The oracle's best config measured again on a fresh robot of this run,
/// from a drained state as the oracle measured it: row `oracle-here`.
#[allow(clippy::too_many_arguments)]
async fn best_here(
    cur: &mut Current,
    a: &BenchArgs,
    name: &str,
    stack: &RobotStack,
    spec: &PerformanceSpec,
    defs: &[MetricDef],
    best: &MethodResult,
    window: u64,
) -> anyhow::Result<MethodResult> {
    let config: ResourceConfig = serde_json::from_value(best.config.clone())
        .map_err(|e| anyhow::anyhow!("{name}: the oracle's best config: {e}"))?;
    let robot = start(cur, &a.out, name, "oracle-here", stack, defs).await?;
    let out = async {
        let r = robot.robot.as_ref();
        let space = super::live_space(r, stack, spec).await?;
        let rep = measure_from_drained(r, &space, defs, &config, window).await?;
        anyhow::Ok(result(
            name,
            "oracle-here",
            defs,
            &rep,
            best.config.clone(),
            None,
        ))
    }
    .await;
    cur.close().await?;
    out
}

/// The run whose scalarised objective is the median of `runs` (pure); for
/// an even count the lower of the two middle ones.
pub fn median_run(defs: &[MetricDef], runs: &[MethodResult]) -> Option<MethodResult> {
    let mut sorted: Vec<&MethodResult> = runs.iter().collect();
    sorted.sort_by(|a, b| objective(defs, a).total_cmp(&objective(defs, b)));
    sorted
        .get(sorted.len().saturating_sub(1) / 2)
        .map(|r| (*r).clone())
}

/// The scalarised objective (max-min of capped, normalised objectives) of a
/// measured row; 1 without objectives; 0 for a run that had not settled in
/// its time and measured nothing (so the median ranks it lowest).
pub fn objective(defs: &[MetricDef], r: &MethodResult) -> f64 {
    if r.unfinished() {
        return 0.0;
    }
    measure::scalarize(defs, &r.metrics, Default::default()).unwrap_or(1.0)
}

/// The stack's nodes as one launch session: started by this process with
/// the robot's ROS master, in this process's own cgroup, no limits.
async fn launch_default(
    cur: &mut Current,
    a: &BenchArgs,
    name: &str,
    stack: &RobotStack,
    defs: &[MetricDef],
    window: u64,
) -> anyhow::Result<MethodResult> {
    let dir = super::fresh_dir(&a.out, name, "launch-default")?;
    let robot = cur.start(&dir).await?;
    let logs = dir.join("launch");
    std::fs::create_dir_all(&logs)?;
    let mut children = Vec::new();
    for (_, node) in stack.spec.nodes() {
        let Some(run) = &node.run else { continue };
        let log = std::fs::File::create(logs.join(format!(
            "{}.log",
            node.name.trim_start_matches('/').replace('/', "_")
        )))?;
        let mut cmd = tokio::process::Command::new(&run.command);
        cmd.args(&run.args)
            .envs(&run.env)
            .env("ROS_MASTER_URI", &robot.master_uri)
            .stdin(Stdio::null())
            .stdout(log.try_clone()?)
            .stderr(log)
            .kill_on_drop(true);
        children.push(cmd.spawn().map_err(|e| {
            anyhow::anyhow!("{name}: starting {} ({}): {e}", node.name, run.command)
        })?);
    }
    let out = async {
        let silent = wait_until_up(robot.robot.as_ref(), defs, FLOW_TIMEOUT).await;
        if !silent.is_empty() {
            println!(
                "    {name}: no messages on {} under the launch default",
                silent.join(", ")
            );
        }
        let r = measure_defs(robot.robot.as_ref(), defs, window).await?;
        anyhow::Ok(result(name, "launch-default", defs, &r, Value::Null, None))
    }
    .await;
    for mut c in children {
        let _ = c.kill().await;
    }
    cur.close().await?;
    out
}

/// The agent's per-node default: every node in its own cgroup, no limits.
async fn per_node_default(
    cur: &mut Current,
    a: &BenchArgs,
    name: &str,
    stack: &RobotStack,
    defs: &[MetricDef],
    window: u64,
) -> anyhow::Result<MethodResult> {
    let robot = start(cur, &a.out, name, "default", stack, defs).await?;
    let out = async {
        let r = measure_defs(robot.robot.as_ref(), defs, window).await?;
        anyhow::Ok(result(name, "default", defs, &r, Value::Null, None))
    }
    .await;
    cur.close().await?;
    out
}

/// One config the oracle measured.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct OracleConfig {
    pub x: Vec<f64>,
    pub config: ResourceConfig,
    pub satisfaction: f64,
    pub objective: f64,
    pub metrics: std::collections::BTreeMap<String, f64>,
}

/// One verification of an oracle candidate over a full window.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct OracleVerification {
    /// Index into `Oracle::configs`.
    pub config: usize,
    /// With the core nodes at [`configbot_tuning::knobs::CORE_WEIGHT`]: the candidate's
    /// unweighted minute missed in bursts ([`outcome::bursts`]), and a
    /// tuning run would verify it so next.
    pub weighted: bool,
    pub satisfaction: f64,
    /// The satisfaction of the minute after, the config left in place, when
    /// this one held: the minute the candidate is reported by.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub then: Option<f64>,
}

/// What the oracle measured on one stack.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct Oracle {
    pub stack: String,
    /// When it was measured (RFC 3339, UTC).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub measured_at: Option<String>,
    /// The machine it was measured on.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub machine: Option<Machine>,
    /// [`library::stack_digest`] of the manifests it was measured for.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stack_digest: Option<String>,
    /// The file a bench took it from (`--oracle-from`) instead of measuring it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reused_from: Option<String>,
    pub knobs: Vec<String>,
    pub pinned: Vec<String>,
    pub window_seconds: u64,
    pub configs: Vec<OracleConfig>,
    /// Candidates verified over a full window, in order.
    pub verified: Vec<OracleVerification>,
    /// The best config that held ≥ 99.5 % over a full window and then over
    /// another, as measured in the second.
    pub best: Option<MethodResult>,
    /// A reused oracle only: whether it stands for the machine that reused
    /// it, by its best config measured again there ([`stands_here`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub here: Option<Here>,
}

/// The check that a reused oracle stands for this machine ([`stands_here`]).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct Here {
    pub stands: bool,
    /// How its best config compared, and why it does not stand if not.
    pub note: String,
}

impl Here {
    /// The note, marked when the oracle does not stand.
    pub fn said(&self) -> String {
        if self.stands {
            self.note.clone()
        } else {
            format!("WARNING: {}", self.note)
        }
    }
}

/// The machine a measurement ran on; an oracle stands for another run on
/// the same class of machine (CPUs and model), whatever its hostname.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct Machine {
    pub hostname: String,
    /// CPUs this process may run on.
    pub cpus: usize,
    /// `model name` in `/proc/cpuinfo`.
    pub cpu_model: String,
}

impl Machine {
    /// The machine this bench runs on.
    pub fn here() -> Machine {
        let read = |p: &str| std::fs::read_to_string(p).unwrap_or_default();
        let cpu_model = read("/proc/cpuinfo")
            .lines()
            .find_map(|l| {
                let (k, v) = l.split_once(':')?;
                (k.trim() == "model name").then(|| v.trim().to_string())
            })
            .unwrap_or_default();
        Machine {
            hostname: read("/proc/sys/kernel/hostname").trim().to_string(),
            cpus: std::thread::available_parallelism().map_or(0, |n| n.get()),
            cpu_model,
        }
    }
}

/// Whether `o`, an oracle an earlier bench wrote, may stand for this run's
/// oracle of `stack` (pure): measured for the manifests whose
/// [`library::stack_digest`] is `digest`, on a machine of `here`'s class.
/// `Ok` carries what could not be checked or differs harmlessly (an oracle
/// written before the bench recorded its manifests or machine, another
/// hostname), to be printed; `Err` says why it may not.
pub fn reusable(
    o: &Oracle,
    stack: &str,
    digest: &str,
    here: &Machine,
) -> Result<Vec<String>, String> {
    if o.stack != stack {
        return Err(format!("it is the oracle of {}, not of {stack}", o.stack));
    }
    let mut notes = Vec::new();
    match &o.stack_digest {
        Some(d) if d != digest => {
            return Err(format!(
                "it was measured for other manifests of {stack} (digest {d}; these are {digest}): measure it again"
            ));
        }
        Some(_) => {}
        None => notes.push(
            "it records no manifest digest (written before the bench kept one): the manifests are not checked"
                .to_string(),
        ),
    }
    match &o.machine {
        Some(m) if m.cpus != here.cpus || m.cpu_model != here.cpu_model => {
            return Err(format!(
                "it was measured on {} CPUs of {:?}, this machine has {} of {:?}: an oracle is a yardstick of its machine class",
                m.cpus, m.cpu_model, here.cpus, here.cpu_model
            ));
        }
        Some(m) if m.hostname != here.hostname => notes.push(format!(
            "it was measured on host {}, a machine of this one's class",
            m.hostname
        )),
        Some(_) => {}
        None => notes.push(
            "it records no machine (written before the bench kept one): the machine class is not checked"
                .to_string(),
        ),
    }
    Ok(notes)
}

/// The oracles `--oracle-from DIR` names for `stacks` (each real stack's
/// `DIR/oracle-<stack>.json`), read and checked ([`reusable`]) before the
/// bench starts any robot, so a missing or unfit file stops it with nothing
/// measured; notes are printed.
pub fn load_oracles(
    dir: &Path,
    stacks: &[String],
) -> anyhow::Result<std::collections::BTreeMap<String, Oracle>> {
    let here = Machine::here();
    let mut out = std::collections::BTreeMap::new();
    for name in stacks.iter().filter(|s| is_real(s)) {
        let (mut o, notes) = read_oracle(dir, name, Some(&here))
            .map_err(|e| anyhow::anyhow!("--oracle-from: {e}"))?;
        let path = oracle_path(dir, name);
        for n in notes {
            println!("    {}: {n}", path.display());
        }
        o.reused_from = Some(path.display().to_string());
        // An earlier bench's check of the file is of its machine, not this one.
        o.here = None;
        out.insert(name.clone(), o);
    }
    Ok(out)
}

fn oracle_path(dir: &Path, stack: &str) -> std::path::PathBuf {
    dir.join(format!("oracle-{stack}.json"))
}

/// Reads `dir`'s oracle of `stack` and checks that it may stand for one of
/// today's manifests on a machine of `class`'s class ([`reusable`]; the
/// machine the file names when `None`): the oracle and the check's notes.
fn read_oracle(
    dir: &Path,
    stack: &str,
    class: Option<&Machine>,
) -> anyhow::Result<(Oracle, Vec<String>)> {
    let path = oracle_path(dir, stack);
    let text = std::fs::read_to_string(&path)
        .map_err(|e| anyhow::anyhow!("reading {}: {e}", path.display()))?;
    let o: Oracle =
        serde_json::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    let (st, spec) = example(stack)?;
    let digest = library::stack_digest(&st.spec, &spec.spec);
    let class = match class.or(o.machine.as_ref()) {
        Some(m) => m.clone(),
        None => anyhow::bail!("{} names no machine to check it against", path.display()),
    };
    let notes = reusable(&o, stack, &digest, &class)
        .map_err(|e| anyhow::anyhow!("{} cannot stand for this run's: {e}", path.display()))?;
    Ok((o, notes))
}

/// The points the oracle measures (pure): the two corners of the knob
/// space (everything at its minimum, everything at its maximum), then a
/// scrambled Sobol design, `n` in all; pinned knobs stay pinned.
pub fn oracle_points(space: &KnobSpace, n: usize, seed: u64) -> Vec<Vec<f64>> {
    let dim = space.knobs.len();
    let lo: Vec<f64> = space.knobs.iter().map(|k| k.min).collect();
    let hi: Vec<f64> = space.knobs.iter().map(|k| k.max).collect();
    let mut out = vec![lo, hi];
    out.truncate(n);
    if dim == 0 || out.len() >= n {
        return out;
    }
    let opt_space = space.optimizer_space().ok();
    let mut rng = configbot_optimizer::rng::Rng::seed_from_u64(seed);
    let sobol = configbot_optimizer::design::Sobol::scrambled(dim, &mut rng);
    for u in sobol.points(1, n - out.len()) {
        let x = match &opt_space {
            Some(s) => s.from_unit(&u),
            None => u,
        };
        out.push(x);
    }
    out
}

/// Measures the oracle's configs, then verifies the best ones over a full
/// window ([`oracle_candidates`]) until one holds ≥ [`ORACLE_HOLDS`] (weighted on bursts, as a
/// tuning run verifies) in that window and in the next, which it is
/// reported by. A tuning run's row is a window measured after its own
/// verification held; an oracle row taken from the window it was chosen
/// by would be the luckier draw of the two. Measured on real-nodelets
/// (2026-11-26): a ConfigBot run held its verification minute and missed
/// 3 windows of the next, and the oracle's first pick, which held its 6 s,
/// missed 2 of its minute.
async fn oracle(
    cur: &mut Current,
    a: &BenchArgs,
    p: &RealPlan,
    name: &str,
    stack: &RobotStack,
    spec: &PerformanceSpec,
    defs: &[MetricDef],
) -> anyhow::Result<Oracle> {
    let robot = start(cur, &a.out, name, "oracle", stack, defs).await?;
    let out = async {
        let r = robot.robot.as_ref();
        let space = super::live_space(r, stack, spec).await?;
        let points = oracle_points(&space, p.oracle_configs, a.seed);
        let mut configs = Vec::new();
        for (i, x) in points.iter().enumerate() {
            let config = space.to_config(x);
            let rep = measure_from_drained(r, &space, defs, &config, p.oracle_window).await?;
            let e = measure::evaluate(defs, &rep, Default::default());
            println!(
                "    config {:>2}/{}: satisfaction {:5.1} %, objective {:.3}",
                i + 1,
                points.len(),
                e.satisfaction * 100.0,
                e.objective.unwrap_or(1.0)
            );
            configs.push(OracleConfig {
                x: x.clone(),
                config,
                satisfaction: e.satisfaction,
                objective: e.objective.unwrap_or(1.0),
                metrics: e.means,
            });
        }
        let mut verified = Vec::new();
        let mut best = None;
        let weighted_space = KnobSpace {
            weighted: true,
            ..space.clone()
        };
        let mut missed: Vec<usize> = Vec::new();
        for i in oracle_candidates(&configs) {
            if let Some(&m) = missed
                .iter()
                .find(|&&m| space.gives_no_less(&configs[i].x, &configs[m].x))
            {
                println!(
                    "    config {:>2} skipped: it gives the non-core apps as much as config {}, which missed",
                    i + 1,
                    m + 1
                );
                continue;
            }
            let mut config = configs[i].config.clone();
            let mut weighted = false;
            loop {
                let row_of = |rep: &configbot_api::measure::MeasureReport| -> anyhow::Result<MethodResult> {
                    let config = serde_json::to_value(&config)?;
                    Ok(result(name, "oracle", defs, rep, config, None))
                };
                let rep = measure_from_drained(r, &space, defs, &config, p.window).await?;
                let row = row_of(&rep)?;
                let mut v = OracleVerification {
                    config: i,
                    weighted,
                    satisfaction: row.satisfaction,
                    then: None,
                };
                let mut last = rep;
                if row.satisfaction >= ORACLE_HOLDS {
                    let rep = measure_defs(r, defs, p.window).await?;
                    let then = row_of(&rep)?;
                    println!(
                        "    config {:>2} held {:.1} %; the minute after: {:.1} %",
                        i + 1,
                        row.satisfaction * 100.0,
                        then.satisfaction * 100.0
                    );
                    v.then = Some(then.satisfaction);
                    verified.push(v);
                    if then.satisfaction >= ORACLE_HOLDS {
                        best = Some(then);
                        break;
                    }
                    last = rep;
                } else {
                    verified.push(v);
                }
                let e = measure::evaluate(defs, &last, Default::default());
                if weighted || space.core.is_empty() || !outcome::bursts(defs, &e) {
                    break;
                }
                println!(
                    "    config {:>2} missed in bursts ({:.1} %): verifying it again with the core nodes weighted",
                    i + 1,
                    e.satisfaction * 100.0
                );
                weighted = true;
                config = weighted_space.weigh(config);
            }
            if best.is_some() {
                break;
            }
            missed.push(i);
        }
        anyhow::Ok(Oracle {
            stack: name.into(),
            measured_at: Some(now_rfc3339()),
            machine: Some(Machine::here()),
            stack_digest: Some(library::stack_digest(&stack.spec, &spec.spec)),
            reused_from: None,
            knobs: space.knobs.iter().map(|k| k.name.clone()).collect(),
            pinned: space.pinned_names().iter().map(|s| s.to_string()).collect(),
            window_seconds: p.oracle_window,
            configs,
            verified,
            best,
            here: None,
        })
    }
    .await;
    cur.close().await?;
    out
}

/// The oracle's candidates to verify, best first (pure): configs whose every
/// window held, by objective (ties: the first measured). The oracle goes
/// down the list until one holds, skipping a config that gives the
/// non-core apps as much on every knob as one that missed
/// (`KnobSpace::gives_no_less`). It stopped after five until session 39:
/// on real-nodelets (2026-11-28) the five best screens each missed one or
/// more windows of their minute, weighted too, and the oracle named none.
pub fn oracle_candidates(configs: &[OracleConfig]) -> Vec<usize> {
    let mut held: Vec<usize> = (0..configs.len())
        .filter(|&i| configs[i].satisfaction >= 1.0)
        .collect();
    held.sort_by(|&a, &b| {
        configs[b]
            .objective
            .total_cmp(&configs[a].objective)
            .then(a.cmp(&b))
    });
    held
}

/// Drains the non-core apps as a tuning run does (their input at its
/// minimum, their CPU at its maximum, until the core metrics are on target
/// and still, at most [`settle::DRAIN_MAX_SECONDS`]), applies `config`,
/// lets it settle 3 s and measures it for `secs`.
async fn measure_from_drained(
    r: &dyn Robot,
    space: &KnobSpace,
    defs: &[MetricDef],
    config: &ResourceConfig,
    secs: u64,
) -> anyhow::Result<configbot_api::measure::MeasureReport> {
    if let Some(d) = space.drain_point(&space.from_config(config)) {
        r.apply(&space.to_config(&d)).await?;
        let mut so_far = measure_defs(r, defs, 2).await?;
        while !settle::drained(defs, &so_far) {
            let more = measure_defs(r, defs, 1).await?;
            so_far = measure::concat(&so_far, &more);
        }
    }
    r.apply(config).await?;
    tokio::time::sleep(Duration::from_secs(3)).await;
    measure_defs(r, defs, secs).await
}

/// Now as RFC 3339, UTC, to the second.
fn now_rfc3339() -> String {
    let now = time::OffsetDateTime::now_utc();
    now.replace_nanosecond(0)
        .unwrap_or(now)
        .format(&time::format_description::well_known::Rfc3339)
        .unwrap_or_default()
}

/// Writes `oracle-<stack>.json`.
pub fn write_oracle(out: &Path, o: &Oracle) -> anyhow::Result<()> {
    std::fs::write(
        out.join(format!("oracle-{}.json", o.stack)),
        serde_json::to_string_pretty(o)?,
    )?;
    Ok(())
}

/// The per-stack summary against the oracle (pure): each row's
/// satisfaction and scalarised objective, and its objective as a share of
/// the oracle best's (`X ORACLE`) and, when the oracle came from an earlier
/// bench, of that best config measured again in this run (`X HERE`).
pub fn summary(defs_of: &dyn Fn(&str) -> Vec<MetricDef>, rows: &[MethodResult]) -> String {
    let mut out = Vec::new();
    for r in rows {
        let defs = defs_of(&r.stack);
        let o = objective(&defs, r);
        let share = |method: &str| {
            rows.iter()
                .find(|b| b.stack == r.stack && b.method == method)
                .map(|b| objective(&defs, b))
                .filter(|&b| b > 0.0)
                .map_or("-".into(), |b| format!("{:.2}", o / b))
        };
        out.push(vec![
            r.stack.clone(),
            r.method.clone(),
            super::satisfaction(r),
            format!("{o:.3}"),
            share("oracle"),
            share("oracle-here"),
        ]);
    }
    let h = [
        "STACK",
        "METHOD",
        "SATISFACTION",
        "OBJECTIVE",
        "X ORACLE",
        "X HERE",
    ]
    .map(String::from);
    configbot_controller::table::render(&h, &out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use configbot_tuning::knobs;

    fn row(stack: &str, method: &str, sat: f64, det: f64) -> MethodResult {
        MethodResult {
            stack: stack.into(),
            method: method.into(),
            satisfaction: sat,
            metrics: [("cmd".to_string(), 30.0), ("det".to_string(), det)]
                .into_iter()
                .collect(),
            config: Value::Null,
            tuning: None,
            core_series: Vec::new(),
            core_latency: Default::default(),
        }
    }

    fn defs() -> Vec<MetricDef> {
        vec![
            MetricDef::rate_at_least("cmd", "nav", "/cmd", 25.0, true),
            MetricDef::rate_at_least("det", "det", "/det", 4.0, false),
        ]
    }

    /// The oracles committed under `docs/oracles/<class>/` stay usable by
    /// `--oracle-from`: one per real stack, each for today's manifests (a
    /// change to a real stack's manifests fails here until it is measured
    /// again). The machine class is the file's own: this runs on any machine.
    #[test]
    fn committed_oracles_are_of_todays_manifests() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/oracles");
        let mut classes = 0;
        for class in std::fs::read_dir(&root).expect("docs/oracles") {
            let dir = class.unwrap().path();
            if !dir.is_dir() {
                continue;
            }
            classes += 1;
            for name in STACKS {
                let (o, _) = read_oracle(&dir, name, None).unwrap_or_else(|e| panic!("{e}"));
                assert!(
                    o.machine.is_some() && o.stack_digest.is_some(),
                    "{}: a committed oracle names its machine and manifests",
                    dir.display()
                );
            }
        }
        assert!(classes > 0, "no machine class under {}", root.display());
    }

    #[test]
    fn real_expands_to_every_real_stack() {
        let s = expand(&["basic-nav".into(), "real".into()]);
        assert_eq!(s[0], "basic-nav");
        assert_eq!(&s[1..], STACKS.map(String::from));
        assert!(is_real("real-nodelets") && !is_real("basic-nav"));
    }

    #[test]
    fn a_seed_that_did_not_settle_ranks_lowest() {
        let mut late = row("s", "configbot-seed-2", 0.0, 0.0);
        late.metrics.clear();
        late.tuning = Some(super::super::TuningCost {
            phase: configbot_manifests::Phase::Satisfied,
            trials: 9,
            first_feasible_trial: None,
            first_feasible_seconds: None,
            final_trial: None,
            final_trial_seconds: None,
            final_config_seconds: 1500.0,
            trial_history: Vec::new(),
            rejected_trials: Vec::new(),
            unfinished: true,
        });
        // Without objectives a measured row scores 1; this one measured nothing.
        assert_eq!(objective(&defs(), &late), 0.0);
        let runs = [
            row("s", "configbot-seed-1", 1.0, 3.0),
            late,
            row("s", "configbot-seed-3", 1.0, 2.0),
        ];
        assert_eq!(
            median_run(&defs(), &runs).unwrap().method,
            "configbot-seed-3"
        );
        let t = summary(&|_| defs(), &runs);
        let line = t.lines().find(|l| l.contains("seed-2")).unwrap();
        assert!(line.contains("unfinished") && line.contains("0.000"), "{t}");
    }

    #[test]
    fn the_median_run_is_the_middle_objective() {
        let runs = [
            row("s", "configbot-seed-1", 1.0, 3.0),
            row("s", "configbot-seed-2", 1.0, 1.0),
            row("s", "configbot-seed-3", 1.0, 2.0),
        ];
        assert_eq!(
            median_run(&defs(), &runs).unwrap().method,
            "configbot-seed-3"
        );
        assert_eq!(
            median_run(&defs(), &runs[..2]).unwrap().method,
            "configbot-seed-2"
        );
        assert!(median_run(&defs(), &[]).is_none());
    }

    #[test]
    fn the_summary_compares_each_row_with_the_oracle() {
        let rows = [
            row("s", "configbot", 1.0, 3.0),
            row("s", "oracle", 1.0, 4.0),
        ];
        let t = summary(&|_| defs(), &rows);
        let lines: Vec<&str> = t.lines().collect();
        assert!(
            lines[1].contains("0.750") && lines[1].contains("0.75"),
            "{t}"
        );
        assert!(lines[2].contains("1.00"), "{t}");
        // Without an oracle-here row, X HERE is empty.
        assert!(lines[1].trim_end().ends_with('-'), "{t}");
    }

    #[test]
    fn the_summary_compares_each_row_with_the_oracle_measured_here_too() {
        let rows = [
            row("s", "configbot", 1.0, 3.0),
            row("s", "oracle", 1.0, 4.0),
            row("s", "oracle-here", 1.0, 2.0),
        ];
        let t = summary(&|_| defs(), &rows);
        let cells: Vec<&str> = t.lines().nth(1).unwrap().split_whitespace().collect();
        assert_eq!(cells[cells.len() - 2..], ["0.75", "1.50"], "{t}");
    }

    #[test]
    fn a_reused_oracle_stands_when_its_best_config_gives_here_what_it_gave_there() {
        let was = row("s", "oracle", 1.0, 4.0);
        let ok = stands_here(&defs(), &was, &row("s", "oracle-here", 1.0, 3.8));
        assert!(ok.stands && ok.note.contains("0.95x"), "{ok:?}");
        // A slower machine: the same config gives less.
        let e = stands_here(&defs(), &was, &row("s", "oracle-here", 1.0, 2.0));
        assert!(!e.stands, "{e:?}");
        assert!(
            e.note.contains("0.50x") && e.note.contains("measure the oracle here"),
            "{e:?}"
        );
        assert!(e.said().starts_with("WARNING: "), "{e:?}");
        // Misses the core targets here: no yardstick whatever it gives.
        let e = stands_here(&defs(), &was, &row("s", "oracle-here", 0.9, 4.0));
        assert!(
            !e.stands && e.note.contains("misses the core targets"),
            "{e:?}"
        );
        // Just at the margins: stands.
        let edge = row("s", "oracle-here", ORACLE_HOLDS, 4.0 * HERE_KEEPS);
        assert!(stands_here(&defs(), &was, &edge).stands);
    }

    #[test]
    fn oracle_points_start_at_the_corners_and_fill_the_space() {
        let k = |name: &str, min: f64, max: f64| knobs::KnobDef {
            name: name.into(),
            target: knobs::KnobTarget::Cpu { node: name.into() },
            min,
            max,
            restricts_non_core: true,
            feeds: Vec::new(),
        };
        let space = KnobSpace {
            knobs: vec![k("/a", 0.05, 2.0), k("/b", 0.1, 1.0)],
            period_micros: 100_000,
            ..KnobSpace::default()
        };
        let p = oracle_points(&space, 50, 1);
        assert_eq!(p.len(), 50);
        assert_eq!(p[0], vec![0.05, 0.1]);
        assert_eq!(p[1], vec![2.0, 1.0]);
        for x in &p {
            assert!(
                (0.05..=2.0).contains(&x[0]) && (0.1..=1.0).contains(&x[1]),
                "{x:?}"
            );
        }
        // Space-filling: every quarter of each knob's range gets points.
        for (d, (lo, hi)) in [(0.05, 2.0), (0.1, 1.0)].into_iter().enumerate() {
            for q in 0..4 {
                let (a, b) = (
                    lo + (hi - lo) * q as f64 / 4.0,
                    lo + (hi - lo) * (q + 1) as f64 / 4.0,
                );
                assert!(
                    p.iter().any(|x| x[d] >= a && x[d] <= b),
                    "knob {d} quarter {q}"
                );
            }
        }
    }

    fn measured(stack: &str) -> Oracle {
        Oracle {
            stack: stack.into(),
            measured_at: Some("2026-11-28T20:00:00Z".into()),
            machine: Some(machine("vm-1", 2)),
            stack_digest: Some("d1".into()),
            reused_from: None,
            knobs: vec!["cpu:/a".into()],
            pinned: Vec::new(),
            window_seconds: 6,
            configs: Vec::new(),
            verified: Vec::new(),
            best: Some(row(stack, "oracle", 1.0, 4.0)),
            here: None,
        }
    }

    fn machine(host: &str, cpus: usize) -> Machine {
        Machine {
            hostname: host.into(),
            cpus,
            cpu_model: "Some CPU @ 2.0GHz".into(),
        }
    }

    #[test]
    fn an_oracle_stands_for_the_same_manifests_on_the_same_machine_class() {
        let o = measured("s");
        assert_eq!(reusable(&o, "s", "d1", &machine("vm-1", 2)), Ok(vec![]));
        // Another host of the same class: reused, and said so.
        let notes = reusable(&o, "s", "d1", &machine("vm-2", 2)).unwrap();
        assert!(notes.len() == 1 && notes[0].contains("vm-1"), "{notes:?}");
        let e = reusable(&o, "s", "d2", &machine("vm-1", 2)).unwrap_err();
        assert!(e.contains("other manifests") && e.contains("d2"), "{e}");
        let e = reusable(&o, "s", "d1", &machine("vm-1", 4)).unwrap_err();
        assert!(e.contains("machine class"), "{e}");
        let e = reusable(&o, "t", "d1", &machine("vm-1", 2)).unwrap_err();
        assert!(e.contains("oracle of s"), "{e}");
        // Written before the bench kept digest and machine: reused, unchecked, said so.
        let old = Oracle {
            machine: None,
            stack_digest: None,
            ..o
        };
        let notes = reusable(&old, "s", "d2", &machine("vm-9", 8)).unwrap();
        assert_eq!(notes.len(), 2, "{notes:?}");
        assert!(notes.iter().all(|n| n.contains("not checked")), "{notes:?}");
    }

    #[test]
    fn an_oracle_written_by_the_bench_reads_back_as_it_was() {
        let dir = tempfile::tempdir().unwrap();
        let mut o = measured("real-perception");
        let (stack, spec) = example("real-perception").unwrap();
        o.stack_digest = Some(library::stack_digest(&stack.spec, &spec.spec));
        o.machine = Some(Machine::here());
        write_oracle(dir.path(), &o).unwrap();
        let stacks = ["real-perception".to_string(), "basic-nav".to_string()];
        let got = load_oracles(dir.path(), &stacks).unwrap();
        assert_eq!(got.len(), 1, "only real stacks have oracles");
        let r = &got["real-perception"];
        assert_eq!(
            serde_json::to_value(Oracle {
                reused_from: None,
                ..r.clone()
            })
            .unwrap(),
            serde_json::to_value(&o).unwrap()
        );
        assert!(
            r.reused_from
                .as_deref()
                .unwrap()
                .ends_with("oracle-real-perception.json")
        );
        // A stack without a file stops the bench, naming the file.
        let e = load_oracles(dir.path(), &["real-nodelets".to_string()]).unwrap_err();
        assert!(
            format!("{e:#}").contains("oracle-real-nodelets.json"),
            "{e:#}"
        );
    }

    #[test]
    fn the_oracle_verifies_only_configs_that_held_best_first() {
        let c = |sat: f64, obj: f64| OracleConfig {
            x: vec![],
            config: ResourceConfig::default(),
            satisfaction: sat,
            objective: obj,
            metrics: Default::default(),
        };
        let configs = [c(1.0, 0.5), c(0.9, 1.0), c(1.0, 0.8), c(1.0, 0.5)];
        assert_eq!(oracle_candidates(&configs), vec![2, 0, 3]);
    }
}
