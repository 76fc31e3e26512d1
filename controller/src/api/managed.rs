//! Field ownership, pure: `metadata.managedFields` as Kubernetes keeps it,
//! server-side apply (merge a manager's applied configuration, 409 on fields
//! another manager set to other values unless forced, remove fields the
//! manager stopped applying) and the `Update` entries of every other write.
//!
//! A field is a path of object keys to a leaf; lists are atomic (one field),
//! as `x-kubernetes-list-type: atomic` is in Kubernetes.

use std::collections::BTreeSet;

use serde_json::{Map, Value, json};

/// A path of object keys, e.g. `["spec", "robot", "model"]`.
pub type Field = Vec<String>;

/// `.spec.robot.model`, as Kubernetes names fields in conflicts.
pub fn field_name(f: &Field) -> String {
    f.iter().map(|k| format!(".{k}")).collect()
}

/// One field owned by another manager that the applied configuration sets
/// to a different value.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Conflict {
    pub manager: String,
    pub field: String,
}

#[derive(Debug, Clone, PartialEq)]
struct Entry {
    manager: String,
    operation: String,
    api_version: String,
    time: Option<String>,
    fields: BTreeSet<Field>,
}

/// Metadata the server owns, and the object's identity: never a manager's field.
const SERVER_METADATA: [&str; 8] = [
    "name",
    "namespace",
    "uid",
    "resourceVersion",
    "generation",
    "creationTimestamp",
    "deletionTimestamp",
    "managedFields",
];

/// The fields an object (or an applied configuration) sets.
pub fn fields_of(obj: &Value) -> BTreeSet<Field> {
    let mut out = BTreeSet::new();
    let Some(top) = obj.as_object() else {
        return out;
    };
    for (k, v) in top {
        match k.as_str() {
            "apiVersion" | "kind" | "status" => {}
            "metadata" => {
                if let Some(m) = v.as_object() {
                    for (mk, mv) in m {
                        if !SERVER_METADATA.contains(&mk.as_str()) {
                            leaves(mv, &mut vec!["metadata".into(), mk.clone()], &mut out);
                        }
                    }
                }
            }
            _ => leaves(v, &mut vec![k.clone()], &mut out),
        }
    }
    out
}

fn leaves(v: &Value, at: &mut Field, out: &mut BTreeSet<Field>) {
    match v {
        Value::Object(m) if !m.is_empty() => {
            for (k, c) in m {
                at.push(k.clone());
                leaves(c, at, out);
                at.pop();
            }
        }
        _ => {
            out.insert(at.clone());
        }
    }
}

fn value_at<'a>(v: &'a Value, f: &Field) -> Option<&'a Value> {
    f.iter().try_fold(v, |cur, k| cur.as_object()?.get(k))
}

fn set_at(v: &mut Value, f: &Field, value: Value) {
    let mut cur = v;
    for k in f {
        if !cur.is_object() {
            *cur = Value::Object(Map::new());
        }
        let Value::Object(m) = cur else { return };
        cur = m.entry(k.clone()).or_insert(Value::Null);
    }
    *cur = value;
}

/// Remove a field, and the objects it leaves empty.
fn remove_at(v: &mut Value, f: &[String]) {
    let Some((first, rest)) = f.split_first() else {
        return;
    };
    let Some(m) = v.as_object_mut() else { return };
    if rest.is_empty() {
        m.remove(first);
        return;
    }
    if let Some(child) = m.get_mut(first) {
        remove_at(child, rest);
        if child.as_object().is_some_and(Map::is_empty) {
            m.remove(first);
        }
    }
}

/// `FieldsV1`: `{"f:spec": {"f:robot": {"f:model": {}}}}`.
fn encode(fields: &BTreeSet<Field>) -> Value {
    let mut root = Value::Object(Map::new());
    for f in fields {
        let mut cur = &mut root;
        for k in f {
            let Value::Object(m) = cur else { break };
            cur = m.entry(format!("f:{k}")).or_insert_with(|| json!({}));
        }
    }
    root
}

fn decode(v: &Value, at: &mut Field, out: &mut BTreeSet<Field>) {
    let children: Vec<(&String, &Value)> = v
        .as_object()
        .into_iter()
        .flatten()
        .filter(|(k, _)| k.starts_with("f:"))
        .collect();
    if children.is_empty() {
        if !at.is_empty() {
            out.insert(at.clone());
        }
        return;
    }
    for (k, c) in children {
        at.push(k[2..].to_string());
        decode(c, at, out);
        at.pop();
    }
}

fn read_entries(obj: &Value) -> Vec<Entry> {
    obj["metadata"]["managedFields"]
        .as_array()
        .into_iter()
        .flatten()
        .map(|e| {
            let mut fields = BTreeSet::new();
            decode(&e["fieldsV1"], &mut Vec::new(), &mut fields);
            Entry {
                manager: e["manager"].as_str().unwrap_or("").to_string(),
                operation: e["operation"].as_str().unwrap_or("Update").to_string(),
                api_version: e["apiVersion"].as_str().unwrap_or("").to_string(),
                time: e["time"].as_str().map(str::to_string),
                fields,
            }
        })
        .collect()
}

fn write_entries(obj: &mut Value, entries: &[Entry]) {
    let list: Vec<Value> = entries
        .iter()
        .filter(|e| !e.fields.is_empty())
        .map(|e| {
            let mut v = json!({
                "manager": e.manager, "operation": e.operation, "apiVersion": e.api_version,
                "fieldsType": "FieldsV1", "fieldsV1": encode(&e.fields),
            });
            if let Some(t) = &e.time {
                v["time"] = t.clone().into();
            }
            v
        })
        .collect();
    if list.is_empty() {
        if let Some(m) = obj["metadata"].as_object_mut() {
            m.remove("managedFields");
        }
    } else {
        obj["metadata"]["managedFields"] = Value::Array(list);
    }
}

/// Give `fields` to `(manager, operation)`, taking them from every other
/// entry; the entry's time moves only when its set changes.
fn take(
    entries: &mut Vec<Entry>,
    manager: &str,
    operation: &str,
    api_version: &str,
    fields: &BTreeSet<Field>,
    now: &str,
) {
    for e in entries.iter_mut() {
        if !(e.manager == manager && e.operation == operation) {
            e.fields.retain(|f| !fields.contains(f));
        }
    }
    match entries
        .iter_mut()
        .find(|e| e.manager == manager && e.operation == operation)
    {
        Some(e) => {
            let before = e.fields.len();
            e.fields.extend(fields.iter().cloned());
            if e.fields.len() != before {
                e.time = Some(now.to_string());
            }
        }
        None if !fields.is_empty() => entries.push(Entry {
            manager: manager.into(),
            operation: operation.into(),
            api_version: api_version.into(),
            time: Some(now.to_string()),
            fields: fields.clone(),
        }),
        None => {}
    }
    entries.retain(|e| !e.fields.is_empty());
}

/// Record a write that is not an apply (create, update, patch): the fields it
/// changed or added become `manager`'s (`Update`), fields it removed are
/// nobody's. `new` gets the resulting `managedFields`; a write that changes
/// no field leaves them exactly as they were.
pub fn record_update(old: Option<&Value>, new: &mut Value, manager: &str, now: &str) {
    let api_version = new["apiVersion"].as_str().unwrap_or("").to_string();
    let mut entries = old.map(read_entries).unwrap_or_default();
    let new_fields = fields_of(new);
    let old_fields = old.map(fields_of).unwrap_or_default();
    let changed: BTreeSet<Field> = new_fields
        .iter()
        .filter(|f| old.and_then(|o| value_at(o, f)) != value_at(new, f))
        .cloned()
        .collect();
    for e in entries.iter_mut() {
        e.fields.retain(|f| new_fields.contains(f));
    }
    let removed = old_fields.difference(&new_fields).next().is_some();
    if !changed.is_empty() || removed {
        take(&mut entries, manager, "Update", &api_version, &changed, now);
    }
    write_entries(new, &entries);
}

/// Server-side apply of `applied` by `manager` onto `live` (or a new object).
/// Conflicts are fields another manager owns that `applied` sets to another
/// value; with `force` they are taken, otherwise nothing is applied.
pub fn apply(
    live: Option<&Value>,
    applied: &Value,
    manager: &str,
    force: bool,
    now: &str,
) -> Result<Value, Vec<Conflict>> {
    let applying = fields_of(applied);
    let mut entries = live.map(read_entries).unwrap_or_default();
    let mut conflicts = Vec::new();
    for e in &entries {
        if e.manager == manager && e.operation == "Apply" {
            continue;
        }
        for f in e.fields.intersection(&applying) {
            let current = live.and_then(|l| value_at(l, f));
            if current != value_at(applied, f) {
                conflicts.push(Conflict {
                    manager: e.manager.clone(),
                    field: field_name(f),
                });
            }
        }
    }
    if !conflicts.is_empty() && !force {
        return Err(conflicts);
    }
    let forced: BTreeSet<Field> = if force {
        entries
            .iter()
            .filter(|e| !(e.manager == manager && e.operation == "Apply"))
            .flat_map(|e| e.fields.intersection(&applying).cloned())
            .filter(|f| live.and_then(|l| value_at(l, f)) != value_at(applied, f))
            .collect()
    } else {
        BTreeSet::new()
    };
    for e in entries.iter_mut() {
        if !(e.manager == manager && e.operation == "Apply") {
            e.fields.retain(|f| !forced.contains(f));
        }
    }
    let mut out = match live {
        Some(l) => l.clone(),
        None => {
            json!({"apiVersion": applied["apiVersion"], "kind": applied["kind"], "metadata": {}})
        }
    };
    for k in ["name", "namespace"] {
        if let Some(v) = applied["metadata"].get(k) {
            out["metadata"][k] = v.clone();
        }
    }
    // Fields this manager applied before and applies no more, that nobody else owns, go.
    let previously: BTreeSet<Field> = entries
        .iter()
        .filter(|e| e.manager == manager && e.operation == "Apply")
        .flat_map(|e| e.fields.iter().cloned())
        .collect();
    for f in previously.difference(&applying) {
        let shared = entries
            .iter()
            .any(|e| !(e.manager == manager && e.operation == "Apply") && e.fields.contains(f));
        if !shared {
            remove_at(&mut out, f);
        }
    }
    for f in &applying {
        if let Some(v) = value_at(applied, f) {
            set_at(&mut out, f, v.clone());
        }
    }
    let api_version = applied["apiVersion"].as_str().unwrap_or("").to_string();
    // The manager's set is exactly what it applies now.
    let changed = previously != applying;
    match entries
        .iter_mut()
        .find(|e| e.manager == manager && e.operation == "Apply")
    {
        Some(e) => {
            if changed || live != Some(&out) {
                e.time = Some(now.to_string());
            }
            e.fields = applying.clone();
        }
        None => entries.push(Entry {
            manager: manager.into(),
            operation: "Apply".into(),
            api_version,
            time: Some(now.to_string()),
            fields: applying.clone(),
        }),
    }
    entries.retain(|e| !e.fields.is_empty());
    write_entries(&mut out, &entries);
    Ok(out)
}

#[cfg(test)]
#[path = "managed_tests.rs"]
mod tests;
