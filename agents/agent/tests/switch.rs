//! Switching stacks at run time keeps topic meters working: when a node is
//! restarted under the same ROS name (new slave URI), the agent's meter on
//! its topics follows the new publisher, also for topics nobody else
//! subscribes to (real rospy nodes, real cgroups; root and ROS needed).

mod common;

use std::time::Duration;

use configbot_agent::{NodeApi, NodeRuntime};
use configbot_api::measure::{MeasureRequest, Probe};

use common::rt::{RT_POLL, RtEnv, graph_pid, robot_stack, stack_yaml};
use configbot_test_support::{try_wait_until_async, wait_until_async};

const T: Duration = Duration::from_secs(30);
/// How long a topic may take to show messages again after a restart.
const FLOW: Duration = Duration::from_secs(12);

/// Mean rate of `topic` over one second as the agent measures it.
async fn rate(rt: &NodeRuntime, topic: &str) -> f64 {
    let req = MeasureRequest {
        probes: vec![Probe::TopicRate {
            topic: topic.into(),
            subscriber: None,
        }],
        duration_ms: 1000,
        sub_window_ms: 1000,
    };
    rt.measure(&req).await.unwrap().series[0].mean
}

/// Waits until the agent measures messages on `topic`.
async fn flows(rt: &NodeRuntime, topic: &str, when: &str) {
    // No pause between looks: each measures for a second.
    try_wait_until_async("messages", FLOW, Duration::ZERO, async || {
        rate(rt, topic).await > 0.0
    })
    .await
    .unwrap_or_else(|_| panic!("{topic} measures 0 Hz for {FLOW:?} {when}"));
}

/// Waits until `name` runs as a new process (registered with the master).
async fn restarted(rt: &NodeRuntime, name: &str, old: u32) -> u32 {
    wait_until_async(&format!("{name} restarted"), T, RT_POLL, async || {
        graph_pid(rt, name).is_some_and(|p| p != old)
    })
    .await;
    graph_pid(rt, name).unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn meters_follow_nodes_restarted_by_a_stack_switch() {
    let Some((env, rt)) = RtEnv::start_with_ros(None).await else {
        return;
    };
    // /src publishes /in; /nav relays /in to /out, which nobody subscribes
    // to (like /cmd_vel in the example stacks): only the meter reads it.
    let stack = |src_hz: &str, nav_tag: &str| {
        robot_stack(&stack_yaml(&env.rospy_core_app(
            "nav",
            &[
                ("/src", "talker.py", &["src", "/in", src_hz]),
                ("/nav", "relay.py", &["nav", "/in", "/out", nav_tag]),
            ],
        )))
    };
    rt.set_stack(Some(&stack("10", "a"))).await.unwrap();
    wait_until_async("/src and /nav registered", T, RT_POLL, async || {
        graph_pid(&rt, "/src").is_some() && graph_pid(&rt, "/nav").is_some()
    })
    .await;
    flows(&rt, "/out", "with the first stack").await;
    let (src, nav) = (
        graph_pid(&rt, "/src").unwrap(),
        graph_pid(&rt, "/nav").unwrap(),
    );

    // The relay changes: restarted under the same name.
    rt.set_stack(Some(&stack("10", "b"))).await.unwrap();
    let nav = restarted(&rt, "/nav", nav).await;
    flows(&rt, "/out", "after /nav restarted").await;

    // The publisher of /in changes: restarted under the same name.
    rt.set_stack(Some(&stack("15", "b"))).await.unwrap();
    let src = restarted(&rt, "/src", src).await;
    flows(&rt, "/in", "after /src restarted").await;
    flows(&rt, "/out", "after /src restarted").await;

    // Back to the first stack: both restart.
    rt.set_stack(Some(&stack("10", "a"))).await.unwrap();
    restarted(&rt, "/src", src).await;
    restarted(&rt, "/nav", nav).await;
    flows(&rt, "/in", "after switching back").await;
    flows(&rt, "/out", "after switching back").await;
}
