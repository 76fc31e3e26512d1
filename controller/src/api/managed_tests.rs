//! Server-side apply and field ownership as tables of small objects.

use super::*;

fn obj(spec: Value) -> Value {
    json!({"apiVersion": "configbot.dev/v1alpha1", "kind": "RobotStack",
           "metadata": {"name": "a", "namespace": "default", "uid": "u"}, "spec": spec})
}

fn managers(o: &Value) -> Vec<(String, String, Vec<String>)> {
    read_entries(o)
        .into_iter()
        .map(|e| {
            (
                e.manager,
                e.operation,
                e.fields.iter().map(field_name).collect(),
            )
        })
        .collect()
}

fn owned(manager: &str, op: &str, fields: &[&str]) -> (String, String, Vec<String>) {
    (
        manager.into(),
        op.into(),
        fields.iter().map(|f| f.to_string()).collect(),
    )
}

#[test]
fn fields_are_leaves_with_atomic_lists_and_no_server_metadata() {
    let o = json!({"apiVersion": "v", "kind": "K", "status": {"x": 1},
                   "metadata": {"name": "a", "uid": "u", "labels": {"k": "v"}},
                   "spec": {"apps": [{"name": "x"}], "robot": {"model": "spot", "labels": {}}}});
    let names: Vec<String> = fields_of(&o).iter().map(field_name).collect();
    assert_eq!(
        names,
        [
            ".metadata.labels.k",
            ".spec.apps",
            ".spec.robot.labels",
            ".spec.robot.model"
        ]
    );
    let mut back = BTreeSet::new();
    decode(&encode(&fields_of(&o)), &mut Vec::new(), &mut back);
    assert_eq!(back, fields_of(&o));
}

#[test]
fn apply_creates_then_conflicts_on_another_managers_field_unless_forced() {
    let a = apply(
        None,
        &obj(json!({"robot": {"model": "spot"}, "apps": []})),
        "a",
        false,
        "t1",
    )
    .unwrap();
    assert_eq!(
        managers(&a),
        [owned("a", "Apply", &[".spec.apps", ".spec.robot.model"])]
    );
    assert_eq!(
        a["metadata"]["managedFields"][0]["fieldsV1"],
        json!({"f:spec": {"f:apps": {}, "f:robot": {"f:model": {}}}})
    );

    // Same value: shared, no conflict.
    let b = apply(
        Some(&a),
        &obj(json!({"robot": {"model": "spot"}})),
        "b",
        false,
        "t2",
    )
    .unwrap();
    assert_eq!(
        managers(&b),
        [
            owned("a", "Apply", &[".spec.apps", ".spec.robot.model"]),
            owned("b", "Apply", &[".spec.robot.model"])
        ]
    );
    // Another value: a conflict naming manager and field; nothing applied.
    let err = apply(
        Some(&a),
        &obj(json!({"robot": {"model": "jackal"}})),
        "b",
        false,
        "t2",
    )
    .unwrap_err();
    assert_eq!(
        err,
        [Conflict {
            manager: "a".into(),
            field: ".spec.robot.model".into()
        }]
    );
    // Forced: b takes the field, a keeps the rest.
    let forced = apply(
        Some(&a),
        &obj(json!({"robot": {"model": "jackal"}})),
        "b",
        true,
        "t2",
    )
    .unwrap();
    assert_eq!(forced["spec"]["robot"]["model"], "jackal");
    assert_eq!(
        managers(&forced),
        [
            owned("a", "Apply", &[".spec.apps"]),
            owned("b", "Apply", &[".spec.robot.model"])
        ]
    );
}

#[test]
fn fields_a_manager_stops_applying_are_removed_unless_shared() {
    let a = apply(
        None,
        &obj(json!({"robot": {"model": "spot", "cpus": 2}, "apps": []})),
        "a",
        false,
        "t1",
    )
    .unwrap();
    let a2 = apply(
        Some(&a),
        &obj(json!({"robot": {"model": "spot"}, "apps": []})),
        "a",
        false,
        "t2",
    )
    .unwrap();
    assert_eq!(a2["spec"]["robot"], json!({"model": "spot"}));
    let shared = apply(
        Some(&a),
        &obj(json!({"robot": {"cpus": 2}})),
        "b",
        false,
        "t2",
    )
    .unwrap();
    let a3 = apply(
        Some(&shared),
        &obj(json!({"robot": {"model": "spot"}, "apps": []})),
        "a",
        false,
        "t3",
    )
    .unwrap();
    assert_eq!(a3["spec"]["robot"]["cpus"], 2, "b still applies cpus");
}

#[test]
fn a_no_op_apply_or_update_moves_no_timestamp() {
    let a = apply(
        None,
        &obj(json!({"robot": {"model": "spot"}})),
        "a",
        false,
        "t1",
    )
    .unwrap();
    let again = apply(
        Some(&a),
        &obj(json!({"robot": {"model": "spot"}})),
        "a",
        false,
        "t2",
    )
    .unwrap();
    assert_eq!(again, a);
    let mut same = a.clone();
    record_update(Some(&a), &mut same, "kubectl-edit", "t3");
    assert_eq!(same, a);
}

#[test]
fn updates_take_the_fields_they_change() {
    let a = apply(
        None,
        &obj(json!({"robot": {"model": "spot"}, "apps": []})),
        "a",
        false,
        "t1",
    )
    .unwrap();
    let mut edited = a.clone();
    edited["spec"]["robot"]["model"] = "jackal".into();
    record_update(Some(&a), &mut edited, "kubectl-edit", "t2");
    assert_eq!(
        managers(&edited),
        [
            owned("a", "Apply", &[".spec.apps"]),
            owned("kubectl-edit", "Update", &[".spec.robot.model"])
        ]
    );
    // Now a's apply of the old value conflicts with the edit.
    let err = apply(
        Some(&edited),
        &obj(json!({"robot": {"model": "spot"}, "apps": []})),
        "a",
        false,
        "t3",
    )
    .unwrap_err();
    assert_eq!(
        err,
        [Conflict {
            manager: "kubectl-edit".into(),
            field: ".spec.robot.model".into()
        }]
    );
    let mut created = obj(json!({"apps": []}));
    record_update(None, &mut created, "configbot", "t1");
    assert_eq!(
        managers(&created),
        [owned("configbot", "Update", &[".spec.apps"])]
    );
}
