//! Issue 6, "Done when" 5: with tuning not allowed (`spec.tuning.allowed:
//! false`) and a violated core constraint with no known config, the loop
//! stops the non-core app (its processes leave their cgroups and stay gone)
//! and the core constraint holds again.

mod common;

use std::time::{Duration, Instant};

use common::{HOG_STACK_NODES, HOGS, Robot, hog_stack, node_pids, phase};

/// Whether `pid` is a live (not zombie) process.
fn running(pid: u32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat"))
        .ok()
        .and_then(|s| s.rsplit_once(')').map(|(_, r)| r.trim_start().to_string()))
        .is_some_and(|r| !r.starts_with('Z') && !r.starts_with('X'))
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
    // The hogs' processes are gone from their cgroups (and from the machine).
    let deadline = Instant::now() + Duration::from_secs(15);
    while HOGS.iter().any(|h| !node_pids(&robot.root, h).is_empty()) {
        assert!(
            Instant::now() < deadline,
            "hogs still running\n{}",
            robot.event_log(name)
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    // ... and from the machine (a zombie not yet reaped by the server counts as gone).
    let deadline = Instant::now() + Duration::from_secs(5);
    while let Some(p) = hog_pids.iter().find(|p| running(**p)) {
        assert!(Instant::now() < deadline, "hog pid {p} still running");
        std::thread::sleep(Duration::from_millis(50));
    }
    let stopped_at = Instant::now();
    // The constraint monitor keeps measuring while remediating: at least 12
    // one-second windows after the stop, all within the core constraint.
    let st = robot.wait_for(
        "pspec",
        name,
        Duration::from_secs(40),
        "12 s of remediation",
        |o| phase(o) != "Remediating" || stopped_at.elapsed() >= Duration::from_secs(12),
    );
    assert_eq!(phase(&st), "Remediating", "{}", robot.event_log(name));
    let sat = st["status"]["satisfaction"].as_f64().expect("satisfaction");
    let base = &st["status"]["baseline"];
    assert!(
        base["satisfaction"].as_f64().unwrap_or(1.0) < 0.5,
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

/// The task executive's way: the annotation `configbot.dev/tuning-allowed:
/// "false"` pauses tuning (remediation stops the hogs); removing it undoes
/// the remediation (an event, the hogs run again) and queues the relearning.
#[test]
fn remediation_is_undone_when_the_annotation_allows_tuning() {
    let robot = Robot::start();
    let t0 = Instant::now();
    let name = "paused";
    let yaml = hog_stack(name, 6, 36.0);
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
    robot.apply(&paused);
    robot.wait_event(name, "Remediated", Duration::from_secs(30), |_| true);
    let deadline = Instant::now() + Duration::from_secs(15);
    while HOGS.iter().any(|h| !node_pids(&robot.root, h).is_empty()) {
        assert!(
            Instant::now() < deadline,
            "hogs still running\n{}",
            robot.event_log(name)
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    robot.wait_for("pspec", name, Duration::from_secs(10), "Remediating", |o| {
        phase(o) == "Remediating"
    });

    // The task executive allows tuning again.
    robot.apply(spec);
    let (ev, _) = robot.wait_event(name, "RemediationUndone", Duration::from_secs(20), |_| true);
    let deadline = Instant::now() + Duration::from_secs(20);
    while HOGS.iter().any(|h| node_pids(&robot.root, h).is_empty()) {
        assert!(
            Instant::now() < deadline,
            "hogs not restarted\n{}",
            robot.event_log(name)
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    // ... and the run relearns.
    robot.wait_for("pspec", name, Duration::from_secs(20), "relearning", |o| {
        matches!(phase(o), "Baseline" | "Tuning")
    });
    eprintln!(
        "e2e remediation undo: {}; {:.0} s",
        ev["message"].as_str().unwrap_or(""),
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
    let deadline = Instant::now() + Duration::from_secs(15);
    while HOGS.iter().any(|h| !node_pids(&robot.root, h).is_empty()) {
        assert!(
            Instant::now() < deadline,
            "hogs still running\n{}",
            robot.event_log(name)
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    robot.apply(spec);
    let deadline = Instant::now() + Duration::from_secs(30);
    while HOGS.iter().any(|h| node_pids(&robot.root, h).is_empty()) {
        assert!(
            Instant::now() < deadline,
            "hogs not restarted 30 s after tuning.allowed became true (phase {})\n{}",
            robot
                .get("pspec", name)
                .map(|o| phase(&o).to_string())
                .unwrap_or_default(),
            robot.event_log(name)
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    eprintln!(
        "e2e remediation field undo: hogs back; {:.0} s",
        t0.elapsed().as_secs_f64()
    );
}
