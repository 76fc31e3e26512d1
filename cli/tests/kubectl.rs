//! Stock `kubectl` against a real `configbot serve` over HTTPS: the verbs
//! and flags of issue 15 (server dry run, JSON patch, unchanged re-apply),
//! each checked by what kubectl prints and what the server then holds.

mod common;

use std::path::Path;
use std::process::Stdio;
use std::time::Duration;

use common::{Kube, Lines, example};
use configbot_test_support::{ChildGuard, wait_until};

/// `--dry-run=server` on create, update (apply, label, patch, replace,
/// server-side apply) and delete reports what would happen and changes nothing.
#[test]
fn server_dry_run_changes_nothing() {
    let k = Kube::start();
    let file = example("basic-nav");
    let out = k.ok(&["apply", "-f", &file, "--dry-run=server"]);
    assert!(
        out.contains("robotstack.configbot.dev/basic-nav created (server dry run)"),
        "{out}"
    );
    assert_eq!(
        k.object("rs", "basic-nav"),
        None,
        "dry-run apply created it"
    );

    k.ok(&["apply", "-f", &file]);
    let before = k.object("rs", "basic-nav").unwrap();
    let out = k.ok(&["label", "rs", "basic-nav", "x=y", "--dry-run=server"]);
    assert!(out.contains("labeled (server dry run)"), "{out}");
    let out = k.ok(&[
        "patch",
        "rs",
        "basic-nav",
        "--type=merge",
        "-p",
        r#"{"spec":{"robot":{"model":"jackal"}}}"#,
        "--dry-run=server",
    ]);
    // (kubectl patch names no dry run in its output; the request has dryRun=All.)
    assert!(out.contains("basic-nav patched"), "{out}");
    let jackal = k.dir.path().join("jackal.yaml");
    std::fs::write(
        &jackal,
        std::fs::read_to_string(&file)
            .unwrap()
            .replace("model: spot", "model: jackal"),
    )
    .unwrap();
    let jackal = jackal.to_str().unwrap();
    let out = k.ok(&["replace", "-f", jackal, "--dry-run=server"]);
    assert!(out.contains("replaced (server dry run)"), "{out}");
    // (The model is kubectl-client-side-apply's field: taking it needs force.)
    let out = k.ok(&[
        "apply",
        "--server-side",
        "--force-conflicts",
        "-f",
        jackal,
        "--dry-run=server",
    ]);
    assert!(out.contains("serverside-applied (server dry run)"), "{out}");
    let out = k.ok(&["delete", "rs", "basic-nav", "--dry-run=server"]);
    assert!(
        out.contains(r#"robotstack.configbot.dev "basic-nav" deleted (server dry run)"#),
        "{out}"
    );
    let out = k.ok(&["delete", "-f", &file, "--dry-run=server"]);
    assert!(out.contains("deleted (server dry run)"), "{out}");
    let after = k
        .object("rs", "basic-nav")
        .expect("a dry-run delete deleted the stack");
    assert_eq!(
        after["metadata"]["resourceVersion"],
        before["metadata"]["resourceVersion"]
    );
    assert_eq!(after["spec"], before["spec"]);
    assert!(k.object("pspec", "basic-nav").is_some());

    let out = k.ok(&["delete", "rs", "basic-nav"]);
    assert!(out.contains("deleted"), "{out}");
    assert_eq!(k.object("rs", "basic-nav"), None);
}

/// `kubectl patch --type json`: operations apply in order, a failing `test`
/// applies nothing and names the field, validation still runs.
#[test]
fn json_patch_with_test_ops() {
    let k = Kube::start();
    k.ok(&["apply", "-f", &example("basic-nav")]);
    let out = k.ok(&[
        "patch",
        "rs",
        "basic-nav",
        "--type",
        "json",
        "-p",
        r#"[{"op":"test","path":"/spec/robot/model","value":"spot"},
            {"op":"replace","path":"/spec/robot/model","value":"jackal"},
            {"op":"add","path":"/metadata/labels/site","value":"lab"}]"#,
    ]);
    assert!(
        out.contains("robotstack.configbot.dev/basic-nav patched"),
        "{out}"
    );
    let obj = k.object("rs", "basic-nav").unwrap();
    assert_eq!(obj["spec"]["robot"]["model"], "jackal");
    assert_eq!(obj["metadata"]["labels"]["site"], "lab");
    assert_eq!(obj["metadata"]["generation"], 2);

    // The test fails (the model is jackal now): the replace before it is not kept.
    let (ok, out, err) = k.run(&[
        "patch",
        "rs",
        "basic-nav",
        "--type=json",
        "-p",
        r#"[{"op":"replace","path":"/metadata/labels/site","value":"moon"},
            {"op":"test","path":"/spec/robot/model","value":"spot"}]"#,
    ]);
    assert!(!ok, "{out}");
    assert!(
        err.contains("spec.robot.model") && err.contains("test failed"),
        "{err}"
    );
    let after = k.object("rs", "basic-nav").unwrap();
    assert_eq!(after["metadata"]["labels"]["site"], "lab");
    assert_eq!(
        after["metadata"]["resourceVersion"],
        obj["metadata"]["resourceVersion"]
    );

    // A patch that makes the object invalid is refused by validation.
    let (ok, _, err) = k.run(&[
        "patch",
        "rs",
        "basic-nav",
        "--type=json",
        "-p",
        r#"[{"op":"add","path":"/spec/colour","value":"red"}]"#,
    ]);
    assert!(!ok && err.contains("colour"), "{err}");

    let (ok, _, err) = k.run(&[
        "patch",
        "rs",
        "basic-nav",
        "--type=json",
        "-p",
        r#"[{"op":"remove","path":"/spec/apps/9"}]"#,
    ]);
    assert!(!ok && err.contains("out of bounds"), "{err}");
}

/// Runs the `configbot` CLI against the server's Unix socket; its output.
fn configbot(k: &Kube, args: &[&str]) -> String {
    let (ok, out, err) = common::cli(k.dir.path(), args);
    let text = out + &err;
    assert!(ok, "configbot {args:?}:\n{text}");
    text
}

/// A second `kubectl apply` (and `configbot apply`) of unchanged files says
/// "unchanged" for every object and moves neither resourceVersion nor
/// generation; a no-op patch is "(no change)".
#[test]
fn reapply_of_unchanged_files_is_unchanged() {
    let k = Kube::start();
    let files = ["basic-nav", "intermed-nav", "terrain-nav"].map(example);
    let mut args = vec!["apply"];
    for f in &files {
        args.extend(["-f", f.as_str()]);
    }
    let first = k.ok(&args);
    assert_eq!(first.matches(" created").count(), 6, "{first}");
    let before = k.object("rs", "basic-nav").unwrap();
    let again = k.ok(&args);
    assert_eq!(again.matches(" unchanged").count(), 6, "{again}");
    assert!(!again.contains("configured"), "{again}");
    let after = k.object("rs", "basic-nav").unwrap();
    assert_eq!(after["metadata"], before["metadata"]);
    let out = k.ok(&[
        "patch",
        "rs",
        "basic-nav",
        "--type=merge",
        "-p",
        r#"{"spec":{"robot":{"model":"spot"}}}"#,
    ]);
    assert!(out.contains("patched (no change)"), "{out}");

    // configbot apply replaces kubectl's annotation once, then is unchanged.
    let mut args = vec!["apply"];
    for f in &files {
        args.extend(["-f", f.as_str()]);
    }
    configbot(&k, &args);
    let again = configbot(&k, &args);
    assert_eq!(again.matches(" unchanged").count(), 6, "{again}");
    assert!(!again.contains("configured"), "{again}");
}

/// `kubectl apply --server-side`: creates, records the manager's fields, a
/// second manager setting one of them to another value gets a 409 naming the
/// field, `--force-conflicts` takes it, and a field the first manager stops
/// applying is removed.
#[test]
fn server_side_apply_with_conflicts() {
    let k = Kube::start();
    let file = example("basic-nav");
    let out = k.ok(&["apply", "--server-side", "-f", &file]);
    assert!(
        out.contains("robotstack.configbot.dev/basic-nav serverside-applied"),
        "{out}"
    );
    let managers = |k: &Kube| -> Vec<(String, String)> {
        let out = k.ok(&[
            "get",
            "rs",
            "basic-nav",
            "-o",
            "json",
            "--show-managed-fields",
        ]);
        let obj: serde_json::Value = serde_json::from_str(&out).unwrap();
        obj["metadata"]["managedFields"]
            .as_array()
            .unwrap()
            .iter()
            .map(|e| {
                (
                    e["manager"].as_str().unwrap().to_string(),
                    e["fieldsV1"].to_string(),
                )
            })
            .collect()
    };
    let first = managers(&k);
    assert_eq!(first.len(), 1, "{first:?}");
    assert_eq!(first[0].0, "kubectl");
    assert!(first[0].1.contains(r#""f:model":{}"#), "{first:?}");
    let rv = k.object("rs", "basic-nav").unwrap()["metadata"]["resourceVersion"].clone();
    k.ok(&["apply", "--server-side", "-f", &file]);
    assert_eq!(
        k.object("rs", "basic-nav").unwrap()["metadata"]["resourceVersion"],
        rv,
        "a no-op server-side apply wrote"
    );

    let text = std::fs::read_to_string(&file).unwrap();
    assert!(text.contains("model: spot"), "the example changed: {text}");
    let other = k.dir.path().join("jackal.yaml");
    std::fs::write(&other, text.replace("model: spot", "model: jackal")).unwrap();
    let other = other.to_str().unwrap();
    let (ok, out, err) = k.run(&[
        "apply",
        "--server-side",
        "--field-manager=fleet",
        "-f",
        other,
    ]);
    assert!(!ok, "{out}");
    assert!(
        err.contains(r#"conflict with "kubectl": .spec.robot.model"#),
        "{err}"
    );
    assert_eq!(
        k.object("rs", "basic-nav").unwrap()["spec"]["robot"]["model"],
        "spot"
    );
    k.ok(&[
        "apply",
        "--server-side",
        "--field-manager=fleet",
        "--force-conflicts",
        "-f",
        other,
    ]);
    assert_eq!(
        k.object("rs", "basic-nav").unwrap()["spec"]["robot"]["model"],
        "jackal"
    );
    let owners = managers(&k);
    let kubectl = &owners.iter().find(|(m, _)| m == "kubectl").unwrap().1;
    let fleet = &owners.iter().find(|(m, _)| m == "fleet").unwrap().1;
    assert!(
        !kubectl.contains("f:model") && fleet.contains("f:model"),
        "{owners:?}"
    );

    // fleet stops applying the robot's cpus; kubectl still applies them, so they stay.
    let cpus_line = text
        .lines()
        .find(|l| l.trim_start().starts_with("cpus:"))
        .expect("basic-nav sets robot.cpus");
    let fewer = k.dir.path().join("fewer.yaml");
    std::fs::write(
        &fewer,
        text.replace("model: spot", "model: jackal")
            .replace(&format!("{cpus_line}\n"), ""),
    )
    .unwrap();
    k.ok(&[
        "apply",
        "--server-side",
        "--field-manager=fleet",
        "-f",
        fewer.to_str().unwrap(),
    ]);
    assert!(k.object("rs", "basic-nav").unwrap()["spec"]["robot"]["cpus"].is_number());
}

/// `kubectl diff`: nothing to show (exit 0) for the stored file, a unified
/// diff of the changed field and exit 1 for a changed one, and the server
/// (a dry-run patch) keeps what it had.
#[test]
fn diff_shows_changes_and_exits_1() {
    let k = Kube::start();
    let file = example("basic-nav");
    k.ok(&["apply", "-f", &file]);
    let before = k.object("rs", "basic-nav").unwrap();
    let (ok, out, err) = k.run(&["diff", "-f", &file]);
    assert!(
        ok && out.is_empty(),
        "an unchanged file differs:\n{out}{err}"
    );

    let changed = k.dir.path().join("jackal.yaml");
    let text = std::fs::read_to_string(&file).unwrap();
    assert!(text.contains("model: spot"), "the example changed: {text}");
    std::fs::write(&changed, text.replace("model: spot", "model: jackal")).unwrap();
    let out = k
        .command()
        .args(["diff", "-f", changed.to_str().unwrap()])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(
        out.status.code(),
        Some(1),
        "kubectl diff of a change: {text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        text.contains("-    model: spot") && text.contains("+    model: jackal"),
        "{text}"
    );
    // Only the RobotStack changed; the PerformanceSpec of the file is the same.
    assert!(text.contains("RobotStack.default.basic-nav"), "{text}");
    assert!(
        !text.contains("PerformanceSpec.default.basic-nav"),
        "{text}"
    );
    let after = k.object("rs", "basic-nav").unwrap();
    assert_eq!(after["metadata"], before["metadata"]);
    assert_eq!(after["spec"], before["spec"]);
}

/// `kubectl edit` with a non-interactive editor: a change is saved (new
/// generation), no change is "Edit cancelled", and an edit the server refuses
/// is reported with the field and stores nothing.
#[test]
fn edit_with_a_scripted_editor() {
    let k = Kube::start();
    k.ok(&["apply", "-f", &example("basic-nav")]);
    let script = |name: &str, sed: &str| -> String {
        let p = k.dir.path().join(name);
        std::fs::write(&p, format!("#!/bin/sh\nexec sed -i '{sed}' \"$1\"\n")).unwrap();
        std::fs::set_permissions(&p, std::os::unix::fs::PermissionsExt::from_mode(0o755)).unwrap();
        p.display().to_string()
    };
    let edit = |editor: &str| {
        let out = k
            .command()
            .env("KUBE_EDITOR", editor)
            .env("TMPDIR", k.dir.path())
            .args(["edit", "rs", "basic-nav"])
            .output()
            .unwrap();
        (
            out.status.success(),
            format!(
                "{}{}",
                String::from_utf8_lossy(&out.stdout),
                String::from_utf8_lossy(&out.stderr)
            ),
        )
    };
    let (ok, out) = edit(&script("jackal.sh", "s/model: spot/model: jackal/"));
    assert!(ok, "{out}");
    assert!(
        out.contains("robotstack.configbot.dev/basic-nav edited"),
        "{out}"
    );
    let obj = k.object("rs", "basic-nav").unwrap();
    assert_eq!(obj["spec"]["robot"]["model"], "jackal");
    assert_eq!(obj["metadata"]["generation"], 2);

    let (ok, out) = edit("true");
    assert!(
        ok && out.contains("Edit cancelled, no changes made"),
        "{out}"
    );

    let (ok, out) = edit(&script(
        "colour.sh",
        "s/^    model: jackal$/    model: jackal\\n    colour: red/",
    ));
    assert!(!ok, "{out}");
    assert!(out.contains("is invalid"), "{out}");
    // kubectl keeps the refused edit, with the server's causes on top. It
    // may also leave the buffer it handed the editor, so look at every copy
    // (directory order is arbitrary).
    let kept: Vec<String> = std::fs::read_dir(k.dir.path())
        .unwrap()
        .filter_map(Result::ok)
        .filter(|e| e.file_name().to_string_lossy().starts_with("kubectl-edit-"))
        .map(|e| std::fs::read_to_string(e.path()).unwrap())
        .collect();
    assert!(!kept.is_empty(), "no copy of the refused edit: {out}");
    assert!(
        kept.iter()
            .any(|c| c.contains("# * spec.robot.colour: unknown field")),
        "{kept:#?}"
    );
    let after = k.object("rs", "basic-nav").unwrap();
    assert_eq!(
        after["metadata"]["resourceVersion"],
        obj["metadata"]["resourceVersion"]
    );
}

/// `kubectl explain` reads the OpenAPI v3 document: both kinds, their short
/// names and plurals, and nested fields with their descriptions and types.
#[test]
fn explain_kinds_and_nested_fields() {
    let k = Kube::start();
    for (what, kind) in [
        ("robotstacks", "RobotStack"),
        ("rs", "RobotStack"),
        ("performancespecs", "PerformanceSpec"),
        ("pspec", "PerformanceSpec"),
    ] {
        let out = k.ok(&["explain", what]);
        assert!(
            out.contains(&format!("KIND:       {kind}"))
                && out.contains("GROUP:      configbot.dev")
                && out.contains("VERSION:    v1alpha1")
                && out.contains("spec\t<Object> -required-")
                && out.contains("status\t<Object>"),
            "kubectl explain {what}:\n{out}"
        );
    }
    let out = k.ok(&["explain", "robotstacks.spec.apps"]);
    assert!(
        out.contains("FIELD: apps <[]Object>")
            && out.contains("name\t<string> -required-")
            && out.contains("nodes\t<[]Object> -required-")
            && out.contains("core\t<boolean>"),
        "{out}"
    );
    let out = k.ok(&["explain", "pspec.spec.knobs.cpu.min"]);
    assert!(
        out.contains("FIELD: min <number>") && out.contains("in CPUs"),
        "{out}"
    );
    let out = k.ok(&["explain", "rs", "--recursive"]);
    assert!(
        out.contains("cpus\t<integer>") || out.contains("cpus\t<number>"),
        "{out}"
    );
    let (ok, _, err) = k.run(&["explain", "rs.spec.colour"]);
    assert!(!ok && err.contains("colour"), "{err}");
}

/// `n` merge patches of a label of RobotStack `name`, one after another on
/// one connection to the server's Unix socket (a burst kubectl cannot make).
fn label_burst(sock: &Path, name: &str, n: usize) {
    use std::io::{BufRead, BufReader, Read, Write};
    let s = std::os::unix::net::UnixStream::connect(sock).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
    let mut w = s.try_clone().unwrap();
    let mut r = BufReader::new(s);
    for i in 0..n {
        let body = format!(r#"{{"metadata":{{"labels":{{"burst":"{i}"}}}}}}"#);
        write!(
            w,
            "PATCH /apis/configbot.dev/v1alpha1/namespaces/default/robotstacks/{name} HTTP/1.1\r\n\
             Host: localhost\r\nContent-Type: application/merge-patch+json\r\nContent-Length: {}\r\n\r\n{body}",
            body.len()
        )
        .unwrap();
        let mut status = String::new();
        r.read_line(&mut status).unwrap();
        assert!(status.starts_with("HTTP/1.1 200"), "patch {i}: {status}");
        let mut len = 0;
        loop {
            let mut h = String::new();
            r.read_line(&mut h).unwrap();
            if h.trim().is_empty() {
                break;
            }
            if let Some((k, v)) = h.split_once(':')
                && k.eq_ignore_ascii_case("content-length")
            {
                len = v.trim().parse().unwrap();
            }
        }
        assert!(len > 0, "patch {i}: no content-length");
        let mut body = vec![0; len];
        r.read_exact(&mut body).unwrap();
    }
}

/// `kubectl get -w`: the watch shows an update as a MODIFIED event. A
/// watcher that stops reading (SIGSTOP) while thousands of changes happen
/// falls behind: kubectl gets the 410 Expired `Status` as an ERROR event,
/// prints it and ends, as with the apiserver.
#[test]
fn get_watch_sees_updates_and_expiry() {
    let k = Kube::start();
    k.ok(&["apply", "-f", &example("basic-nav")]);
    let mut watch = ChildGuard(
        k.command()
            .args(["get", "rs", "-w", "--output-watch-events"])
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let mut lines = Lines::of(&mut watch.0);
    lines.wait_for("an ADDED line", Duration::from_secs(20), |l| {
        l.starts_with("ADDED") && l.contains("basic-nav")
    });
    k.ok(&["label", "rs", "basic-nav", "seen=yes"]);
    lines.wait_for("a MODIFIED line", Duration::from_secs(20), |l| {
        l.starts_with("MODIFIED") && l.contains("basic-nav")
    });

    // The slow consumer: kubectl stopped, 3500 changes, kubectl goes on.
    let pid = libc::pid_t::try_from(watch.id()).unwrap();
    #[allow(unsafe_code)]
    // SAFETY: kill(2) of the kubectl child this test started.
    unsafe {
        libc::kill(pid, libc::SIGSTOP);
    }
    label_burst(&k.dir.path().join("api.sock"), "basic-nav", 3500);
    #[allow(unsafe_code)]
    // SAFETY: as above.
    unsafe {
        libc::kill(pid, libc::SIGCONT);
    }
    let expired = lines.wait_for("an Expired line", Duration::from_secs(60), |l| {
        l.contains("Expired")
    });
    assert!(
        expired.starts_with("ERROR") && expired.contains("list again"),
        "{expired}"
    );
    let status = wait_until(
        "kubectl to end after the 410",
        Duration::from_secs(20),
        Duration::from_millis(50),
        || watch.0.try_wait().unwrap(),
    );
    assert!(status.success(), "{status}");
}
