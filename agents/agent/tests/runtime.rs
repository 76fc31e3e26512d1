//! The node runtime end to end on real cgroups, real processes, the real
//! process monitor and real rospy nodes against the agent's own ROS master
//! (root needed; ROS tests skip when ROS is not installed).

mod common;

use std::time::{Duration, Instant};

use configbot_agent::{AgentEvent, NodeApi, RuntimeEvent, StackSpec};
use configbot_api::measure::{MeasureRequest, Probe};
use configbot_manifests::{AdaptorRate, ResourceConfig};
use configbot_procmon::{MonitorKind, Preference};

use common::rt::{
    RECORDING_MAX_MB, RT_POLL, RtEnv, graph_pid, robot_stack, ros_available, stack_yaml,
};
use common::{node, try_wait_event, wait_event};
use configbot_test_support::wait_until_async;

const T: Duration = Duration::from_secs(40);

fn cgroup_pids(rt: &configbot_agent::NodeRuntime, n: &str) -> Vec<u32> {
    rt.agent().backend().pids(&node(n)).unwrap_or_default()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ros_nodes_are_adopted_limited_adapted_and_measured() {
    let Some((mut env, rt)) = RtEnv::start_with_ros(Some(Preference::Auto)).await else {
        return;
    };
    let mut events = rt.events();
    let nav = env.rospy_core_app(
        "nav",
        &[("/talker", "talker.py", &["talker", "/chatter", "30"])],
    );
    let stack = robot_stack(&stack_yaml(&format!(
        r#"{nav}    - name: det
      nodes:
        - name: /listener
          match: {{rosNode: /listener}}
        - name: /burner
          run: {{command: /usr/bin/python3, args: ["-c", "while True: pass"]}}
"#
    )));
    rt.set_stack(Some(&stack)).await.unwrap();
    // Limit the busy node at once (keeps the shared machine free).
    let cfg = ResourceConfig {
        cpu: [("/burner".to_string(), 0.1)].into(),
        cpu_weight: Default::default(),
        cpu_period_micros: Some(20_000),
        adaptors: vec![AdaptorRate {
            topic: "/chatter".into(),
            subscriber: "/listener".into(),
            rate_hz: 10.0,
        }],
    };
    rt.apply(&cfg).await.unwrap();
    // The listener starts outside the agent, after the stack made it
    // non-core: the placement gives it an adaptor when it subscribes.
    let listener = env.script("listener.py", &["listener", "/chatter"]);
    let listener_pid = env.procs[listener].pid();

    wait_until_async(
        "both ROS nodes in their cgroups with graph pids",
        T,
        RT_POLL,
        async || {
            let t = graph_pid(&rt, "/talker");
            let l = graph_pid(&rt, "/listener");
            t.is_some_and(|p| cgroup_pids(&rt, "/talker").contains(&p))
                && l == Some(listener_pid)
                && cgroup_pids(&rt, "/listener").contains(&listener_pid)
        },
    )
    .await;
    // The event stream saw the graph change and the adoption by ROS name
    // (the agent's events reach it through a forwarding task: wait for them).
    let (mut graph_listener, mut adopted) = (false, false);
    try_wait_event(&mut events, T, |ev| {
        match ev {
            RuntimeEvent::GraphChanged { events } => {
                graph_listener |= events.iter().any(|g| {
                    matches!(g, configbot_api::graph::GraphEvent::NodeAdded(n)
                        | configbot_api::graph::GraphEvent::NodeChanged(n) if n.name == "/listener")
                });
            }
            RuntimeEvent::Agent(AgentEvent::NodeAdopted { node, pids }) => {
                adopted |= node.as_str() == "/listener" && pids.contains(&listener_pid);
            }
            _ => {}
        }
        graph_listener && adopted
    })
    .await;
    assert!(
        graph_listener && adopted,
        "graph {graph_listener} adopted {adopted}"
    );
    let inv = rt.inventory().await.unwrap();
    let talker = inv.iter().find(|n| n.name.as_str() == "/talker").unwrap();
    assert_eq!(talker.main_pid, graph_pid(&rt, "/talker"), "{talker:?}");
    let edge_adapted = || {
        rt.data_plane()
            .unwrap()
            .adaptor_counters()
            .iter()
            .any(|(e, c)| e.topic == "/chatter" && e.subscriber == "/listener" && c.forwarded > 0)
    };
    wait_until_async("messages through the adaptor", T, RT_POLL, async || {
        edge_adapted()
    })
    .await;

    let req = MeasureRequest {
        probes: vec![
            Probe::TopicRate {
                topic: "/chatter".into(),
                subscriber: None,
            },
            Probe::TopicRate {
                topic: "/chatter".into(),
                subscriber: Some("/listener".into()),
            },
            Probe::CpuUsage {
                node: "/burner".into(),
            },
            Probe::CpuUsage {
                node: "/talker".into(),
            },
            Probe::TopicRate {
                topic: "/nobody_publishes".into(),
                subscriber: None,
            },
        ],
        duration_ms: 4000,
        sub_window_ms: 1000,
    };
    let t0 = Instant::now();
    let report = rt.measure(&req).await.unwrap();
    let received = common::rt::count_between(&env.procs[listener], t0, Instant::now()) as f64
        / t0.elapsed().as_secs_f64();
    eprintln!("report {report:?}\nlistener's own count {received:.1} Hz");
    assert_eq!(report.series.len(), 5);
    for s in &report.series {
        assert_eq!(s.values.len(), 4, "{s:?}");
    }
    let [topic, sub, burner, talker_cpu, silent] = &report.series[..] else {
        unreachable!()
    };
    assert!((27.0..=33.0).contains(&topic.mean), "topic {topic:?}");
    assert!((8.5..=11.5).contains(&sub.mean), "subscriber {sub:?}");
    // per sub-window: whole-message counts over ~1 s, so ±3 at 30 Hz
    assert!(
        topic.values.iter().all(|v| (24.0..=36.0).contains(v)),
        "{topic:?}"
    );
    assert!(
        sub.values.iter().all(|v| (7.0..=13.0).contains(v)),
        "{sub:?}"
    );
    assert!(
        (7.0..=13.0).contains(&received),
        "listener got {received} Hz"
    );
    assert!((0.06..=0.14).contains(&burner.mean), "burner {burner:?}");
    assert!(burner.values.iter().all(|v| *v <= 0.16), "{burner:?}");
    assert!((0.0..0.5).contains(&talker_cpu.mean), "{talker_cpu:?}");
    assert_eq!(silent.mean, 0.0, "a topic without messages is 0 Hz");

    // A config without the edge puts it back to pass-through.
    rt.apply(&ResourceConfig {
        cpu: [("/burner".to_string(), 0.1)].into(),
        ..ResourceConfig::default()
    })
    .await
    .unwrap();
    let adaptors = rt.data_plane().unwrap().adaptors();
    assert!(
        adaptors.values().all(|s| s.rate_hz.is_none()),
        "{adaptors:?}"
    );
    let r = rt
        .measure(&MeasureRequest {
            probes: vec![req.probes[1].clone()],
            duration_ms: 2000,
            sub_window_ms: 1000,
        })
        .await
        .unwrap();
    assert!((25.0..=35.0).contains(&r.series[0].mean), "{r:?}");

    // Unknown node: an error naming it.
    let e = rt
        .measure(&MeasureRequest {
            probes: vec![Probe::CpuUsage {
                node: "/ghost".into(),
            }],
            duration_ms: 100,
            sub_window_ms: 100,
        })
        .await
        .unwrap_err();
    assert!(e.to_string().contains("/ghost"), "{e}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn set_stack_adds_removes_and_restarts_nodes_at_run_time() {
    let mut env = RtEnv::new();
    let one = |extra: &str| {
        robot_stack(&stack_yaml(&format!(
            r#"    - name: a
      nodes:
        - name: /one
          run: {{command: /bin/sleep, args: ["300"]}}
{extra}"#
        )))
    };
    let rt = env.start(false, None, StackSpec::default()).await;
    rt.set_stack(Some(&one(""))).await.unwrap();
    wait_until_async("/one running", T, RT_POLL, async || {
        cgroup_pids(&rt, "/one").len() == 1
    })
    .await;
    let one_pid = cgroup_pids(&rt, "/one")[0];

    rt.set_stack(Some(&one(
        "        - name: /two\n          run: {command: /bin/sleep, args: [\"301\"]}",
    )))
    .await
    .unwrap();
    wait_until_async("/two running", T, RT_POLL, async || {
        cgroup_pids(&rt, "/two").len() == 1
    })
    .await;
    assert_eq!(cgroup_pids(&rt, "/one"), [one_pid], "/one untouched");
    let two_pid = cgroup_pids(&rt, "/two")[0];

    // /two's command changes: restarted with a new process.
    rt.set_stack(Some(&one(
        "        - name: /two\n          run: {command: /bin/sleep, args: [\"302\"]}",
    )))
    .await
    .unwrap();
    // The new process joins its cgroup before it execs, so wait for the exec too.
    wait_until_async("/two restarted as sleep 302", T, RT_POLL, async || {
        let p = cgroup_pids(&rt, "/two");
        p.len() == 1
            && p[0] != two_pid
            && std::fs::read_to_string(format!("/proc/{}/cmdline", p[0]))
                .is_ok_and(|c| c.contains("302"))
    })
    .await;
    // /one removed: stopped and its cgroup gone.
    let only_two = robot_stack(&stack_yaml(
        r#"    - name: a
      nodes:
        - name: /two
          run: {command: /bin/sleep, args: ["302"]}
"#,
    ));
    rt.set_stack(Some(&only_two)).await.unwrap();
    assert!(
        !rt.agent().backend().exists(&node("/one")),
        "cgroup of /one left"
    );
    wait_until_async("/one's process gone", T, RT_POLL, async || {
        std::fs::read_to_string(format!("/proc/{one_pid}/stat")).map_or(true, |s| s.contains(") Z"))
    })
    .await;
    let names: Vec<String> = rt
        .inventory()
        .await
        .unwrap()
        .into_iter()
        .map(|n| n.name.as_str().to_owned())
        .collect();
    assert_eq!(names, ["/two"]);
    // the applied stack survives in the state file for the next start
    let state = std::fs::read_to_string(env.path("state.json")).unwrap();
    assert!(
        state.contains("\"/two\"") && !state.contains("\"/one\""),
        "{state}"
    );
}

async fn exec_event_latency(monitor: Preference, program: &str, args: &[&str]) -> (u64, u64) {
    let mut env = RtEnv::new();
    let rt = env.start(false, Some(monitor), StackSpec::default()).await;
    let mut rx = rt.events();
    let before = configbot_agent_unix_ms();
    let mut child = std::process::Command::new(program)
        .args(args)
        .spawn()
        .unwrap();
    let pid = child.id();
    let spawned = Instant::now();
    let ev = tokio::time::timeout(Duration::from_secs(1), async {
        loop {
            match rx.recv().await {
                Ok(RuntimeEvent::ProcessExec {
                    pid: p,
                    at_unix_ms,
                    seen_unix_ms,
                    ..
                }) if p == pid => return (at_unix_ms, seen_unix_ms),
                Ok(_) | Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => {}
                Err(e) => panic!("{e}"),
            }
        }
    })
    .await;
    let waited = spawned.elapsed();
    let _ = child.kill();
    let _ = child.wait();
    let (at, seen) = ev.unwrap_or_else(|_| panic!("no exec event for {pid} within 1 s"));
    tokio::time::timeout(Duration::from_secs(2), async {
        loop {
            match rx.recv().await {
                Ok(RuntimeEvent::ProcessExit { pid: p, .. }) if p == pid => return,
                Ok(_) | Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => {}
                Err(e) => panic!("{e}"),
            }
        }
    })
    .await
    .unwrap_or_else(|_| panic!("no exit event for {pid}"));
    eprintln!(
        "{}: exec at +{} ms, seen +{} ms after spawn start, event after {waited:?}",
        rt.monitor_status(),
        at.saturating_sub(before),
        seen.saturating_sub(before)
    );
    assert!(
        at + 5 >= before && at <= seen,
        "at {at} seen {seen} before {before}"
    );
    (at - before.min(at), seen - before.min(seen))
}

fn configbot_agent_unix_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_millis() as u64
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn spawned_process_is_an_exec_event_within_a_second() {
    exec_event_latency(Preference::Auto, "/bin/true", &[]).await;
    // The fallback: a /proc scan (250 ms) sees a process that lives a while.
    exec_event_latency(
        Preference::Only(MonitorKind::ProcScan),
        "/bin/sleep",
        &["2"],
    )
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn http_api_and_client_round_trip_over_the_unix_socket() {
    let Some((env, rt)) = RtEnv::start_with_ros(Some(Preference::Auto)).await else {
        return;
    };
    let sock = env.path("agent.sock");
    let listener = configbot_agent::api::bind_unix(&sock).unwrap();
    let server = tokio::spawn(configbot_agent::api::serve_unix(rt.clone(), listener));
    let client = configbot_agent::client::AgentClient::unix(&sock);
    let mut events = client.events().await.unwrap();

    let stack = robot_stack(&stack_yaml(&env.rospy_core_app(
        "cam",
        &[("/camera", "talker.py", &["camera", "/image", "20"])],
    )));
    client.set_stack(Some(&stack)).await.unwrap();
    let camera_pid = wait_until_async(
        "the camera publishing /image in the graph",
        T,
        Duration::from_millis(100),
        async || {
            let g = client.graph().await.unwrap();
            let publishes = g
                .topics
                .get("/image")
                .is_some_and(|t| !t.publishers.is_empty());
            g.nodes
                .get("/camera")
                .and_then(|n| n.pid)
                .filter(|_| publishes)
        },
    )
    .await;
    let inv = client.inventory().await.unwrap();
    assert_eq!(inv.len(), 1);
    assert!(inv[0].pids.contains(&camera_pid), "{inv:?}");

    client
        .apply(&ResourceConfig {
            cpu: [("/camera".to_string(), 0.5)].into(),
            cpu_weight: [("/camera".to_string(), 10_000)].into(),
            cpu_period_micros: Some(50_000),
            adaptors: vec![],
        })
        .await
        .unwrap();
    let max = rt.agent().backend().cpu_max(&node("/camera")).unwrap();
    assert_eq!((max.quota_us, max.period_us), (Some(25_000), 50_000));
    let weight = rt.agent().backend().weight(&node("/camera")).unwrap();
    assert_eq!(weight, configbot_cgroups::CpuWeight::MAX);
    let err = client
        .apply(&ResourceConfig {
            cpu: [("/ghost".to_string(), 0.5)].into(),
            ..ResourceConfig::default()
        })
        .await
        .unwrap_err();
    assert!(err.to_string().contains("/ghost"), "{err}");

    let report = client
        .measure(&MeasureRequest {
            probes: vec![
                Probe::TopicRate {
                    topic: "/image".into(),
                    subscriber: None,
                },
                Probe::CpuUsage {
                    node: "/camera".into(),
                },
            ],
            duration_ms: 3000,
            sub_window_ms: 1000,
        })
        .await
        .unwrap();
    eprintln!("{report:?}");
    assert!((18.0..=22.0).contains(&report.series[0].mean), "{report:?}");
    assert_eq!(report.series[0].values.len(), 3);
    assert!(report.series[1].mean <= 0.5 + 0.05, "{report:?}");

    // The runtime's metrics carry the measured topic rate and the monitor.
    let metrics = {
        let s = tokio::net::UnixStream::connect(&sock)
            .await
            .unwrap()
            .into_std()
            .unwrap();
        s.set_nonblocking(false).unwrap();
        tokio::task::spawn_blocking(move || common::http(s, "GET", "/metrics", None, None))
            .await
            .unwrap()
    };
    assert_eq!(metrics.0, 200);
    assert!(
        metrics
            .1
            .contains("configbot_agent_topic_rate_hz{subscriber=\"\",topic=\"/image\"}"),
        "{}",
        metrics.1
    );
    assert!(
        metrics
            .1
            .contains("configbot_agent_active_monitor{monitor=\"")
    );

    client.stop_app("cam").await.unwrap();
    wait_event(
        &mut events,
        "an appStopped event through the client",
        T,
        |ev| matches!(ev, RuntimeEvent::Agent(AgentEvent::AppStopped { app }) if app == "cam"),
    )
    .await;
    assert!(
        client
            .stop_app("nope")
            .await
            .unwrap_err()
            .to_string()
            .contains("404")
    );
    server.abort();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_binary_runs_the_full_runtime_from_a_robot_stack_yaml() {
    if !ros_available() {
        return;
    }
    let mut env = RtEnv::new();
    let yaml =
        stack_yaml(&env.rospy_core_app("nav", &[("/odom", "talker.py", &["odom", "/odom", "10"])]));
    let stack = env.path("stack.yaml");
    std::fs::write(&stack, yaml).unwrap();
    let sock = env.path("agent.sock");
    let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_configbot-agent"));
    cmd.arg("--stack")
        .arg(&stack)
        .args(["--cgroup-root", &env.root])
        .arg("--state-file")
        .arg(env.path("state.json"))
        .arg("--log-dir")
        .arg(env.path("logs"))
        .arg("--socket")
        .arg(&sock)
        .args([
            "--ros-master-uri",
            &env.master_uri,
            "--ros-bind",
            "127.0.0.1",
        ])
        .arg("--ros-db")
        .arg(env.path("ros1.db"))
        .args(["--monitor", "auto"]);
    env.procs.push(common::rt::Proc::spawn(cmd));
    let client = configbot_agent::client::AgentClient::unix(&sock);
    let odom_pid = wait_until_async(
        "/odom to register with the agent's master",
        T,
        Duration::from_millis(100),
        async || client.graph().await.ok()?.nodes.get("/odom")?.pid,
    )
    .await;
    let inv = client.inventory().await.unwrap();
    assert!(inv[0].pids.contains(&odom_pid), "{inv:?}");
    // Real ROS tools see the agent as the master.
    let out = env
        .ros_command("/usr/bin/rostopic")
        .args(["list"])
        .output()
        .unwrap();
    assert!(
        String::from_utf8_lossy(&out.stdout).contains("/odom"),
        "{out:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn client_over_tcp_needs_the_token() {
    let mut env = common::Env::new();
    let agent = env
        .start(common::stack_json(
            r#"{"apps":[{"name":"a","nodes":[{"name":"/s","run":{"command":"/bin/sleep","args":["300"]}}]}]}"#,
        ))
        .await;
    let rt = configbot_agent::NodeRuntime::with_agent(agent).unwrap();
    let l = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = l.local_addr().unwrap().to_string();
    let server = tokio::spawn(configbot_agent::api::serve_tcp(rt, l, "t0ken".into()));
    let good = configbot_agent::client::AgentClient::tcp(addr.clone(), "t0ken");
    let inv = good.inventory().await.unwrap();
    assert_eq!(inv[0].name.as_str(), "/s");
    assert_eq!(
        good.graph().await.unwrap(),
        configbot_api::graph::Graph::default()
    );
    let e = good
        .measure(&MeasureRequest {
            probes: vec![Probe::TopicRate {
                topic: "/x".into(),
                subscriber: None,
            }],
            duration_ms: 100,
            sub_window_ms: 100,
        })
        .await
        .unwrap_err();
    assert!(e.to_string().contains("ROS data plane"), "{e}");
    let bad = configbot_agent::client::AgentClient::tcp(addr, "wrong");
    let e = bad.inventory().await.unwrap_err();
    assert!(
        matches!(
            e,
            configbot_agent::client::ClientError::Status { status: 401, .. }
        ),
        "{e}"
    );
    server.abort();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_rosbag_recording_over_the_api_holds_the_topics_messages() {
    let Some((env, rt)) = RtEnv::start_with_ros(None).await else {
        return;
    };
    let sock = env.path("agent.sock");
    let listener = configbot_agent::api::bind_unix(&sock).unwrap();
    let server = tokio::spawn(configbot_agent::api::serve_unix(rt.clone(), listener));
    let client = configbot_agent::client::AgentClient::unix(&sock);
    let stack = robot_stack(&stack_yaml(&env.rospy_core_app(
        "cam",
        &[("/camera", "talker.py", &["camera", "/image", "20"])],
    )));
    client.set_stack(Some(&stack)).await.unwrap();
    let subscribers = |rt: &configbot_agent::NodeRuntime| {
        let g = rt.data_plane().map(|d| d.graph()).unwrap_or_default();
        g.topics
            .get("/image")
            .map(|t| (t.publishers.len(), t.subscribers.clone()))
            .unwrap_or_default()
    };
    wait_until_async("/image published", T, RT_POLL, async || {
        subscribers(&rt).0 == 1
    })
    .await;
    let mut events = client.events().await.unwrap();

    let image = vec!["/image".to_string()];
    let path = client
        .start_recording("remedy-1", &image)
        .await
        .unwrap()
        .expect("rosbag is installed with ros-core");
    assert!(path.starts_with(env.path("bags")), "{path:?}");
    assert_eq!(
        client.start_recording("remedy-1", &image).await.unwrap(),
        Some(path.clone()),
        "one recording per name"
    );
    let err = client.start_recording("../x", &image).await.unwrap_err();
    assert!(err.to_string().contains("400"), "{err}");
    // rosbag's recorder subscribes like any node (`/record_…`), then records.
    wait_until_async("rosbag subscribed to /image", T, RT_POLL, async || {
        subscribers(&rt).1.iter().any(|s| s.starts_with("/record"))
    })
    .await;
    tokio::time::sleep(Duration::from_secs(3)).await;
    let stopped = client.stop_recording("remedy-1").await.unwrap();
    assert_eq!(stopped, Some(path.clone()));
    assert_eq!(client.stop_recording("remedy-1").await.unwrap(), None);

    let info = env
        .ros_command("/usr/bin/rosbag")
        .args(["info", "--yaml", "--key", "messages"])
        .arg(&path)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&info.stdout);
    let messages: u64 = text.trim().parse().unwrap_or(0);
    eprintln!(
        "bag {}: {messages} messages in about 3 s of a 20 Hz topic",
        path.display()
    );
    assert!(messages >= 20, "{info:?}");
    wait_until_async("rosbag's node unregistered", T, RT_POLL, async || {
        !subscribers(&rt).1.iter().any(|s| s.starts_with("/record"))
    })
    .await;
    let mut seen = (false, false);
    while seen != (true, true) {
        let ev = tokio::time::timeout(T, events.recv())
            .await
            .expect("no recording events")
            .unwrap();
        match ev {
            RuntimeEvent::Agent(AgentEvent::RecordingStarted { name, topics, .. }) => {
                assert_eq!((name.as_str(), topics), ("remedy-1", image.clone()));
                seen.0 = true;
            }
            RuntimeEvent::Agent(AgentEvent::RecordingStopped { path: p, .. }) => {
                assert_eq!(p, path);
                seen.1 = true;
            }
            _ => {}
        }
    }
    server.abort();
}

/// A recording of a busy topic stops at the size cap (`rosbag record
/// --size`): rosbag closes the bag by itself, and the bag is about the cap,
/// not the seconds × rate it would otherwise hold.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_recording_stops_at_its_size_cap() {
    const PAD: usize = 100_000;
    let Some((env, rt)) = RtEnv::start_with_ros(None).await else {
        return;
    };
    let stack = robot_stack(&stack_yaml(&env.rospy_core_app(
        "cam",
        &[(
            "/camera",
            "talker.py",
            &["camera", "/image", "20", &PAD.to_string()],
        )],
    )));
    rt.set_stack(Some(&stack)).await.unwrap();
    let published = || {
        let g = rt.data_plane().map(|d| d.graph()).unwrap_or_default();
        g.topics
            .get("/image")
            .is_some_and(|t| !t.publishers.is_empty())
    };
    wait_until_async("/image published", T, RT_POLL, async || published()).await;
    // 20 × 100 kB = 2 MB/s: the cap is reached in about a second.
    let path = rt
        .start_recording("capped", &["/image".to_string()])
        .await
        .unwrap()
        .expect("rosbag is installed with ros-core");
    // rosbag writes `<bag>.active` and renames it when it closes the bag.
    wait_until_async("rosbag closed the bag at its cap", T, RT_POLL, async || {
        path.exists()
    })
    .await;
    let bytes = std::fs::metadata(&path).unwrap().len();
    let cap = RECORDING_MAX_MB * 1024 * 1024;
    eprintln!("capped bag: {bytes} bytes (cap {cap})");
    // At most one chunk (768 kB) and a message past the cap.
    assert!(bytes <= cap + 1024 * 1024, "{bytes} bytes");
    assert!(bytes >= cap / 2, "{bytes} bytes");
    assert_eq!(rt.stop_recording("capped").await.unwrap(), Some(path));
}

/// A recorder a killed runtime left behind (here a stand-in `rosbag` that
/// exits on SIGINT, as rosbag does after closing its bag) is stopped by the
/// next runtime's `stop_orphans`; one writing elsewhere is left alone.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_recorder_left_by_a_killed_runtime_is_stopped() {
    use configbot_agent::runtime::record::Recordings;
    let tmp = tempfile::tempdir().unwrap();
    let bags = tmp.path().join("bags");
    std::fs::create_dir_all(&bags).unwrap();
    let bags = std::fs::canonicalize(&bags).unwrap();
    let fake = tmp.path().join("rosbag");
    std::fs::write(
        &fake,
        "#!/bin/sh\ntrap 'exit 0' INT\necho ready\nwhile :; do sleep 0.05; done\n",
    )
    .unwrap();
    std::fs::set_permissions(&fake, std::os::unix::fs::PermissionsExt::from_mode(0o755)).unwrap();
    // Started with SIGINT at its default action, as the runtime starts its
    // recorders, whatever this test process inherited.
    let spawn = |dir: &std::path::Path| {
        let mut c = std::process::Command::new("/usr/bin/env");
        c.arg("--default-signal=INT")
            .arg(&fake)
            .args(["record", "-O"])
            .arg(dir.join("x-1.bag"))
            .arg("/scan");
        common::rt::Proc::spawn(c)
    };
    let elsewhere = tmp.path().join("other");
    let mut orphan = spawn(&bags);
    let mut other = spawn(&elsewhere);
    // Started once each stand-in has set its trap and said so. Before
    // that, a SIGINT can reach `env` while it still has this process's
    // disposition (ignored when the tests run as a background job, as CI's
    // do) and be lost, and `/proc` can show a command line mid-exec.
    wait_until_async("recorders started", T, RT_POLL, async || {
        [&orphan, &other].iter().all(|p| p.has_line("ready"))
    })
    .await;
    Recordings::new(bags.clone(), RECORDING_MAX_MB)
        .stop_orphans(std::path::Path::new("/proc"))
        .await;
    assert!(
        orphan.child.try_wait().unwrap().is_some(),
        "the orphan recorder still runs"
    );
    assert!(
        other.child.try_wait().unwrap().is_none(),
        "a recorder writing elsewhere was stopped"
    );
}
