//! The example stacks load cleanly, and every file under `examples/invalid/`
//! produces exactly the errors written in its `# expect:` lines (a header the
//! file itself carries). Set `CONFIGBOT_UPDATE_EXPECT=1` to rewrite the headers
//! after an intended message change, then review the diff.

use std::fs;
use std::path::{Path, PathBuf};

use configbot_manifests::{Manifest, load, yaml::MAX_INPUT_BYTES};

fn examples_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("examples")
}

#[test]
fn example_stacks_load() {
    let mut kinds = Vec::new();
    let files = fs::read_dir(examples_dir())
        .unwrap()
        .chain(fs::read_dir(examples_dir().join("real")).unwrap());
    for entry in files {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "yaml") {
            let text = fs::read_to_string(&path).unwrap();
            let loaded = load(&path.display().to_string(), &text)
                .unwrap_or_else(|e| panic!("{} should load:\n{e}", path.display()));
            kinds.extend(loaded.into_iter().map(|l| l.manifest.kind()));
        }
    }
    assert_eq!(
        kinds.len(),
        13,
        "three simulated and three real stacks, each with its spec, and a config profile"
    );
}

#[test]
fn example_defaults_are_filled_in() {
    let text = fs::read_to_string(examples_dir().join("basic-nav.yaml")).unwrap();
    let loaded = load("basic-nav.yaml", &text).unwrap();
    let Manifest::PerformanceSpec(p) = &loaded[1].manifest else {
        panic!("second document is the spec")
    };
    assert_eq!(p.spec.monitoring.graph_interval_seconds, 30.0);
    assert_eq!(p.spec.knobs.adaptors.min_topic_rate_hz, 5.0);
    assert!(p.spec.knobs.cpu.fix_core_nodes);
    assert_eq!(p.spec.metrics[0].window_seconds, 1.0);
}

fn expected_lines(text: &str) -> Vec<String> {
    text.lines()
        .take_while(|l| l.starts_with('#'))
        .filter_map(|l| l.strip_prefix("# expect: "))
        .map(str::to_string)
        .collect()
}

#[test]
fn invalid_manifests_give_their_exact_errors() {
    let dir = examples_dir().join("invalid");
    let update = std::env::var_os("CONFIGBOT_UPDATE_EXPECT").is_some();
    let mut files: Vec<_> = fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "yaml"))
        .collect();
    files.sort();
    assert!(files.len() >= 20, "at least 20 invalid examples");
    let mut failures = Vec::new();
    for path in files {
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        let text = fs::read_to_string(&path).unwrap();
        // The `# expect:` header is YAML comments, so the file parses as stored.
        let actual: Vec<String> = match load(&name, &text) {
            Ok(_) => vec!["<loaded without error>".into()],
            Err(e) => e.0.iter().map(ToString::to_string).collect(),
        };
        if update {
            let body: String = text
                .lines()
                .filter(|l| !l.starts_with("# expect: "))
                .map(|l| format!("{l}\n"))
                .collect();
            let header: String = actual.iter().map(|l| format!("# expect: {l}\n")).collect();
            fs::write(&path, format!("{header}{body}")).unwrap();
            continue;
        }
        let expected = expected_lines(&text);
        if expected.is_empty() || actual != expected {
            failures.push(format!(
                "{name}:\n  expected: {expected:#?}\n  actual:   {actual:#?}"
            ));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn oversized_input_is_refused_before_parsing() {
    let big = format!(
        "apiVersion: configbot.dev/v1alpha1\nkind: RobotStack\nmetadata: {{name: big}}\nspec:\n  apps: []\n#{}\n",
        "x".repeat(50 * 1024 * 1024)
    );
    let err = load("big.yaml", &big).unwrap_err();
    assert_eq!(err.0.len(), 1);
    assert_eq!(
        err.to_string(),
        format!(
            "big.yaml: input is {} bytes, more than the {MAX_INPUT_BYTES} byte limit for manifests",
            big.len()
        )
    );
}

#[test]
fn a_good_document_beside_a_bad_one_is_not_accepted() {
    let text = "apiVersion: configbot.dev/v1alpha1\nkind: RobotStack\nmetadata: {name: ok}\nspec:\n  apps:\n    - name: nav\n      core: true\n      nodes: [{name: /nav, run: {command: /bin/true}}]\n---\napiVersion: configbot.dev/v1alpha1\nkind: RobotStack\nmetadata: {name: bad}\nspec:\n  apps: []\n";
    let err = load("mixed.yaml", text).unwrap_err();
    assert_eq!(
        err.to_string(),
        "mixed.yaml:14:9: document 2: spec.apps: a stack needs at least one app"
    );
}
