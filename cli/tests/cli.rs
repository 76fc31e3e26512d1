//! The `configbot` CLI against a real server: `get -o` formats, `delete` by
//! file, selector and dry run, shell completion, and inputs without objects.

mod common;

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use common::{BIN, cli, example, serve};
use serde_json::Value;

fn ok(dir: &Path, args: &[&str]) -> String {
    let (ok, out, err) = cli(dir, args);
    assert!(ok, "configbot {args:?} failed:\n{out}{err}");
    out
}

#[test]
fn get_output_formats() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let _server = serve(d);
    // Empty lists: a List object for json and yaml, nothing for name.
    let empty: Value = serde_json::from_str(&ok(d, &["get", "rs", "-o", "json"])).unwrap();
    assert_eq!(empty["kind"], "List");
    assert_eq!(empty["items"], serde_json::json!([]));
    let yaml = ok(d, &["get", "rs", "-o", "yaml"]);
    assert!(
        yaml.contains("kind: List") && yaml.contains("items: []"),
        "{yaml}"
    );
    assert_eq!(ok(d, &["get", "rs", "-o", "name"]), "");

    ok(
        d,
        &[
            "apply",
            "-f",
            &example("basic-nav"),
            "-f",
            &example("terrain-nav"),
        ],
    );
    assert_eq!(
        ok(d, &["get", "rs", "-o", "name"]),
        "robotstack.configbot.dev/basic-nav\nrobotstack.configbot.dev/terrain-nav\n"
    );
    assert_eq!(
        ok(
            d,
            &["get", "rs", "-o", "jsonpath={.items[*].metadata.name}"]
        ),
        "basic-nav terrain-nav"
    );
    assert_eq!(
        ok(
            d,
            &[
                "get",
                "rs",
                "basic-nav",
                "-o",
                r#"jsonpath={range .spec.apps[*]}{.name}{"\n"}{end}"#
            ]
        ),
        "sensors\nnavigation\nobj\n"
    );
    let cols = ok(
        d,
        &[
            "get",
            "rs",
            "-o",
            "custom-columns=NAME:.metadata.name,MODEL:.spec.robot.model,APPS:.spec.apps[*].name",
        ],
    );
    let lines: Vec<&str> = cols.lines().collect();
    assert_eq!(lines.len(), 3, "{cols}");
    assert!(
        lines[0].starts_with("NAME") && lines[0].contains("MODEL") && lines[0].contains("APPS"),
        "{cols}"
    );
    assert!(
        lines[1].starts_with("basic-nav") && lines[1].contains("sensors,navigation,obj"),
        "{cols}"
    );
    // One object by name is the object itself; a list is a List.
    let one: Value =
        serde_json::from_str(&ok(d, &["get", "rs", "basic-nav", "-o", "json"])).unwrap();
    assert_eq!(one["kind"], "RobotStack");
    let (succeeded, _, err) = cli(d, &["get", "rs", "-o", "jsonpath={.items[?(@.x)]}"]);
    assert!(!succeeded && err.contains("is not supported"), "{err}");

    // `get -o yaml` of a list is a manifest `apply` takes back.
    let exported = dir.path().join("export.yaml");
    std::fs::write(&exported, ok(d, &["get", "rs", "-o", "yaml"])).unwrap();
    ok(d, &["delete", "pspec", "basic-nav", "terrain-nav"]);
    ok(d, &["delete", "rs", "basic-nav", "terrain-nav"]);
    let out = ok(d, &["apply", "-f", exported.to_str().unwrap()]);
    assert_eq!(out.matches(" created").count(), 2, "{out}");
}

#[test]
fn delete_by_file_selector_and_dry_run() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let _server = serve(d);
    let basic = example("basic-nav");
    ok(d, &["apply", "-f", &basic, "-f", &example("terrain-nav")]);

    let out = ok(d, &["delete", "-f", &basic, "--dry-run"]);
    assert!(
        out.contains("performancespec.configbot.dev/basic-nav deleted (server dry run)"),
        "{out}"
    );
    assert_eq!(ok(d, &["get", "pspec", "-o", "name"]).lines().count(), 2);

    // Specs go before the stacks they refer to.
    let out = ok(d, &["delete", "-f", &basic]);
    assert_eq!(
        out,
        "performancespec.configbot.dev/basic-nav deleted\nrobotstack.configbot.dev/basic-nav deleted\n"
    );
    let (succeeded, _, err) = cli(d, &["delete", "-f", &basic]);
    assert!(!succeeded && err.contains("not found"), "{err}");
    ok(d, &["delete", "-f", &basic, "--ignore-not-found"]);

    let labels = ok(
        d,
        &[
            "get",
            "rs",
            "terrain-nav",
            "-o",
            "jsonpath={.metadata.labels}",
        ],
    );
    let labels: Value = serde_json::from_str(&labels).unwrap();
    let (k, v) = labels
        .as_object()
        .unwrap()
        .iter()
        .next()
        .expect("terrain-nav has labels");
    let sel = format!("{k}={}", v.as_str().unwrap());
    let out = ok(
        d,
        &[
            "delete",
            "rs",
            "-l",
            &format!("{k}!={}", v.as_str().unwrap()),
        ],
    );
    assert!(out.is_empty(), "{out}");
    let out = ok(d, &["delete", "rs", "-l", &sel]);
    assert_eq!(out, "robotstack.configbot.dev/terrain-nav deleted\n");
    assert_eq!(ok(d, &["get", "rs", "-o", "name"]), "");

    let (succeeded, _, err) = cli(d, &["delete", "rs"]);
    assert!(!succeeded && err.contains("-l SELECTOR"), "{err}");
    let (succeeded, _, _) = cli(d, &["delete", "rs", "x", "-f", &basic]);
    assert!(!succeeded, "KIND and -f together must be refused");
}

/// `---` lines alone are no objects: validate and apply say so and fail.
#[test]
fn inputs_without_objects_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let _server = serve(d);
    let empty = d.join("empty.yaml");
    std::fs::write(&empty, "---\n---\n").unwrap();
    let f = empty.to_str().unwrap();
    for verb in ["validate", "apply"] {
        let (ok, _, err) = cli(d, &[verb, "-f", f]);
        assert!(!ok, "{verb} of an empty stream succeeded");
        assert!(
            err.contains(&format!("no objects passed to {verb}")),
            "{err}"
        );
    }
    let run_on = d.join("run-on.yaml");
    std::fs::write(&run_on, "--- ---\n").unwrap();
    let (ok, _, err) = cli(d, &["validate", "-f", run_on.to_str().unwrap()]);
    assert!(!ok && err.contains("invalid document separator"), "{err}");
}

/// The bash script really completes subcommands; zsh and fish scripts are
/// produced for `configbot`.
#[test]
fn shell_completion() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let script = d.join("configbot.bash");
    std::fs::write(&script, ok(d, &["completion", "bash"])).unwrap();
    let out = Command::new("bash")
        .arg("-c")
        .arg(format!(
            "source {}; COMP_WORDS=(configbot de); COMP_CWORD=1; _configbot configbot de configbot; printf '%s\\n' \"${{COMPREPLY[@]}}\"",
            script.display()
        ))
        .output()
        .unwrap();
    let words = String::from_utf8_lossy(&out.stdout);
    let mut words: Vec<&str> = words.lines().collect();
    words.sort();
    assert_eq!(
        words,
        ["delete", "demo", "describe"],
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(ok(d, &["completion", "zsh"]).starts_with("#compdef configbot"));
    assert!(ok(d, &["completion", "fish"]).contains("complete -c configbot"));
    let (succeeded, _, err) = cli(d, &["completion", "tcsh"]);
    assert!(!succeeded && err.contains("tcsh"), "{err}");
}

/// `get -w` against a server that ends its watch with ERROR 410 Expired (a
/// watcher that fell behind): the CLI says so, lists again and watches on.
#[test]
fn get_watch_lists_again_when_the_watch_expires() {
    use axum::extract::Query;
    use std::collections::HashMap;
    use std::sync::Arc;
    use std::sync::atomic::{AtomicUsize, Ordering};

    let dir = tempfile::tempdir().unwrap();
    let socket = dir.path().join("api.sock");
    let stack = |name: &str| {
        serde_json::json!({"apiVersion": "configbot.dev/v1alpha1", "kind": "RobotStack",
            "metadata": {"name": name, "namespace": "default", "creationTimestamp": "2026-01-01T00:00:00Z"},
            "spec": {"apps": []}, "status": {"phase": "Accepted"}})
    };
    let lists = Arc::new(AtomicUsize::new(0));
    let watches = Arc::new(AtomicUsize::new(0));
    let (l, w) = (lists.clone(), watches.clone());
    let app = axum::Router::new().route(
        "/apis/configbot.dev/v1alpha1/namespaces/default/robotstacks",
        axum::routing::get(
            move |Query(q): Query<HashMap<String, String>>| {
                let (l, w) = (l.clone(), w.clone());
                async move {
                    if q.get("watch").map(String::as_str) != Some("true") {
                        let n = l.fetch_add(1, Ordering::SeqCst);
                        let items = if n == 0 { vec![stack("first")] } else { vec![stack("first"), stack("relisted")] };
                        return serde_json::json!({"kind": "RobotStackList", "metadata": {"resourceVersion": "7"}, "items": items}).to_string();
                    }
                    if w.fetch_add(1, Ordering::SeqCst) == 0 {
                        let expired = serde_json::json!({"type": "ERROR", "object": {"kind": "Status", "apiVersion": "v1", "status": "Failure",
                            "code": 410, "reason": "Expired", "message": "the watch fell 9 changes behind and was closed"}});
                        format!("{}\n", expired)
                    } else {
                        let ev = serde_json::json!({"type": "MODIFIED", "object": stack("later")});
                        format!("{ev}\n")
                    }
                }
            },
        ),
    );
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let listener = rt
        .block_on(async { tokio::net::UnixListener::bind(&socket) })
        .unwrap();
    let server = std::thread::spawn(move || {
        rt.block_on(async move {
            let _ = tokio::time::timeout(
                Duration::from_secs(60),
                axum::serve(listener, app).into_future(),
            )
            .await;
        })
    });
    let out = Command::new(BIN)
        .arg("--server")
        .arg(format!("unix://{}", socket.display()))
        .args(["get", "rs", "-w"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stdout}{stderr}");
    assert!(stderr.contains("fell 9 changes behind"), "{stderr}");
    let names: Vec<&str> = stdout
        .lines()
        .skip(1)
        .filter_map(|l| l.split_whitespace().next())
        .collect();
    assert_eq!(names, ["first", "first", "relisted", "later"], "{stdout}");
    assert_eq!(
        (lists.load(Ordering::SeqCst), watches.load(Ordering::SeqCst)),
        (2, 2)
    );
    // The server thread ends with its timeout; the test does not wait for it.
    drop(server);
}
