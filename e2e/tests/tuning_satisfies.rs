//! Issue 6, "Done when" 1: a stack whose default config violates its core
//! constraint on this 2-core machine is tuned to Satisfied and then holds
//! with ≥ 99 % satisfaction in steady state.
//!
//! The stack is [`common::hog_stack`]: five non-core thread-per-message
//! hogs starve the core `/nav` to ~28 Hz of `/cmd_vel` against a target of
//! 36 Hz; the knobs are the hogs' CPU limits.

mod common;

use std::time::{Duration, Instant};

use common::{HOG_STACK_NODES, Robot, hog_stack, phase, trial_history, trial_table};
use configbot_manifests::Phase;

#[test]
fn tuning_satisfies_a_violating_stack() {
    let robot = Robot::start();
    let t0 = Instant::now();
    let name = "hogged";
    let yaml = hog_stack(name, 6, 36.0);
    // The stack first, so that every node is in the graph when the run observes it.
    let (stack, spec) = yaml.split_once("---\n").expect("two documents");
    robot.apply(stack);
    robot.wait_nodes(&HOG_STACK_NODES);
    robot.apply(spec);

    let done = robot.wait_for(
        "pspec",
        name,
        Duration::from_secs(75),
        "Monitoring with a best config",
        |o| {
            phase(o) == Phase::Monitoring && o["status"]["bestConfig"].is_object()
                || phase(o) == Phase::Unsat
        },
    );
    let st = &done["status"];
    assert_eq!(
        phase(&done),
        Phase::Monitoring,
        "{}\n{}",
        trial_table(&done),
        robot.event_log(name)
    );
    let baseline = &st["baseline"];
    let base_rate = baseline["values"]["cmd-vel-rate"].as_f64().unwrap();
    let base_sat = baseline["satisfaction"].as_f64().unwrap();
    // The default must violate: its mean rate under the target and at least
    // half of its windows off it (exactly half was seen once in a CI run).
    assert!(
        base_sat <= 0.5 && base_rate < 36.0,
        "the default config must violate: baseline {baseline}"
    );
    assert_eq!(st["knobs"].as_array().map(Vec::len), Some(5), "{st}");
    let trials = trial_history(&done);
    assert!(!trials.is_empty() && trials.len() <= 6, "{st}");
    let best = st["bestTrial"].as_u64().expect("best trial") as usize;
    let best_rate = trials[best]["values"]["cmd-vel-rate"].as_f64().unwrap();
    let tuned_at = Instant::now();

    // Steady state: the monitor's satisfaction over at least 20 one-second
    // windows, without a relearning in between.
    let steady = robot.wait_for(
        "pspec",
        name,
        Duration::from_secs(40),
        "20 s of monitoring",
        |o| phase(o) != Phase::Monitoring || tuned_at.elapsed() >= Duration::from_secs(20),
    );
    assert_eq!(
        phase(&steady),
        Phase::Monitoring,
        "{}",
        robot.event_log(name)
    );
    assert!(
        robot.events_with(name, "ConstraintViolated").is_empty(),
        "{}",
        robot.event_log(name)
    );
    let sat = steady["status"]["satisfaction"].as_f64().unwrap();
    assert!(
        sat >= 0.99,
        "steady-state satisfaction {sat}\n{}",
        robot.event_log(name)
    );
    eprintln!(
        "e2e tuning_satisfies: baseline /cmd_vel {base_rate:.1} Hz (satisfaction {:.0} %), {} trials, best trial {best} at {best_rate:.1} Hz with {}, steady-state satisfaction {:.1} % over {:.0} s; total {:.0} s",
        base_sat * 100.0,
        trials.len(),
        steady["status"]["bestConfig"],
        sat * 100.0,
        tuned_at.elapsed().as_secs_f64(),
        t0.elapsed().as_secs_f64()
    );
    eprintln!("{}\n{}", trial_table(&steady), robot.event_log(name));
}
