//! Issue 7, "Done when" 3: `configbot bench --quick` runs on real processes,
//! cgroups and ROS transport, and its output has the expected shape: every
//! method row, satisfactions in [0, 1], tuning costs for the tuned methods,
//! the cross-evaluation and the context-switch timeline with their keys, and
//! SVG plots that are well-formed XML. Not the numbers: the example stacks
//! are calibrated elsewhere and the machine is shared.
//!
//! The bench makes its own robots (cgroup root `configbot-demo-<its pid>`);
//! the test checks that the bench removed them and their processes, and
//! removes them itself if the bench failed or was killed. As for the other
//! scenarios ([`common::ROBOT_SHARES`]), the bench process (control plane,
//! ROS master, meters) runs in a `configbot-e2e-<pid>-bench` cpu cgroup and
//! its robots' roots get as high a weight (`--subtree-cpu-weight`), so a
//! busy shared machine does not starve the robot it measures.

mod common;

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use configbot_test_support::{CpuCgroup, try_wait_until};

use serde_json::Value;

/// The bench process; killed, and its cgroups and nodes removed, on drop.
struct Bench {
    child: Child,
    /// Its own cpu cgroup (`configbot-e2e-<test pid>-<n>-bench`), if there is
    /// a cpu hierarchy; it drops after `Drop::drop` killed the bench.
    ctl: Option<CpuCgroup>,
}

impl Bench {
    fn start(out: &Path, log: &Path, extra: &[&str]) -> Bench {
        let cpu = configbot_cgroups::Layout::detect()
            .ok()
            .and_then(|l| l.v1_cpu);
        let ctl = cpu.map(|c| {
            let ctl = CpuCgroup::create(&c, &format!("{}-bench", common::unique_root()))
                .expect("create the bench's cpu cgroup");
            ctl.set("cpu.shares", common::ROBOT_SHARES)
                .expect("set cpu.shares");
            ctl
        });
        let child = Command::new(common::configbot_bin())
            .args(["bench", "--quick", "--out"])
            .arg(out)
            .args(["--subtree-cpu-weight", &common::ROBOT_WEIGHT.to_string()])
            .args(extra)
            .env("ROS_HOSTNAME", "localhost")
            .stdout(std::fs::File::create(log).expect("log"))
            .stderr(Stdio::inherit())
            .spawn()
            .expect("start configbot bench");
        let b = Bench { child, ctl };
        if let Some(ctl) = &b.ctl {
            ctl.add(b.child.id())
                .expect("move the bench into its cgroup");
        }
        b
    }

    fn root(&self) -> String {
        format!("configbot-demo-{}", self.child.id())
    }
}

impl Drop for Bench {
    fn drop(&mut self) {
        let root = self.root();
        common::kill_and_remove(&mut self.child, &root);
    }
}

/// Well-formed enough to be XML: one root `<svg>`, every tag closed in order.
fn check_svg(path: &Path) {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert!(text.trim_start().starts_with("<svg"), "{}", path.display());
    let mut open: Vec<String> = Vec::new();
    let mut rest = text.as_str();
    let mut roots = 0;
    while let Some(i) = rest.find('<') {
        let j = rest[i..]
            .find('>')
            .map(|j| i + j)
            .unwrap_or_else(|| panic!("{}: unterminated tag", path.display()));
        let tag = &rest[i + 1..j];
        rest = &rest[j + 1..];
        if tag.starts_with('?') || tag.starts_with('!') {
            continue;
        }
        let name = |t: &str| t.split_whitespace().next().unwrap_or("").to_string();
        if let Some(closing) = tag.strip_prefix('/') {
            let top = open.pop();
            assert_eq!(
                top.as_deref(),
                Some(name(closing).as_str()),
                "{}",
                path.display()
            );
        } else {
            if open.is_empty() {
                roots += 1;
            }
            if !tag.ends_with('/') {
                open.push(name(tag));
            }
        }
    }
    assert!(open.is_empty(), "{}: unclosed {open:?}", path.display());
    assert_eq!(roots, 1, "{}", path.display());
    assert!(text.contains("<svg"));
}

fn unit(v: &Value, what: &str) -> f64 {
    let x = v
        .as_f64()
        .unwrap_or_else(|| panic!("{what}: not a number: {v}"));
    assert!((0.0..=1.0).contains(&x), "{what} = {x}");
    x
}

fn secs(v: &Value, what: &str) -> f64 {
    let x = v
        .as_f64()
        .unwrap_or_else(|| panic!("{what}: not a number: {v}"));
    assert!(x.is_finite() && x >= 0.0, "{what} = {x}");
    x
}

/// Waits for the bench to exit (at most `limit`) and checks it succeeded
/// and left no cgroup behind; returns what it printed.
fn finish(bench: &mut Bench, log: &Path, limit: Duration) -> String {
    let root = bench.root();
    let exited = try_wait_until(
        "bench --quick to exit",
        limit,
        Duration::from_millis(200),
        || bench.child.try_wait().expect("wait"),
    );
    let status = exited
        .unwrap_or_else(|e| panic!("{e}:\n{}", std::fs::read_to_string(log).unwrap_or_default()));
    let printed = std::fs::read_to_string(log).unwrap_or_default();
    assert!(
        status.success(),
        "bench --quick failed ({status}):\n{printed}"
    );
    let left = common::cgroup_dirs(&root);
    assert!(left.is_empty(), "left behind: {left:?}");
    printed
}

fn check_results(results: &[Value]) {
    for method in ["default", "random-1", "cgroup-only", "configbot"] {
        let r = results
            .iter()
            .find(|r| r["stack"] == "basic-nav" && r["method"] == method)
            .unwrap_or_else(|| panic!("no {method} row"));
        unit(&r["satisfaction"], &format!("{method} satisfaction"));
        let metrics = r["metrics"].as_object().expect("metrics");
        assert!(!metrics.is_empty(), "{method}: no metrics");
        for (k, v) in metrics {
            secs(v, &format!("{method} {k}"));
        }
        assert!(!r["coreSeries"].as_array().expect("coreSeries").is_empty());
        let t = &r["tuning"];
        if method == "cgroup-only" || method == "configbot" {
            let phase = t["phase"].as_str().expect("phase");
            assert!(matches!(phase, "Monitoring" | "Unsat"), "{method}: {phase}");
            let trials = t["trials"].as_u64().expect("trials");
            assert!(trials <= 6, "quick caps trials at 6: {trials}");
            let settled = secs(&t["finalConfigSeconds"], "finalConfigSeconds");
            assert!(settled > 0.0);
            for (trial, at) in [
                ("firstFeasibleTrial", "firstFeasibleSeconds"),
                ("finalTrial", "finalTrialSeconds"),
            ] {
                // A trial number comes with the second it was measured, before the run settled.
                if let Some(n) = t[trial].as_u64() {
                    assert!(n >= 1 && n <= trials, "{method} {trial} {n}");
                    assert!(secs(&t[at], at) <= settled, "{method}: {at} after settling");
                } else {
                    assert!(t[at].is_null(), "{method}: {at} without {trial}");
                }
            }
            assert_eq!(
                t["trialHistory"].as_array().expect("trialHistory").len() as u64,
                trials
            );
            if phase == "Monitoring" {
                assert!(r["config"].is_object(), "{method}: no config");
            }
        } else {
            assert!(t.is_null(), "{method} has no tuning cost");
        }
    }
}

fn check_cross(cross: &[Value]) {
    let own = cross
        .iter()
        .find(|e| e["own"] == true && e["from"] == "basic-nav")
        .expect("the diagonal: basic-nav on itself, if it is evaluated");
    assert_eq!(own["on"], "basic-nav");
    let other = cross
        .iter()
        .find(|e| e["from"] == "basic-nav" && e["on"] == "terrain-nav")
        .expect("basic-nav's config on terrain-nav");
    assert_eq!(other["own"], false);
    for e in [own, other] {
        unit(&e["satisfaction"], "cross satisfaction");
        let nc = e["nonCore"].as_object().expect("nonCore");
        assert!(!nc.is_empty());
        for (k, v) in nc {
            secs(v, k);
        }
        assert!(e["dropped"].is_array() && e["config"].is_object(), "{e}");
    }
}

fn check_timeline(t: &Value, out: &Path) {
    assert!(
        t["coreMetric"].is_string() && t["target"].is_number(),
        "{t}"
    );
    let mut last_at = -1.0;
    for key in ["initial", "toTerrain", "backToBasic"] {
        let m = &t[key];
        let at = secs(&m["at"], "at");
        assert!(at > last_at, "{key} at {at} after {last_at}");
        let applied = secs(&m["applied"], &format!("{key} applied"));
        let detected = secs(&m["detected"], &format!("{key} detected"));
        let up = secs(&m["stackUp"], "stackUp");
        let spec = secs(&m["specApplied"], "specApplied");
        assert!(at <= up && up <= spec, "{key}: {m}");
        assert!(spec <= detected && detected <= applied, "{key}: {m}");
        assert!(
            (secs(&m["settleSeconds"], "settleSeconds") - (applied - at)).abs() < 1e-6,
            "{m}"
        );
        secs(&m["detectionSeconds"], "detectionSeconds");
        assert!(m["reused"].is_boolean() && m["trials"].is_u64(), "{m}");
        assert!(
            matches!(m["phase"].as_str(), Some("Monitoring" | "Unsat")),
            "{m}"
        );
        last_at = applied;
    }
    // The first run learns; the switch back reuses the library config unless Basic-NAV ended Unsat.
    assert_eq!(t["initial"]["reused"], false);
    if t["initial"]["phase"] == "Monitoring" && t["backToBasic"]["reused"] == true {
        assert_eq!(t["backToBasic"]["trials"], 0);
    }
    let seconds = t["seconds"].as_array().expect("seconds");
    assert!(!seconds.is_empty());
    let mut prev = f64::MIN;
    for s in seconds {
        let x = s["t"].as_f64().expect("t");
        assert!(x > prev, "seconds in order");
        prev = x;
        secs(&s["core"], "core");
        assert!(s["satisfied"].is_boolean());
    }
    let end = t["backToBasic"]["applied"].as_f64().unwrap_or(0.0);
    assert!(
        prev >= end - 6.0,
        "recorded up to {prev} s, back applied at {end} s"
    );
    let segs = t["segments"].as_array().expect("segments");
    assert!(segs.len() >= 4, "{segs:?}");
    for s in segs {
        if !s["satisfaction"].is_null() {
            unit(&s["satisfaction"], "segment satisfaction");
        }
    }
    assert!(!t["samples"].as_array().expect("samples").is_empty());
    assert!(t["events"].is_array() && t["notes"].is_array());
    assert_eq!(
        Path::new(t["svg"].as_str().expect("svg")),
        out.join("timeline.svg")
    );
}

#[test]
fn quick_bench_writes_every_table_and_plot() {
    let _serial = common::serial();
    let started = Instant::now();
    let out = tempfile::tempdir().expect("temp dir");
    let log = out.path().join("bench.log");
    let mut bench = Bench::start(out.path(), &log, &[]);
    // The bench removed its robot: no cgroup, so no node left in one.
    let printed = finish(&mut bench, &log, Duration::from_secs(420));

    let json: Value = serde_json::from_str(
        &std::fs::read_to_string(out.path().join("bench.json")).expect("bench.json"),
    )
    .expect("bench.json is JSON");
    assert_eq!(json["quick"], true);
    assert_eq!(json["complete"], true);
    check_results(json["results"].as_array().expect("results"));
    check_cross(json["crossEvaluation"].as_array().expect("crossEvaluation"));
    check_timeline(&json["timeline"], out.path());
    for svg in [
        "basic-nav-progress.svg",
        "basic-nav-core-rate.svg",
        "timeline.svg",
    ] {
        check_svg(&out.path().join(svg));
    }
    // What a reader sees: the table, the matrix and the timeline summary.
    for heading in ["SETTLED S", "Cross-evaluation", "Context-switch timeline"] {
        assert!(printed.contains(heading), "no {heading:?} in:\n{printed}");
    }
    eprintln!(
        "e2e bench --quick: {:.0} s\n{printed}",
        started.elapsed().as_secs_f64()
    );
}

/// Issue 14: `bench --quick --stacks real-perception` on the real Debian ROS 1
/// nodes: every row of the real-stack table (launch and per-node defaults,
/// cgroup-only, ConfigBot for one seed and its median row, the oracle's
/// configs and its verified best if one held), the summary against the
/// oracle, `oracle-real-perception.json` and the plots. Shape, not numbers.
#[test]
fn quick_bench_on_a_real_stack_writes_every_row_and_the_oracle() {
    let _serial = common::serial();
    let out = tempfile::tempdir().expect("temp dir");
    let log = out.path().join("bench.log");
    let mut bench = Bench::start(out.path(), &log, &["--stacks", "real-perception"]);
    let printed = finish(&mut bench, &log, Duration::from_secs(600));
    let json: Value = serde_json::from_str(
        &std::fs::read_to_string(out.path().join("bench.json")).expect("bench.json"),
    )
    .expect("bench.json is JSON");
    let results = json["results"].as_array().expect("results");
    for method in [
        "launch-default",
        "default",
        "cgroup-only",
        "configbot-seed-1",
        "configbot",
    ] {
        let r = results
            .iter()
            .find(|r| r["stack"] == "real-perception" && r["method"] == method)
            .unwrap_or_else(|| panic!("no {method} row in {results:?}"));
        unit(&r["satisfaction"], &format!("{method} satisfaction"));
        let metrics = r["metrics"].as_object().expect("metrics");
        assert_eq!(metrics.len(), 4, "{method}: {metrics:?}");
        for (k, v) in metrics {
            secs(v, &format!("{method} {k}"));
        }
        if method == "launch-default" {
            // The feature tracker passes its camera's stamp on; under the
            // default's contention (it misses 25 Hz) its frames come late.
            let late = r["coreLatency"]["corners-rate"]
                .as_array()
                .unwrap_or_else(|| panic!("no latency of the core topic: {r}"));
            assert_eq!(late.len(), r["coreSeries"].as_array().unwrap().len());
            assert!(late.iter().any(|v| v.as_f64().unwrap() > 0.0), "{late:?}");
        }
        let tuned = method.starts_with("c");
        assert_eq!(r["tuning"].is_object(), tuned, "{method}: {r}");
        if tuned {
            let t = &r["tuning"];
            assert!(t["trials"].as_u64().expect("trials") <= 4, "{t}");
            secs(&t["finalConfigSeconds"], "finalConfigSeconds");
        }
    }
    let oracle: Value = serde_json::from_str(
        &std::fs::read_to_string(out.path().join("oracle-real-perception.json"))
            .expect("oracle-real-perception.json"),
    )
    .expect("the oracle is JSON");
    let configs = oracle["configs"].as_array().expect("configs");
    assert_eq!(configs.len(), 3, "quick measures three configs");
    for c in configs {
        unit(&c["satisfaction"], "oracle satisfaction");
        unit(&c["objective"], "oracle objective");
    }
    // Two of the stack's nodes feed no metric: pinned, not searched.
    let pinned = oracle["pinned"].as_array().expect("pinned");
    assert!(
        pinned.iter().any(|k| k == "cpu:/find_contours"),
        "{pinned:?}"
    );
    assert!(
        pinned.iter().any(|k| k == "cpu:/contour_moments"),
        "{pinned:?}"
    );
    if !oracle["best"].is_null() {
        assert!(oracle["best"]["satisfaction"].as_f64().unwrap() >= 0.995);
    }
    check_svg(&out.path().join("real-perception-progress.svg"));
    check_svg(&out.path().join("real-perception-core-rate.svg"));
    assert!(printed.contains("X ORACLE"), "{printed}");
    for key in ["measuredAt", "machine", "stackDigest"] {
        assert!(
            oracle[key].is_object() || oracle[key].is_string(),
            "{key}: {oracle}"
        );
    }
    reused_oracle(out.path(), &oracle);
}

/// `--oracle-from`: a second bench takes the first one's oracle (every
/// measured config, its best as the oracle row) without measuring it,
/// measures that best config again on this machine (`oracle-here`), and
/// refuses one measured for other manifests before it writes anything.
fn reused_oracle(first: &Path, oracle: &Value) {
    let out = tempfile::tempdir().expect("temp dir");
    let log = out.path().join("bench.log");
    let args = [
        "--stacks",
        "real-perception",
        "--real-methods",
        "oracle",
        "--oracle-from",
    ];
    let mut bench = Bench::start(
        out.path(),
        &log,
        &[&args[..], &[first.to_str().unwrap()]].concat(),
    );
    let printed = finish(&mut bench, &log, Duration::from_secs(300));
    assert!(printed.contains("not measured again"), "{printed}");
    let again: Value = serde_json::from_str(
        &std::fs::read_to_string(out.path().join("oracle-real-perception.json"))
            .expect("oracle-real-perception.json"),
    )
    .expect("the oracle is JSON");
    assert!(again["reusedFrom"].as_str().is_some(), "{again}");
    for key in [
        "configs",
        "verified",
        "best",
        "stackDigest",
        "measuredAt",
        "machine",
    ] {
        assert_eq!(again[key], oracle[key], "{key}");
    }
    let json: Value = serde_json::from_str(
        &std::fs::read_to_string(out.path().join("bench.json")).expect("bench.json"),
    )
    .expect("bench.json is JSON");
    let rows = json["results"].as_array().expect("results");
    let methods: Vec<&str> = rows.iter().filter_map(|r| r["method"].as_str()).collect();
    // The reused best config is measured again here (oracle-here), and the
    // bench says how it compares with the file's.
    let expected: &[&str] = if oracle["best"].is_null() {
        &[]
    } else {
        assert!(
            printed.contains("its best config gave") && printed.contains("where it was measured"),
            "{printed}"
        );
        &["oracle", "oracle-here"]
    };
    assert_eq!(methods, expected, "{rows:?}");
    if let Some(here) = rows.iter().find(|r| r["method"] == "oracle-here") {
        assert_eq!(here["config"], oracle["best"]["config"], "{here}");
        assert!(printed.contains("X HERE"), "{printed}");
        // The check is kept with the oracle it judged.
        assert!(again["here"]["stands"].is_boolean(), "{again}");
        assert!(again["here"]["note"].is_string(), "{again}");
    }
    // Measured for other manifests: refused, with nothing written.
    let other = tempfile::tempdir().expect("temp dir");
    let mut tampered = oracle.clone();
    tampered["stackDigest"] = Value::from("0000000000000000");
    std::fs::write(
        other.path().join("oracle-real-perception.json"),
        tampered.to_string(),
    )
    .expect("write");
    let refused = other.path().join("out");
    let run = Command::new(common::configbot_bin())
        .args(["bench", "--quick", "--out"])
        .arg(&refused)
        .args(args)
        .arg(other.path())
        .output()
        .expect("run configbot bench");
    let said = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success(), "{said}");
    assert!(said.contains("other manifests"), "{said}");
    assert!(!refused.exists(), "nothing written before the check");
}
