//! Issue 6, "Done when" 5: with tuning not allowed (`spec.tuning.allowed:
//! false`) and a violated core constraint with no known config, the loop
//! stops the non-core app (its processes leave their cgroups and stay gone)
//! and the core constraint holds again; or freezes it and records its inputs
//! with rosbag; allowing tuning again undoes either.

mod common;

use std::time::{Duration, Instant};

use common::{HOG_STACK_NODES, HOGS, Robot, hog_stack, node_pids, phase, proc_state as state};
use configbot_manifests::Phase;
use configbot_test_support::try_wait_until;

/// Whether rosbag's recorder (node `/record_…`) subscribes to `/scan`, by
/// the robot's master (`rostopic info`).
fn recorder_on_scan(robot: &Robot) -> bool {
    std::process::Command::new("/usr/bin/rostopic")
        .args(["info", "/scan"])
        .env("ROS_MASTER_URI", robot.master_uri())
        .env("ROS_HOSTNAME", "localhost")
        .env("ROS_HOME", robot.dir.path())
        .output()
        .is_ok_and(|o| {
            let text = String::from_utf8_lossy(&o.stdout);
            text.split_once("Subscribers:")
                .is_some_and(|(_, subs)| subs.contains(" * /record_"))
        })
}

/// Waits until no hog has a process in its cgroup; panics with the events
/// about spec `name` after `timeout`.
fn hogs_gone(robot: &Robot, name: &str, timeout: Duration) {
    let gone = try_wait_until(
        "the hogs to stop",
        timeout,
        Duration::from_millis(100),
        || HOGS.iter().all(|h| node_pids(&robot.root, h).is_empty()),
    );
    gone.unwrap_or_else(|e| panic!("{e}\n{}", robot.event_log(name)));
}

/// Whether `pid` is a live (not zombie) process.
fn running(pid: u32) -> bool {
    state(pid).is_some_and(|c| !matches!(c, 'Z' | 'X'))
}

#[test]
fn remediation_stops_the_non_core_app() {
    let robot = Robot::start();
    let t0 = Instant::now();
    let name = "remedied";
    let yaml = hog_stack(name, 6, 36.0).replace("tuning: {", "tuning: {allowed: false, ");
    let (stack, spec) = yaml.split_once("---\n").expect("two documents");
    robot.apply(stack);
    robot.wait_nodes(&HOG_STACK_NODES);
    let hog_pids: Vec<u32> = HOGS
        .iter()
        .flat_map(|h| node_pids(&robot.root, h))
        .collect();
    assert_eq!(hog_pids.len(), 5, "{hog_pids:?}");
    robot.apply(spec);

    let (ev, _) = robot.wait_event(name, "Remediated", Duration::from_secs(30), |_| true);
    let msg = ev["message"].as_str().unwrap_or("").to_string();
    assert!(msg.contains("stopping hogs"), "{msg}");
    // The hogs' processes are gone from their cgroups (and from the machine):
    // a graceful stop takes at most 2 × stopTimeout (5 s) per node, the
    // nodes of an app stop in parallel.
    hogs_gone(&robot, name, Duration::from_secs(30));
    // ... and from the machine (a zombie not yet reaped by the server counts as gone).
    let mut left = Vec::new();
    let gone = try_wait_until(
        "the hogs' processes to end",
        Duration::from_secs(5),
        Duration::from_millis(50),
        || {
            left = hog_pids.iter().filter(|p| running(**p)).collect();
            left.is_empty()
        },
    );
    gone.unwrap_or_else(|e| panic!("{e}: hog pids {left:?} still running"));
    let stopped_at = Instant::now();
    // The constraint monitor keeps measuring while remediating: at least 12
    // one-second windows after the stop, all within the core constraint.
    let st = robot.wait_for(
        "pspec",
        name,
        Duration::from_secs(40),
        "12 s of remediation",
        |o| phase(o) != Phase::Remediating || stopped_at.elapsed() >= Duration::from_secs(12),
    );
    assert_eq!(phase(&st), Phase::Remediating, "{}", robot.event_log(name));
    let sat = st["status"]["satisfaction"].as_f64().expect("satisfaction");
    let base = &st["status"]["baseline"];
    // The baseline broke the core constraint (what made the loop remediate):
    // infeasible, some of its windows below the target.
    assert_eq!(base["feasible"], false, "the baseline violated: {base}");
    assert!(
        base["satisfaction"].as_f64().unwrap_or(1.0) < 1.0,
        "the baseline violated: {base}"
    );
    assert!(
        sat >= 0.99,
        "core constraint restored: satisfaction {sat}\n{}",
        robot.event_log(name)
    );
    let ready = st["status"]["conditions"]
        .as_array()
        .and_then(|c| c.iter().find(|c| c["type"] == "Ready"))
        .cloned()
        .expect("Ready condition");
    assert_eq!(ready["reason"], "Remediating");
    // Still stopped: the supervisor did not restart them.
    assert!(HOGS.iter().all(|h| node_pids(&robot.root, h).is_empty()));
    assert!(robot.events_with(name, "Trial").is_empty(), "no trials ran");
    eprintln!(
        "e2e remediation: baseline /cmd_vel {:.1} Hz (satisfaction {:.0} %); event: {msg}; after the stop satisfaction {:.1} % over {:.0} s; {:.0} s",
        base["values"]["cmd-vel-rate"].as_f64().unwrap_or(0.0),
        base["satisfaction"].as_f64().unwrap_or(0.0) * 100.0,
        sat * 100.0,
        stopped_at.elapsed().as_secs_f64(),
        t0.elapsed().as_secs_f64()
    );
}

/// The task executive's way, freezing: with the annotation
/// `configbot.dev/tuning-allowed: "false"` and `remediation: {action:
/// FreezeNonCore, recordRosbag: true}` the hogs are frozen (SIGSTOP: same
/// pids, stopped, still in their cgroups) and rosbag records their input
/// `/scan`; removing the annotation thaws them, closes the bag (it holds the
/// messages) and queues the relearning.
#[test]
fn a_frozen_remediation_records_the_inputs_and_thaws_when_the_annotation_allows_tuning() {
    let robot = Robot::start();
    let t0 = Instant::now();
    let name = "paused";
    let yaml = hog_stack(name, 6, 36.0).replace(
        "  monitoring: {",
        "  remediation: {action: FreezeNonCore, recordRosbag: true}\n  monitoring: {",
    );
    let (stack, spec) = yaml.split_once("---\n").expect("two documents");
    let paused = spec.replace(
        &format!("metadata:\n  name: {name}\n"),
        &format!(
            "metadata:\n  name: {name}\n  annotations:\n    configbot.dev/tuning-allowed: \"false\"\n"
        ),
    );
    assert_ne!(paused, spec);
    robot.apply(stack);
    robot.wait_nodes(&HOG_STACK_NODES);
    let hog_pids: Vec<u32> = HOGS
        .iter()
        .flat_map(|h| node_pids(&robot.root, h))
        .collect();
    robot.apply(&paused);
    let (ev, _) = robot.wait_event(name, "Remediated", Duration::from_secs(30), |_| true);
    let msg = ev["message"].as_str().unwrap_or("").to_string();
    assert!(msg.contains("freezing hogs"), "{msg}");
    let (rec, _) = robot.wait_event(name, "RecordingInputs", Duration::from_secs(30), |_| true);
    let rec = rec["message"].as_str().unwrap_or("").to_string();
    assert!(
        rec.starts_with("recording /scan (the inputs of hogs) to "),
        "{rec}"
    );
    let bag = rec.rsplit_once(" to ").map(|(_, p)| p.to_string()).unwrap();
    // Frozen, not stopped: the same processes, all in state T.
    let frozen = try_wait_until(
        "the hogs to be frozen",
        Duration::from_secs(15),
        Duration::from_millis(100),
        || hog_pids.iter().all(|p| state(*p) == Some('T')),
    );
    frozen.unwrap_or_else(|e| panic!("{e}\n{}", robot.event_log(name)));
    let now: Vec<u32> = HOGS
        .iter()
        .flat_map(|h| node_pids(&robot.root, h))
        .collect();
    assert_eq!(now, hog_pids, "the frozen hogs keep their processes");
    robot.wait_for("pspec", name, Duration::from_secs(10), "Remediating", |o| {
        phase(o) == Phase::Remediating
    });
    // rosbag's wrapper starts its recorder, which subscribes and opens
    // `<bag>.active` (seconds on a busy machine): only then can the bag hold
    // messages. Stopped sooner, it writes none (CI, 2026-11-26).
    let recording = try_wait_until(
        "rosbag to subscribe to /scan and open its bag",
        Duration::from_secs(30),
        Duration::from_millis(200),
        || std::path::Path::new(&format!("{bag}.active")).is_file() && recorder_on_scan(&robot),
    );
    recording.unwrap_or_else(|e| panic!("{e}\n{}", robot.event_log(name)));

    // The task executive allows tuning again.
    robot.apply(spec);
    let (ev, _) = robot.wait_event(name, "RemediationUndone", Duration::from_secs(30), |_| true);
    let undone = ev["message"].as_str().unwrap_or("").to_string();
    assert!(
        undone.contains("thawed hogs") && undone.contains(&format!("inputs recorded to {bag}")),
        "{undone}"
    );
    let thawed = try_wait_until(
        "the hogs to be thawed (the same processes, running)",
        Duration::from_secs(20),
        Duration::from_millis(100),
        || {
            hog_pids
                .iter()
                .all(|p| running(*p) && state(*p) != Some('T'))
        },
    );
    thawed.unwrap_or_else(|e| panic!("{e}\n{}", robot.event_log(name)));
    let info = std::process::Command::new("/usr/bin/rosbag")
        .args(["info", "--yaml", "--key", "messages", &bag])
        .env("ROS_HOME", robot.dir.path())
        .output()
        .expect("rosbag info");
    let messages: u64 = String::from_utf8_lossy(&info.stdout)
        .trim()
        .parse()
        .unwrap_or(0);
    assert!(messages > 0, "the bag holds /scan messages: {info:?}");
    // ... and the run relearns.
    robot.wait_for("pspec", name, Duration::from_secs(20), "relearning", |o| {
        matches!(phase(o), Phase::Baseline | Phase::Tuning)
    });
    eprintln!(
        "e2e frozen remediation undo: {undone}; bag of {messages} messages; {:.0} s",
        t0.elapsed().as_secs_f64()
    );
}

/// The same through the spec field: `tuning.allowed` set back to true while
/// remediating restarts the stopped app too (a new spec generation starts a
/// new run, which first undoes the old run's remediation).
#[test]
fn remediation_is_undone_when_the_spec_field_allows_tuning() {
    let robot = Robot::start();
    let t0 = Instant::now();
    let name = "fieldpaused";
    let yaml = hog_stack(name, 6, 36.0);
    let (stack, spec) = yaml.split_once("---\n").expect("two documents");
    let paused = spec.replace("tuning: {", "tuning: {allowed: false, ");
    robot.apply(stack);
    robot.wait_nodes(&HOG_STACK_NODES);
    robot.apply(&paused);
    robot.wait_event(name, "Remediated", Duration::from_secs(30), |_| true);
    hogs_gone(&robot, name, Duration::from_secs(15));
    robot.apply(spec);
    let back = try_wait_until(
        "the hogs to restart after tuning.allowed became true",
        Duration::from_secs(30),
        Duration::from_millis(100),
        || HOGS.iter().all(|h| !node_pids(&robot.root, h).is_empty()),
    );
    back.unwrap_or_else(|e| {
        panic!(
            "{e} (phase {})\n{}",
            robot
                .get("pspec", name)
                .map(|o| phase(&o).to_string())
                .unwrap_or_default(),
            robot.event_log(name)
        )
    });
    eprintln!(
        "e2e remediation field undo: hogs back; {:.0} s",
        t0.elapsed().as_secs_f64()
    );
}
