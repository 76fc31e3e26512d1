//! `kill -9` of the agent binary, then a restart: everything is re-adopted
//! with limits intact, a frozen app stays frozen until thawed, and no run
//! node is started twice (root needed).

mod common;

use std::os::unix::net::UnixStream;
use std::path::Path;
use std::process::Command;
use std::time::Duration;

use common::*;
use configbot_cgroups::{CgroupBackend, CpuMax};
use configbot_test_support::{ChildGuard, kill9, wait_until};

fn spawn_agent(env: &Env, stack: &Path, socket: &Path) -> ChildGuard {
    let child = Command::new(env!("CARGO_BIN_EXE_configbot-agent"))
        .args(["--stack", stack.to_str().unwrap()])
        .args(["--cgroup-root", &env.root])
        .args(["--state-file", env.path("state.json").to_str().unwrap()])
        .args(["--log-dir", env.path("logs").to_str().unwrap()])
        .args(["--socket", socket.to_str().unwrap()])
        .args(["--scan-interval-ms", "100", "--stop-timeout-ms", "1000"])
        .args(["--no-ros", "--monitor", "none"])
        .spawn()
        .unwrap();
    ChildGuard(child)
}

fn request(socket: &Path, method: &str, path: &str, body: Option<&str>) -> Option<(u16, String)> {
    let s = UnixStream::connect(socket).ok()?;
    Some(http(s, method, path, body, None))
}

fn wait_api(socket: &Path) {
    wait_until("the agent api", WAIT, Duration::from_millis(50), || {
        request(socket, "GET", "/v1/nodes", None).is_some()
    });
}

/// How long the agent api and the nodes may take to come up.
const WAIT: Duration = Duration::from_secs(20);

fn pids_of(b: &dyn CgroupBackend, n: &str) -> Vec<u32> {
    b.pids(&node(n)).unwrap_or_default()
}

#[test]
fn kill_9_then_restart_readopts_everything_with_limits_intact() {
    let mut env = Env::new();
    // sleep sums its arguments: a unique, valid duration marks our target.
    let token = format!("0.{}7", std::process::id());
    // A `match` target started before any agent.
    let target = Command::new("/bin/sleep")
        .args(["300", &token])
        .spawn()
        .unwrap();
    let target_pid = target.id();
    env.children.push(target);
    let stack = env.path("stack.json");
    std::fs::write(
        &stack,
        format!(
            r#"{{"apps":[{{"name":"a","nodes":[
            {{"name":"/worker","core":true,"run":{{"command":"/bin/sleep","args":["300"]}}}},
            {{"name":"/found","match":{{"cmdlineRegex":"^/bin/sleep 300 {token}$"}}}}]}}]}}"#
        ),
    )
    .unwrap();
    let socket = env.path("agent.sock");
    let b = v1_backend(&env.root);

    let mut first = spawn_agent(&env, &stack, &socket);
    wait_api(&socket);
    wait_until("the nodes to come up", WAIT, POLL, || {
        !pids_of(&b, "/worker").is_empty() && pids_of(&b, "/found") == [target_pid]
    });
    let (code, body) = request(
        &socket,
        "PUT",
        "/v1/config",
        Some(r#"{"cpu":{"/worker":0.2,"/found":0.3},"cpuPeriodMicros":20000}"#),
    )
    .unwrap();
    assert_eq!(code, 200, "{body}");
    let worker_pid = pids_of(&b, "/worker");

    // kill -9: no shutdown code runs.
    first.0.kill().unwrap();
    first.0.wait().unwrap();
    assert_eq!(
        pids_of(&b, "/worker"),
        worker_pid,
        "node died with the agent"
    );

    let _second = spawn_agent(&env, &stack, &socket);
    wait_api(&socket);
    let (code, body) = request(&socket, "GET", "/v1/nodes", None).unwrap();
    assert_eq!(code, 200);
    let nodes: serde_json::Value = serde_json::from_str(&body).unwrap();
    let worker = nodes
        .as_array()
        .unwrap()
        .iter()
        .find(|n| n["name"] == "/worker")
        .unwrap();
    assert_eq!(
        worker["mainPid"], worker_pid[0],
        "re-attached, not restarted: {worker}"
    );
    assert_eq!(pids_of(&b, "/worker"), worker_pid);
    assert_eq!(pids_of(&b, "/found"), [target_pid]);
    assert_eq!(
        b.cpu_max(&node("/worker")).unwrap(),
        CpuMax {
            quota_us: Some(4000),
            period_us: 20_000
        }
    );
    assert_eq!(
        b.cpu_max(&node("/found")).unwrap(),
        CpuMax {
            quota_us: Some(6_000),
            period_us: 20_000
        }
    );
    let (_, status) = request(&socket, "GET", "/v1/status", None).unwrap();
    assert!(
        status.contains("\"activeMonitor\":\"proc_scan\""),
        "{status}"
    );

    // A re-attached run node is still supervised: killing it restarts it.
    kill9(worker_pid[0]);
    wait_until("the re-attached node to be restarted", WAIT, POLL, || {
        let now = pids_of(&b, "/worker");
        !now.is_empty() && now != worker_pid
    });
    let (code, _) = request(&socket, "POST", "/v1/apps/a/stop", None).unwrap();
    assert_eq!(code, 200);
    assert!(pids_of(&b, "/worker").is_empty() && pids_of(&b, "/found").is_empty());
}

#[test]
fn a_changed_stack_lifts_stale_limits_of_core_nodes() {
    let env = Env::new();
    let b = v1_backend(&env.root);
    let stack = env.path("stack.json");
    let socket = env.path("agent.sock");
    std::fs::write(&stack, r#"{"apps":[{"name":"a","nodes":[{"name":"/core","core":true,"run":{"command":"/bin/sleep","args":["300"]}}]}]}"#).unwrap();
    {
        let _a = spawn_agent(&env, &stack, &socket);
        wait_api(&socket);
        let (code, body) = request(
            &socket,
            "PUT",
            "/v1/config",
            Some(r#"{"cpu":{"/core":0.2}}"#),
        )
        .unwrap();
        assert_eq!(code, 200, "{body}");
    } // kill -9 (Drop)
    assert_eq!(b.cpu_max(&node("/core")).unwrap().quota_us, Some(20_000));
    // The stack gains a node: the committed config was made for another stack.
    std::fs::write(&stack, r#"{"apps":[{"name":"a","nodes":[{"name":"/core","core":true,"run":{"command":"/bin/sleep","args":["300"]}},{"name":"/new","run":{"command":"/bin/sleep","args":["300"]}}]}]}"#).unwrap();
    let _a = spawn_agent(&env, &stack, &socket);
    wait_api(&socket);
    assert_eq!(
        b.cpu_max(&node("/core")).unwrap().quota_us,
        None,
        "core node left throttled"
    );
    let (code, _) = request(&socket, "POST", "/v1/apps/a/stop", None).unwrap();
    assert_eq!(code, 200);
}

#[test]
fn an_app_frozen_before_a_kill_9_stays_frozen_and_thaws_after_the_restart() {
    let env = Env::new();
    let stack = env.path("stack.json");
    std::fs::write(
        &stack,
        r#"{"apps":[{"name":"pause","nodes":[
        {"name":"/napper","run":{"command":"/bin/sleep","args":["300"]}}]}]}"#,
    )
    .unwrap();
    let socket = env.path("agent.sock");
    let b = v1_backend(&env.root);
    let mut first = spawn_agent(&env, &stack, &socket);
    wait_api(&socket);
    wait_until("the node to come up", WAIT, POLL, || {
        !pids_of(&b, "/napper").is_empty()
    });
    let pid = pids_of(&b, "/napper")[0];
    let (code, body) = request(&socket, "POST", "/v1/apps/pause/freeze", None).unwrap();
    assert_eq!(code, 200, "{body}");
    assert_eq!(proc_state(pid), Some('T'));

    first.0.kill().unwrap();
    first.0.wait().unwrap();
    let _second = spawn_agent(&env, &stack, &socket);
    wait_api(&socket);
    let (_, body) = request(&socket, "GET", "/v1/nodes", None).unwrap();
    let nodes: serde_json::Value = serde_json::from_str(&body).unwrap();
    let napper = &nodes.as_array().unwrap()[0];
    assert_eq!(napper["frozen"], true, "{napper}");
    assert_eq!(
        napper["mainPid"], pid,
        "re-attached, not restarted: {napper}"
    );
    assert_eq!(proc_state(pid), Some('T'), "still stopped");

    let (code, body) = request(&socket, "POST", "/v1/apps/pause/thaw", None).unwrap();
    assert_eq!(code, 200, "{body}");
    assert_ne!(proc_state(pid), Some('T'), "thawed");
    let (_, body) = request(&socket, "GET", "/v1/nodes", None).unwrap();
    assert!(body.contains("\"frozen\":false"), "{body}");
    let (code, _) = request(&socket, "POST", "/v1/apps/pause/stop", None).unwrap();
    assert_eq!(code, 200);
    assert!(pids_of(&b, "/napper").is_empty());
}
