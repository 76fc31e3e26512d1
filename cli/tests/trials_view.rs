//! `configbot get trials` (once and `-w`) and `configbot get cprof` (the
//! library, exported as YAML) against a control plane whose runner tunes
//! the simulated two-app robot of the controller's tests to Monitoring.

use std::time::Duration;

use configbot_manifests::Kind;
use configbot_test_support::{try_wait_until, try_wait_until_async};
use serde_json::{Value, json};

#[path = "../../controller/tests/fixture/mod.rs"]
mod fixture;

/// How often the condition waits look.
const POLL: Duration = Duration::from_millis(20);

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_trials_view_redraws_on_change_and_the_library_exports_as_yaml() {
    let dir = tempfile::tempdir().unwrap();
    let (server, cfg) = fixture::serve(dir.path(), 11).await;
    let store = server.state.store.clone();
    let mut last = Value::Null;
    try_wait_until_async("Monitoring", Duration::from_secs(120), POLL, async || {
        last = store
            .get(Kind::PerformanceSpec, "default", "nav-spec")
            .unwrap()
            .unwrap();
        (last["status"]["phase"] == "Monitoring").then_some(())
    })
    .await
    .unwrap_or_else(|e| panic!("{e}: {last:#}"));
    // The CLI: the trials view and the library as ConfigProfiles (export as YAML).
    let cli = |args: &[&str]| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_configbot"))
            .arg("--server")
            .arg(format!("unix://{}", cfg.socket.display()))
            .args(args)
            .output()
            .unwrap();
        assert!(out.status.success(), "{args:?}: {out:?}");
        String::from_utf8(out.stdout).unwrap()
    };
    let view = cli(&["get", "trials", "nav-spec"]);
    assert!(
        view.starts_with("nav-spec: Monitoring  trials 6/6 [####################]"),
        "{view}"
    );
    assert!(
        view.contains("baseline") && view.contains("CMD-VEL"),
        "{view}"
    );
    // `-w` redraws on every status change (the runner keeps monitoring).
    let mut watch = std::process::Command::new(env!("CARGO_BIN_EXE_configbot"))
        .arg("--server")
        .arg(format!("unix://{}", cfg.socket.display()))
        .args(["get", "trials", "nav-spec", "-w"])
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let stdout = watch.stdout.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel::<String>();
    std::thread::spawn(move || {
        use std::io::Read;
        let mut stdout = stdout;
        let mut buf = [0u8; 4096];
        while let Ok(n) = stdout.read(&mut buf) {
            if n == 0
                || tx
                    .send(String::from_utf8_lossy(&buf[..n]).into_owned())
                    .is_err()
            {
                break;
            }
        }
    });
    let mut seen = String::new();
    let read_until = |seen: &mut String, what: &str| {
        try_wait_until(what, Duration::from_secs(30), POLL, || {
            seen.extend(rx.try_iter());
            seen.contains(what)
        })
        .is_ok()
    };
    assert!(
        read_until(&mut seen, "nav-spec: Monitoring"),
        "first view: {seen}"
    );
    // Any change to the object redraws: touch an annotation.
    let mut obj = store
        .get(Kind::PerformanceSpec, "default", "nav-spec")
        .unwrap()
        .unwrap();
    obj["metadata"]["annotations"] = json!({"note": "watched"});
    obj["metadata"]
        .as_object_mut()
        .unwrap()
        .remove("resourceVersion");
    store.put(Kind::PerformanceSpec, obj, false).unwrap();
    let redrawn = read_until(&mut seen, "\x1b[2J\x1b[Hnav-spec: Monitoring");
    let _ = watch.kill();
    let _ = watch.wait();
    assert!(redrawn, "get trials -w redraws on changes: {seen}");
    let profiles = cli(&["get", "cprof"]);
    assert!(
        profiles.contains("simbot") && profiles.contains("nav-spec"),
        "{profiles}"
    );
    let exported = cli(&["get", "cprof", "-o", "yaml"]);
    assert!(
        exported.contains("kind: ConfigProfile") && exported.contains("robotModel: simbot"),
        "{exported}"
    );
    server.stop();
}
