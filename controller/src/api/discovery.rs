//! Kubernetes discovery documents so stock `kubectl` finds our kinds:
//! `/version`, `/api`, `/api/v1`, `/apis`, `/apis/configbot.dev/v1alpha1`.

use axum::Json;
use configbot_manifests::{API_VERSION, GROUP, Kind, VERSION};
use serde_json::{Value, json};

pub async fn version() -> Json<Value> {
    Json(json!({
        "major": "1", "minor": "32",
        "gitVersion": format!("v1.32.0+configbot-{}", env!("CARGO_PKG_VERSION")),
        "platform": "linux/amd64", "goVersion": "n/a", "compiler": "rustc",
    }))
}

pub async fn core_versions() -> Json<Value> {
    Json(json!({"kind": "APIVersions", "versions": ["v1"],
        "serverAddressByClientCIDRs": [{"clientCIDR": "0.0.0.0/0", "serverAddress": ""}]}))
}

pub async fn core_v1() -> Json<Value> {
    Json(
        json!({"kind": "APIResourceList", "apiVersion": "v1", "groupVersion": "v1", "resources": [
            {"name": "events", "singularName": "event", "namespaced": true, "kind": "Event",
             "verbs": ["get", "list", "watch"], "shortNames": ["ev"]},
            {"name": "namespaces", "singularName": "namespace", "namespaced": false, "kind": "Namespace",
             "verbs": ["get", "list"], "shortNames": ["ns"]},
        ]}),
    )
}

pub async fn groups() -> Json<Value> {
    let gv = json!({"groupVersion": API_VERSION, "version": VERSION});
    Json(
        json!({"kind": "APIGroupList", "apiVersion": "v1", "groups": [
            {"name": GROUP, "versions": [gv], "preferredVersion": gv}
        ]}),
    )
}

pub async fn group() -> Json<Value> {
    let gv = json!({"groupVersion": API_VERSION, "version": VERSION});
    Json(
        json!({"kind": "APIGroup", "apiVersion": "v1", "name": GROUP, "versions": [gv], "preferredVersion": gv}),
    )
}

pub async fn resources() -> Json<Value> {
    let mut list = Vec::new();
    for k in Kind::ALL {
        list.push(json!({
            "name": k.plural(), "singularName": k.singular(), "namespaced": true, "kind": k.name(),
            "verbs": ["create", "delete", "get", "list", "patch", "update", "watch"],
            "shortNames": k.short_names(), "categories": ["configbot"],
        }));
        list.push(json!({
            "name": format!("{}/status", k.plural()), "singularName": "", "namespaced": true,
            "kind": k.name(), "verbs": ["get", "patch", "update"],
        }));
    }
    Json(
        json!({"kind": "APIResourceList", "apiVersion": "v1", "groupVersion": API_VERSION, "resources": list}),
    )
}
