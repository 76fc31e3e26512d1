//! Issue 6, "Done when" 3: `kill -9` of the controller mid-tuning, then a
//! restart on the same database: the run resumes (a `Resumed` event), trial
//! indices continue without repeats, the finished trials keep their configs
//! and values, and the run completes.

mod common;

use std::time::{Duration, Instant};

use common::{HOG_STACK_NODES, Robot, hog_stack, phase, trial_history};
use configbot_manifests::Phase;

#[test]
fn kill_9_mid_tuning_resumes_without_repeating_trials() {
    let mut robot = Robot::start();
    let t0 = Instant::now();
    let name = "resumed";
    let max_trials = 6;
    let yaml = hog_stack(name, max_trials, 36.0);
    let (stack, spec) = yaml.split_once("---\n").expect("two documents");
    robot.apply(stack);
    robot.wait_nodes(&HOG_STACK_NODES);
    robot.apply(spec);

    let before = robot.wait_for(
        "pspec",
        name,
        Duration::from_secs(40),
        "2 trials recorded",
        |o| o["status"]["trials"].as_u64().unwrap_or(0) >= 2,
    );
    robot.kill9_and_restart();
    let killed_after = trial_history(&before);
    let done_before = robot.get("pspec", name).map(|o| trial_history(&o));
    assert!(
        phase(&before) == Phase::Tuning,
        "killed mid-tuning: {}",
        phase(&before)
    );

    let (resumed, _) = robot.wait_event(name, "Resumed", Duration::from_secs(20), |_| true);
    let done = robot.wait_for(
        "pspec",
        name,
        Duration::from_secs(60),
        "the resumed run completes",
        |o| matches!(phase(o), Phase::Monitoring | Phase::Unsat),
    );
    let after = trial_history(&done);
    // The resumed run kept every trial finished before the kill, unchanged.
    let finished = done_before.unwrap_or(killed_after);
    assert!(finished.len() >= 2);
    for (i, t) in finished.iter().enumerate() {
        assert_eq!(t["index"].as_u64(), Some(i as u64));
        assert_eq!(
            after.get(i),
            Some(t),
            "trial {i} changed across the restart\n{}",
            robot.event_log(name)
        );
    }
    // Indices continue 0..n without gaps or repeats, up to maxTrials.
    let idx: Vec<u64> = after.iter().filter_map(|t| t["index"].as_u64()).collect();
    assert_eq!(idx, (0..after.len() as u64).collect::<Vec<_>>());
    assert!(after.len() > finished.len() && after.len() <= max_trials as usize);
    // Every trial was measured once: one `Trial` event per index, across both servers.
    let per_index = robot.trial_events_per_index(name);
    assert!(
        per_index.values().all(|n| *n == 1) && per_index.len() == after.len(),
        "trial events per index {per_index:?}\n{}",
        robot.event_log(name)
    );
    eprintln!(
        "e2e resume: killed after {} finished trials; {}; completed {} with {} trials (indices {idx:?}); {:.0} s",
        finished.len(),
        resumed["message"].as_str().unwrap_or(""),
        phase(&done),
        after.len(),
        t0.elapsed().as_secs_f64()
    );
}
