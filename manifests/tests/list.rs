//! A `v1` `List` document (what `get -o yaml` prints for a list) loads as its
//! items, and an error in an item names `items[N].…` with its line.

use configbot_manifests::load;

const LIST: &str = "\
apiVersion: v1
kind: List
metadata:
  resourceVersion: \"\"
items:
- apiVersion: configbot.dev/v1alpha1
  kind: RobotStack
  metadata: {name: a}
  spec:
    apps: [{name: nav, nodes: [{name: /nav, run: {command: x}}]}]
- apiVersion: configbot.dev/v1alpha1
  kind: RobotStack
  metadata: {name: b}
  spec:
    apps: [{name: nav, nodes: [{name: /nav, run: {command: x}, colour: red}]}]
";

#[test]
fn list_items_load_and_their_errors_are_located() {
    let good = LIST.replace(", colour: red", "");
    let loaded = load("list.yaml", &good).unwrap();
    let names: Vec<_> = loaded
        .iter()
        .map(|l| (l.manifest.metadata().name.clone(), l.path_prefix.clone()))
        .collect();
    assert_eq!(
        names,
        [
            ("a".to_string(), "items[0].".to_string()),
            ("b".to_string(), "items[1].".to_string())
        ]
    );
    assert_eq!(loaded[1].value["metadata"]["name"], "b");

    let errs = load("list.yaml", LIST).unwrap_err();
    assert_eq!(errs.0.len(), 1, "{errs}");
    assert!(
        errs.0[0].path.starts_with("items[1].spec.apps[0].nodes[0]"),
        "{errs}"
    );
    assert_eq!(errs.0[0].line, Some(15), "{errs}");
    assert!(errs.0[0].message.contains("colour"), "{errs}");
}

#[test]
fn an_empty_stream_loads_nothing_and_a_separator_run_on_is_refused() {
    assert!(load("empty.yaml", "---\n---\n").unwrap().is_empty());
    assert!(load("empty.yaml", "").unwrap().is_empty());
    let errs = load("empty.yaml", "--- ---\n").unwrap_err();
    assert!(
        errs.0[0].message.contains("invalid document separator"),
        "{errs}"
    );
    assert_eq!(errs.0[0].line, Some(1));
}
