//! Real-process tests of the simnode against Debian's ROS 1 tools (rospy,
//! rostopic, rosnode) and both masters (Debian's rosmaster and the agent's
//! configbot-ros1 master). Each test runs its own master on a free port;
//! all print `SKIPPED` and pass when ROS is not installed (and fail when
//! CI=true or CONFIGBOT_REQUIRE=1).

mod common;

use std::time::Duration;

use common::*;
use configbot_test_support::wait_until;

/// Waits until `listener` has printed `n` messages.
fn wait_msgs(p: &Proc, n: usize, what: &str) {
    wait_until(what, Duration::from_secs(30), POLL, || p.msg_count() >= n);
}

/// Parses the last "average rate: X" of `rostopic hz` output.
fn hz_of(out: &str) -> Option<f64> {
    out.lines()
        .rev()
        .filter_map(|l| l.trim().strip_prefix("average rate:"))
        .find_map(|v| v.trim().parse().ok())
}

/// Waits until `node` is in `rosnode list`.
fn wait_registered(env: &RosEnv, node: &str) {
    wait_until(
        "the simnode in rosnode list",
        Duration::from_secs(20),
        POLL,
        || env.node_list().iter().any(|n| n == node),
    );
}

/// Sends `sig` to the simnode `sim` named `node`: it exits within 5 s and
/// leaves `rosnode list` within 10 s.
fn exits_and_unregisters(env: &RosEnv, sim: &mut Proc, node: &str, sig: &str) {
    assert!(
        sim.signal(sig, false) && sim.wait_exit(Duration::from_secs(5)),
        "no prompt exit"
    );
    wait_until(
        "the simnode to leave rosnode list",
        Duration::from_secs(10),
        POLL,
        || !env.node_list().iter().any(|n| n == node),
    );
}

fn publisher_seen_by_real_tools(kind: MasterKind) {
    if !ros_available() {
        return;
    }
    let m = Master::start(kind);
    let env = &m.env;
    let (node, topic) = (
        format!("/{}", unique("lidar")),
        format!("/{}", unique("scan")),
    );
    let spec = format!("{topic}:20:1024");
    let mut sim = env.simnode(&[
        "--name",
        &node,
        "--publish",
        &spec,
        "--cost-ms-per-msg",
        "1",
    ]);
    wait_registered(env, &node);
    let info = env.try_run("rosnode", &["info", &node]).unwrap_or_default();
    assert!(
        info.contains(&topic) && info.contains("std_msgs/UInt8MultiArray"),
        "{info}"
    );
    assert!(info.contains(&format!("Pid: {}", sim.pid())), "{info}");

    // A rospy listener decodes the messages: rate, sizes, sequence, latency.
    let listener = env.script("listen.py", &[&unique("listener"), &topic]);
    wait_msgs(&listener, 5, "messages at the rospy listener");
    let (rate, msgs) = rate_over(&listener, 3.0);
    assert!(
        (16.0..=22.0).contains(&rate),
        "rospy listener saw {rate:.1} Hz of 20"
    );
    assert!(msgs.iter().all(|&(_, _, len)| len == 1024));
    assert!(
        msgs.windows(2).all(|w| w[1].0 == w[0].0 + 1),
        "sequence gaps"
    );
    let mut lat: Vec<f64> = msgs.iter().map(|m| m.1).collect();
    lat.sort_by(f64::total_cmp);
    assert!(
        lat[lat.len() / 2] < 100.0,
        "median latency {:.1} ms",
        lat[lat.len() / 2]
    );
    let info = env.try_run("rosnode", &["info", &node]).unwrap_or_default();
    assert!(info.contains("outbound"), "{info}");

    // The real `rostopic hz`.
    let out = env
        .command("timeout")
        .args(["-s", "INT", "6", "rostopic", "hz", "-w", "40", &topic])
        .output()
        .unwrap();
    let hz = hz_of(&String::from_utf8_lossy(&out.stdout));
    assert!(
        hz.is_some_and(|h| (16.0..=22.0).contains(&h)),
        "rostopic hz: {hz:?}"
    );
    let echo = env
        .try_run(
            "timeout",
            &["10", "rostopic", "echo", "-n", "1", "--noarr", &topic],
        )
        .unwrap_or_default();
    assert!(echo.contains("length: 1024"), "{echo}");

    // SIGTERM: prompt exit, unregistered.
    exits_and_unregisters(env, &mut sim, &node, "TERM");
    let topics = env.try_run("rostopic", &["list", "-p"]).unwrap_or_default();
    assert!(!topics.contains(&topic), "{topics}");
}

#[test]
fn publisher_works_with_rosmaster_rostopic_rosnode_and_rospy() {
    publisher_seen_by_real_tools(MasterKind::Rosmaster);
}

#[test]
fn publisher_works_with_the_configbot_master() {
    publisher_seen_by_real_tools(MasterKind::Configbot);
}

fn rospy_feeds_a_callback(kind: MasterKind) {
    if !ros_available() {
        return;
    }
    let m = Master::start(kind);
    let env = &m.env;
    let (node, input, output) = (
        format!("/{}", unique("nav")),
        format!("/{}", unique("in")),
        format!("/{}", unique("out")),
    );
    // The simnode subscribes first, so it connects on publisherUpdate.
    let on = format!("{input}->{output}:cost-ms=3,bytes=48");
    let mut sim = env.simnode(&["--name", &node, "--on", &on]);
    wait_registered(env, &node);
    let listener = env.script("listen.py", &[&unique("listener"), &output]);
    wait_until("the listener", Duration::from_secs(20), POLL, || {
        listener.has_line("ready")
    });
    let _talker = env.script("talk.py", &[&unique("talker"), &input, "20", "300"]);
    wait_msgs(&listener, 5, "callback output at the rospy listener");
    let (rate, msgs) = rate_over(&listener, 3.0);
    assert!(
        (16.0..=22.0).contains(&rate),
        "callback output {rate:.1} Hz of 20"
    );
    assert!(msgs.iter().all(|&(_, _, len)| len == 48));
    // The output carries the talker's stamp: latency covers both hops.
    let mut lat: Vec<f64> = msgs.iter().map(|m| m.1).collect();
    lat.sort_by(f64::total_cmp);
    let med = lat[lat.len() / 2];
    assert!(
        (2.5..200.0).contains(&med),
        "median end-to-end latency {med:.1} ms"
    );
    let info = env.try_run("rosnode", &["info", &node]).unwrap_or_default();
    assert!(info.contains("inbound") && info.contains(&input), "{info}");
    exits_and_unregisters(env, &mut sim, &node, "INT");
}

#[test]
fn rospy_publisher_feeds_a_callback_with_rosmaster() {
    rospy_feeds_a_callback(MasterKind::Rosmaster);
}

#[test]
fn rospy_publisher_feeds_a_callback_with_the_configbot_master() {
    rospy_feeds_a_callback(MasterKind::Configbot);
}

#[test]
fn adaptor_inserted_live_by_the_configbot_master_limits_a_callback() {
    if !ros_available() {
        return;
    }
    let m = Master::start(MasterKind::Configbot);
    let env = &m.env;
    let t = |s: &str| format!("/{}", unique(s));
    let (scan, cmd, nav) = (t("scan"), t("cmd_vel"), t("navigation"));
    let spec = format!("{scan}:30:512");
    let _lidar = env.simnode(&["--name", &t("lidar"), "--publish", &spec]);
    let on = format!("{scan}->{cmd}:cost-ms=1");
    let _nav = env.simnode(&["--name", &nav, "--on", &on]);
    let listener = env.script("listen.py", &[&unique("listener"), &cmd]);
    wait_msgs(&listener, 10, "callback output");
    let (direct, _) = rate_over(&listener, 2.0);
    // The master points the simnode at its adaptor (publisherUpdate); the
    // simnode drops the direct connection and takes 10 of 30 Hz.
    m.set_adaptor(&scan, &nav, Some(10.0));
    std::thread::sleep(Duration::from_secs(2));
    let (adapted, _) = rate_over(&listener, 3.0);
    m.set_adaptor(&scan, &nav, None);
    std::thread::sleep(Duration::from_secs(2));
    let (back, _) = rate_over(&listener, 2.0);
    eprintln!(
        "callback output: direct {direct:.1} Hz, adapted to 10: {adapted:.1} Hz, removed: {back:.1} Hz"
    );
    assert!(direct >= 25.0, "direct {direct:.1} of 30");
    assert!(
        (8.0..=12.0).contains(&adapted),
        "adapted {adapted:.1} of 10"
    );
    assert!(back >= 25.0, "after removal {back:.1} of 30");
}
