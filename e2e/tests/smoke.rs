//! The harness itself: a private ConfigBot starts, takes a stack and cleans up.

mod common;

use std::time::Duration;

use configbot_test_support::try_wait_until;

#[test]
fn serve_with_agent_accepts_a_stack() {
    let robot = common::Robot::start();
    robot.apply(&common::example("basic-nav.yaml"));
    robot.wait_for(
        "rs",
        "basic-nav",
        Duration::from_secs(30),
        "accepted",
        |o| o["status"]["phase"] != "Pending" && o["status"]["phase"].is_string(),
    );
    // Its four nodes (lidar, camera, navigation, detector) run inside the
    // robot's cgroup subtree.
    let started = try_wait_until(
        "the four nodes to start",
        Duration::from_secs(30),
        Duration::from_millis(100),
        || robot.pids().len() >= 4,
    );
    started.unwrap_or_else(|e| panic!("{e}: {:?}\n{}", robot.pids(), robot.server_log()));
}
