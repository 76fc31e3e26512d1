//! The harness itself: a private ConfigBot starts, takes a stack and cleans up.

mod common;

use std::time::Duration;

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
    let deadline = std::time::Instant::now() + Duration::from_secs(30);
    while robot.pids().len() < 4 {
        assert!(
            std::time::Instant::now() < deadline,
            "nodes did not start: {:?}\n{}",
            robot.pids(),
            robot.server_log()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}
