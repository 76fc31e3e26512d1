//! Issue 6, "Done when" 4: an impossible spec (1000 Hz of `/cmd_vel` from a
//! 30 Hz scan) ends Unsat after its few trials, with a reason that names the
//! constraint and the best value reached (which must match the measured trials).

mod common;

use std::time::{Duration, Instant};

use common::{Robot, app, phase, simnode, stack_yaml, trial_history};
use configbot_manifests::Phase;

#[test]
fn impossible_spec_ends_unsat_naming_the_constraint() {
    let robot = Robot::start();
    let t0 = Instant::now();
    let name = "impossible";
    let stack = stack_yaml(
        name,
        &[
            app(
                "sensors",
                true,
                vec![simnode(
                    "/lidar",
                    &["--publish", "/scan:30:1024", "--cost-ms-per-msg", "1"],
                )],
            ),
            app(
                "nav",
                true,
                vec![simnode("/nav", &["--on", "/scan->/cmd_vel:cost-ms=2"])],
            ),
            app(
                "viz",
                false,
                vec![simnode("/viz", &["--on", "/scan->/viz_out:cost-ms=5"])],
            ),
        ],
    );
    robot.apply(&stack);
    robot.wait_nodes(&["/lidar", "/nav", "/viz"]);
    robot.apply(&format!(
        "apiVersion: configbot.dev/v1alpha1
kind: PerformanceSpec
metadata:
  name: {name}
spec:
  stackRef: {{name: {name}}}
  metrics:
    - name: cmd-vel-rate
      app: nav
      source: {{topicRate: {{topic: /cmd_vel}}}}
      target: {{atLeast: 1000}}
  knobs:
    cpu: {{min: 0.05, max: 1}}
    adaptors: {{enabled: false}}
  tuning: {{trialSeconds: 2, settleSeconds: 0.5, maxTrials: 3, seed: 5}}
  monitoring: {{violationWindowSeconds: 2}}
"
    ));
    let done = robot.wait_for("pspec", name, Duration::from_secs(60), "Unsat", |o| {
        matches!(phase(o), Phase::Unsat | Phase::Monitoring)
    });
    assert_eq!(phase(&done), Phase::Unsat, "{}", robot.event_log(name));
    let st = &done["status"];
    let reason = st["reason"].as_str().expect("a reason");
    assert!(
        reason.contains("cmd-vel-rate") && reason.contains(">= 1000"),
        "the reason names the constraint and its target: {reason}"
    );
    // "best value reached V": V must be what the run measured at best.
    let v: f64 = reason
        .split("best value reached ")
        .nth(1)
        .and_then(|r| r.split_whitespace().next())
        .and_then(|x| x.parse().ok())
        .unwrap_or_else(|| panic!("no best value in {reason:?}"));
    let trials = trial_history(&done);
    assert!(!trials.is_empty() && trials.len() <= 3, "{st}");
    let max_mean = trials
        .iter()
        .chain(std::iter::once(&st["baseline"]))
        .filter_map(|t| t["values"]["cmd-vel-rate"].as_f64())
        .fold(0.0f64, f64::max);
    assert!(
        v > 20.0 && v <= max_mean + 0.01 && max_mean < 32.0,
        "best value {v} vs measured means (max {max_mean}); a 30 Hz source"
    );
    // The condition carries the same message, and an Unsat event was recorded.
    let ready = st["conditions"]
        .as_array()
        .and_then(|c| c.iter().find(|c| c["type"] == "Ready"))
        .expect("Ready condition");
    assert_eq!(ready["status"], "False");
    assert_eq!(ready["reason"], "Unsat");
    assert!(
        !robot.events_with(name, "Unsat").is_empty(),
        "{}",
        robot.event_log(name)
    );
    eprintln!(
        "e2e unsat: {} trials, best value {v:.2} Hz (max trial mean {max_mean:.2}); reason: {reason}; {:.0} s",
        trials.len(),
        t0.elapsed().as_secs_f64()
    );
}
