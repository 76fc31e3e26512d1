//! The data plane runs on threads of its own: each runs its job's start
//! hook (metering or relaying), and the master keeps answering while the runtime that started it is not
//! running at all (a caller busy with blocking work). Needs no ROS install.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use configbot_dataplane::{DataPlane, ThreadHook, ThreadHooks};
use configbot_ros1::xmlrpc::Value;
use configbot_ros1::{DATA_PLANE_THREADS, Ros1Config, Ros1DataPlane, http};
use configbot_test_support::free_port;

#[test]
fn the_master_answers_on_the_data_planes_threads_while_its_callers_runtime_stands_still() {
    let dir = tempfile::tempdir().unwrap();
    // Per job: how many threads ran its hook, and their names.
    let hook = || {
        let started = Arc::new(AtomicUsize::new(0));
        let names = Arc::new(Mutex::new(Vec::new()));
        let (s, n) = (started.clone(), names.clone());
        let hook: ThreadHook = Arc::new(move || {
            s.fetch_add(1, Ordering::SeqCst);
            let name = std::thread::current().name().map(String::from);
            n.lock().unwrap().push(name);
        });
        (started, names, hook)
    };
    let (metering, metering_names, metering_hook) = hook();
    let (relaying, relaying_names, relaying_hook) = hook();
    let cfg = Ros1Config {
        master_uri: format!("http://127.0.0.1:{}/", free_port()),
        bind_host: "127.0.0.1".into(),
        advertise_host: "127.0.0.1".into(),
        refresh_period: Duration::from_secs(60),
        threads: ThreadHooks {
            metering: Some(metering_hook),
            relaying: Some(relaying_hook),
        },
        ..Ros1Config::default()
    };
    let master = cfg.master_uri.clone();
    // The caller's runtime runs only inside this block_on; afterwards
    // nothing drives it, as when its only thread is stuck in blocking work.
    let caller = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let dp = caller
        .block_on(Ros1DataPlane::start(
            cfg,
            &dir.path().join("ros1.db"),
            &prometheus::Registry::new(),
        ))
        .unwrap();
    for (job, started, names, want) in [
        ("metering", &metering, &metering_names, "configbot-ros1"),
        ("relaying", &relaying, &relaying_names, "configbot-relay"),
    ] {
        let workers = started.load(Ordering::SeqCst);
        assert!(
            (1..=DATA_PLANE_THREADS).contains(&workers),
            "{workers} {job} threads ran the hook"
        );
        let names = names.lock().unwrap();
        assert!(
            names.iter().all(|n| n.as_deref() == Some(want)),
            "{job}: {names:?}"
        );
    }

    // Another runtime, on another thread, calls the master.
    let answer = std::thread::spawn(move || {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        rt.block_on(http::call(
            &master,
            "registerPublisher",
            &[
                Value::str("/talker"),
                Value::str("/chatter"),
                Value::str("std_msgs/String"),
                Value::str("http://127.0.0.1:1/"),
            ],
            Duration::from_secs(5),
        ))
    })
    .join()
    .unwrap();
    let v = answer.expect("the master answers while its caller's runtime stands still");
    assert_eq!(
        v.as_array().and_then(|a| a.first()?.as_i64()),
        Some(1),
        "{v:?}"
    );
    assert!(dp.graph().topics.contains_key("/chatter"));
    // Dropping it from a thread outside any runtime, and the caller's
    // runtime after it, leaves nothing hanging.
    drop(dp);
    drop(caller);
}
