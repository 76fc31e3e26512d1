//! Kill -9 of the agent's master process and restart on the same database:
//! running nodes stay visible and connected, parameters survive, an adapted
//! subscriber is re-pointed at the new adaptor, a node stopped across the
//! restart is kept, and a new subscriber still connects to the old
//! publisher. Skipped with a message without ROS.

mod common;

use std::time::{Duration, Instant};

use common::*;
use configbot_test_support::{free_port, wait_until};

fn start_master(env: &RosEnv, port: u16, db: &std::path::Path, adapt: &str) -> Proc {
    let mut c = env.command(env!("CARGO_BIN_EXE_configbot-ros1-master"));
    c.args([
        "--uri",
        &format!("http://localhost:{port}/"),
        "--db",
        db.to_str().unwrap(),
        "--adapt",
        adapt,
    ]);
    let p = Proc::spawn(c);
    wait_until("master up", Duration::from_secs(20), POLL, || {
        p.has_line("listening on")
    });
    p
}

#[test]
fn kill_and_restart_keeps_graph_params_and_connections() {
    if !ros_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let db = dir.path().join("ros1.db");
    let env = RosEnv {
        master_uri: format!("http://localhost:{port}/"),
        home: dir.path().to_path_buf(),
    };
    let topic = format!("/{}", unique("scan"));
    let plain = unique("plain");
    let adapted = unique("adapted");
    let adapt = format!("{topic}=/{adapted}@10");
    let mut master = start_master(&env, port, &db, &adapt);

    env.run("rosparam", &["set", "/persist/me", "7"]);
    let tname = unique("talker");
    let _talker = env.script("talker.py", &[&tname, &topic, "30"]);
    let lp = env.script("listener.py", &[&plain, &topic]);
    let la = env.script("listener.py", &[&adapted, &topic]);
    let recent =
        |p: &Proc| p.count_between(Instant::now() - Duration::from_secs(2), Instant::now());
    wait_until("listeners receive", Duration::from_secs(20), POLL, || {
        recent(&lp) > 20 && recent(&la) > 5
    });
    let ra = measure_rate(&la, 3.0);
    assert!((8.5..=11.5).contains(&ra), "adapted before restart: {ra}");

    let doomed = unique("doomed");
    let mut doomed_p = env.script("listener.py", &[&doomed, &topic]);
    wait_until(
        "doomed listener registered",
        Duration::from_secs(20),
        POLL,
        || doomed_p.has_line("ready"),
    );
    wait_until("doomed listed", Duration::from_secs(10), POLL, || {
        env.run("rosnode", &["list"]).contains(doomed.as_str())
    });

    // a node stopped (SIGSTOP, as an app freeze does) across the restart
    // cannot answer getPid, but it is alive: it is kept
    let frozen = unique("frozen");
    let frozen_p = env.script("listener.py", &[&frozen, &topic]);
    wait_until(
        "frozen listener receives",
        Duration::from_secs(20),
        POLL,
        || recent(&frozen_p) > 20,
    );
    assert!(frozen_p.signal("STOP", true), "kill -STOP");

    master.kill();
    // a node that dies while the master is down is dropped on restart
    doomed_p.kill();
    // nodes keep talking while the master is down
    wait_until(
        "plain listener without master",
        Duration::from_secs(10),
        POLL,
        || recent(&lp) > 20,
    );
    let _master2 = start_master(&env, port, &db, &adapt);

    let nodes = env.run("rosnode", &["list"]);
    for n in [&tname, &plain, &adapted, &frozen] {
        assert!(
            nodes.contains(n.as_str()),
            "{n} missing after restart: {nodes}"
        );
    }
    assert!(
        !nodes.contains(doomed.as_str()),
        "dead node kept after restart: {nodes}"
    );
    let info = env.run("rostopic", &["info", &topic]);
    assert!(info.contains(&tname) && info.contains(&plain), "{info}");
    assert_eq!(env.run("rosparam", &["get", "/persist/me"]).trim(), "7");

    // the adapted subscriber is re-pointed at the restarted adaptor
    wait_until(
        "adapted listener back",
        Duration::from_secs(20),
        POLL,
        || recent(&la) > 5,
    );
    let ra = measure_rate(&la, 3.0);
    assert!((8.5..=11.5).contains(&ra), "adapted after restart: {ra}");
    // the frozen listener, thawed, is still in the graph and receiving
    assert!(frozen_p.signal("CONT", true), "kill -CONT");
    wait_until(
        "thawed listener receives",
        Duration::from_secs(20),
        POLL,
        || recent(&frozen_p) > 20,
    );
    // Past the backlog of its socket: still connected, at the talker's rate.
    let rf = measure_rate(&frozen_p, 3.0);
    assert!(rf >= 20.0, "thawed listener at {rf} Hz of 30");
    let info = env.run("rostopic", &["info", &topic]);
    assert!(info.contains(&frozen), "{info}");
    // a new subscriber still connects to the old publisher
    let newcomer = env.script("listener.py", &[&unique("newcomer"), &topic]);
    wait_until(
        "new subscriber receives",
        Duration::from_secs(20),
        POLL,
        || recent(&newcomer) > 20,
    );
}
