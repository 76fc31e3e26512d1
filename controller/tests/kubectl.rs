//! Stock `kubectl` against a real `configbot serve` over HTTPS: the verbs
//! and flags of issue 15 (server dry run, JSON patch, unchanged re-apply),
//! each checked by what kubectl prints and what the server then holds.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_configbot");
const TOKEN: &str = "t0ken-for-kubectl-tests";

/// A private server with an HTTPS listener, and kubectl aimed at it.
struct Kube {
    dir: tempfile::TempDir,
    port: u16,
    kubectl: PathBuf,
    server: Child,
}

impl Drop for Kube {
    fn drop(&mut self) {
        let _ = self.server.kill();
        let _ = self.server.wait();
    }
}

impl Kube {
    fn start() -> Kube {
        let kubectl = which("kubectl").expect("kubectl is not installed; `./x deps` installs it");
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("token"), format!("{TOKEN}\n")).unwrap();
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let server = Command::new(BIN)
            .args(["serve", "--db"])
            .arg(dir.path().join("db"))
            .arg("--socket")
            .arg(dir.path().join("api.sock"))
            .args(["--listen", &format!("127.0.0.1:{port}"), "--token-file"])
            .arg(dir.path().join("token"))
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let deadline = Instant::now() + Duration::from_secs(20);
        while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
            assert!(Instant::now() < deadline, "https listener did not come up");
            std::thread::sleep(Duration::from_millis(20));
        }
        Kube {
            dir,
            port,
            kubectl,
            server,
        }
    }

    /// Runs kubectl; (success, stdout, stderr).
    fn run(&self, args: &[&str]) -> (bool, String, String) {
        let out = Command::new(&self.kubectl)
            .env("KUBECONFIG", self.dir.path().join("kubeconfig"))
            .env("HOME", self.dir.path())
            .args([
                "--server",
                &format!("https://127.0.0.1:{}", self.port),
                "--token",
                TOKEN,
                "--certificate-authority",
            ])
            .arg(self.dir.path().join("tls.crt"))
            .args(args)
            .output()
            .unwrap();
        (
            out.status.success(),
            String::from_utf8_lossy(&out.stdout).into_owned(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    }

    /// Runs kubectl and requires success; its standard output.
    fn ok(&self, args: &[&str]) -> String {
        let (ok, out, err) = self.run(args);
        assert!(ok, "kubectl {args:?} failed:\n{out}{err}");
        out
    }

    /// An object as JSON, or None when the server has no such object.
    fn object(&self, kind: &str, name: &str) -> Option<serde_json::Value> {
        let (ok, out, err) = self.run(&["get", kind, name, "-o", "json"]);
        if !ok {
            assert!(
                err.contains("NotFound") || err.contains("not found"),
                "{err}"
            );
            return None;
        }
        Some(serde_json::from_str(&out).unwrap())
    }
}

fn example(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(format!("../manifests/examples/{name}.yaml"))
        .display()
        .to_string()
}

fn which(name: &str) -> Option<PathBuf> {
    std::env::var_os("PATH")
        .into_iter()
        .flat_map(|p| std::env::split_paths(&p).collect::<Vec<_>>())
        .map(|d| d.join(name))
        .find(|p| p.is_file())
}

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
    let out = Command::new(BIN)
        .arg("--server")
        .arg(format!(
            "unix://{}",
            k.dir.path().join("api.sock").display()
        ))
        .args(args)
        .output()
        .unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "configbot {args:?}:\n{text}");
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
