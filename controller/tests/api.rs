//! API tests that drive the router directly (no port). The listeners' access
//! rules and durability across `kill -9` run the built program as a process:
//! `cli/tests/processes.rs`.

use std::sync::Arc;

use axum::body::Body;
use axum::http::{Request, StatusCode};
use configbot_controller::api::{self, AppState};
use configbot_controller::metrics::Metrics;
use configbot_controller::store::Store;
use http_body_util::BodyExt;
use serde_json::{Value, json};
use tower::ServiceExt;

const BASE: &str = "/apis/configbot.dev/v1alpha1/namespaces/default";

fn state() -> (tempfile::TempDir, AppState) {
    let dir = tempfile::tempdir().unwrap();
    let store = Arc::new(Store::open(&dir.path().join("api.db")).unwrap());
    (
        dir,
        AppState {
            store,
            metrics: Arc::new(Metrics::new()),
        },
    )
}

fn stack(name: &str) -> Value {
    json!({"apiVersion": "configbot.dev/v1alpha1", "kind": "RobotStack", "metadata": {"name": name, "labels": {"robot": "spot"}},
           "spec": {"apps": [{"name": "nav", "core": true, "nodes": [{"name": "/nav", "run": {"command": "/bin/true"}}]}]}})
}

async fn call(
    s: &AppState,
    method: &str,
    uri: &str,
    body: Option<Value>,
    ct: &str,
) -> (StatusCode, Value) {
    let req = Request::builder()
        .method(method)
        .uri(uri)
        .header("content-type", ct)
        .body(body.map_or(Body::empty(), |b| Body::from(b.to_string())))
        .unwrap();
    let resp = api::router(s.clone()).oneshot(req).await.unwrap();
    let status = resp.status();
    let bytes = resp.into_body().collect().await.unwrap().to_bytes();
    (
        status,
        serde_json::from_slice(&bytes).unwrap_or(Value::Null),
    )
}

#[tokio::test]
async fn create_get_list_update_delete() {
    let (_d, s) = state();
    let (code, created) = call(
        &s,
        "POST",
        &format!("{BASE}/robotstacks"),
        Some(stack("a")),
        "application/json",
    )
    .await;
    assert_eq!(code, StatusCode::CREATED, "{created}");
    assert_eq!(created["metadata"]["generation"], 1);
    let (code, _) = call(
        &s,
        "POST",
        &format!("{BASE}/robotstacks"),
        Some(stack("a")),
        "application/json",
    )
    .await;
    assert_eq!(code, StatusCode::CONFLICT);
    let (code, list) = call(
        &s,
        "GET",
        &format!("{BASE}/robotstacks?labelSelector=robot%3Dspot"),
        None,
        "application/json",
    )
    .await;
    assert_eq!(code, StatusCode::OK);
    assert_eq!(list["items"].as_array().unwrap().len(), 1);
    let (_, none) = call(
        &s,
        "GET",
        &format!("{BASE}/robotstacks?labelSelector=robot%3Djackal"),
        None,
        "application/json",
    )
    .await;
    assert_eq!(none["items"].as_array().unwrap().len(), 0);
    // Same content again: nothing changes, generation stays.
    let (code, same) = call(
        &s,
        "PUT",
        &format!("{BASE}/robotstacks/a"),
        Some(stack("a")),
        "application/json",
    )
    .await;
    assert_eq!(code, StatusCode::OK);
    assert_eq!(
        same["metadata"]["resourceVersion"],
        created["metadata"]["resourceVersion"]
    );
    // A stale resourceVersion is refused.
    let mut changed = stack("a");
    changed["spec"]["robot"] = json!({"model": "jackal"});
    changed["metadata"]["resourceVersion"] = "999999".into();
    let (code, body) = call(
        &s,
        "PUT",
        &format!("{BASE}/robotstacks/a"),
        Some(changed.clone()),
        "application/json",
    )
    .await;
    assert_eq!(code, StatusCode::CONFLICT);
    assert_eq!(body["reason"], "Conflict");
    // Merge patch bumps generation.
    let (code, patched) = call(
        &s,
        "PATCH",
        &format!("{BASE}/robotstacks/a"),
        Some(json!({"spec": {"robot": {"model": "jackal"}}})),
        "application/merge-patch+json",
    )
    .await;
    assert_eq!(code, StatusCode::OK, "{patched}");
    assert_eq!(patched["metadata"]["generation"], 2);
    let (code, _) = call(
        &s,
        "DELETE",
        &format!("{BASE}/robotstacks/a"),
        None,
        "application/json",
    )
    .await;
    assert_eq!(code, StatusCode::OK);
    let (code, body) = call(
        &s,
        "GET",
        &format!("{BASE}/robotstacks/a"),
        None,
        "application/json",
    )
    .await;
    assert_eq!(
        (code, body["kind"].as_str()),
        (StatusCode::NOT_FOUND, Some("Status"))
    );
}

#[tokio::test]
async fn invalid_bodies_get_a_status_and_store_nothing() {
    let (_d, s) = state();
    let mut bad = stack("bad");
    bad["spec"]["apps"][0]["nodes"][0]["name"] = "/../../etc".into();
    bad["spec"]["apps"][0]["extra"] = true.into();
    let (code, body) = call(
        &s,
        "POST",
        &format!("{BASE}/robotstacks"),
        Some(bad),
        "application/json",
    )
    .await;
    assert_eq!(code, StatusCode::UNPROCESSABLE_ENTITY);
    assert_eq!(body["kind"], "Status");
    assert_eq!(body["reason"], "Invalid");
    assert!(
        body["message"]
            .as_str()
            .unwrap()
            .contains("spec.apps[0].extra: unknown field `extra`"),
        "{body}"
    );
    let (code, body) = call(
        &s,
        "POST",
        &format!("{BASE}/robotstacks"),
        None,
        "application/json",
    )
    .await;
    assert_eq!(code, StatusCode::BAD_REQUEST, "{body}");
    let (code, _) = call(
        &s,
        "PATCH",
        &format!("{BASE}/robotstacks/x"),
        Some(json!({})),
        "application/strategic-merge-patch+json",
    )
    .await;
    assert_eq!(code, StatusCode::UNSUPPORTED_MEDIA_TYPE);
    let huge = json!({"apiVersion": "configbot.dev/v1alpha1", "kind": "RobotStack", "metadata": {"name": "huge"}, "spec": {"apps": [], "pad": "x".repeat(4 << 20)}});
    let (code, body) = call(
        &s,
        "POST",
        &format!("{BASE}/robotstacks"),
        Some(huge),
        "application/json",
    )
    .await;
    assert_eq!(code, StatusCode::PAYLOAD_TOO_LARGE, "{body}");
    assert_eq!(body["kind"], "Status");
    assert!(
        s.store
            .list(configbot_manifests::Kind::RobotStack, None)
            .unwrap()
            .0
            .is_empty(),
        "nothing stored"
    );
}

#[tokio::test]
async fn status_is_a_subresource() {
    let (_d, s) = state();
    call(
        &s,
        "POST",
        &format!("{BASE}/robotstacks"),
        Some(stack("a")),
        "application/json",
    )
    .await;
    let mut with_status = stack("a");
    with_status["status"] = json!({"phase": "Running", "apps": 1, "nodes": 1});
    let (code, body) = call(
        &s,
        "PUT",
        &format!("{BASE}/robotstacks/a/status"),
        Some(with_status),
        "application/json",
    )
    .await;
    assert_eq!(code, StatusCode::OK, "{body}");
    assert_eq!(body["status"]["phase"], "Running");
    assert_eq!(body["metadata"]["generation"], 1);
    // A main-resource write cannot change status.
    let mut sneaky = stack("a");
    sneaky["status"] = json!({"phase": "Hacked"});
    let (_, body) = call(
        &s,
        "PUT",
        &format!("{BASE}/robotstacks/a"),
        Some(sneaky),
        "application/json",
    )
    .await;
    assert_eq!(body["status"]["phase"], "Running");
}

#[tokio::test]
async fn discovery_and_tables_for_kubectl() {
    let (_d, s) = state();
    let (_, groups) = call(&s, "GET", "/apis", None, "application/json").await;
    assert_eq!(groups["groups"][0]["name"], "configbot.dev");
    let (_, res) = call(
        &s,
        "GET",
        "/apis/configbot.dev/v1alpha1",
        None,
        "application/json",
    )
    .await;
    let names: Vec<&str> = res["resources"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["name"].as_str().unwrap())
        .collect();
    assert!(
        names.contains(&"robotstacks") && names.contains(&"performancespecs/status"),
        "{names:?}"
    );
    call(
        &s,
        "POST",
        &format!("{BASE}/robotstacks"),
        Some(stack("a")),
        "application/json",
    )
    .await;
    let req = Request::builder()
        .uri(format!("{BASE}/robotstacks"))
        .header(
            "accept",
            "application/json;as=Table;v=v1;g=meta.k8s.io,application/json",
        )
        .body(Body::empty())
        .unwrap();
    let resp = api::router(s.clone()).oneshot(req).await.unwrap();
    let table: Value =
        serde_json::from_slice(&resp.into_body().collect().await.unwrap().to_bytes()).unwrap();
    assert_eq!(table["kind"], "Table");
    assert_eq!(table["rows"][0]["cells"][0], "a");
    let (_, metrics) = {
        let req = Request::builder()
            .uri("/metrics")
            .body(Body::empty())
            .unwrap();
        let resp = api::router(s.clone()).oneshot(req).await.unwrap();
        (
            0,
            String::from_utf8(
                resp.into_body()
                    .collect()
                    .await
                    .unwrap()
                    .to_bytes()
                    .to_vec(),
            )
            .unwrap(),
        )
    };
    assert!(
        metrics.contains("configbot_api_requests_total"),
        "{metrics}"
    );
}

#[tokio::test]
async fn tcp_requires_the_bearer_token() {
    let (_d, s) = state();
    let app = api::with_token(api::router(s), "s3cret".into());
    for (auth, want) in [
        (None, StatusCode::UNAUTHORIZED),
        (Some("Bearer wrong"), StatusCode::UNAUTHORIZED),
        (Some("Bearer s3cret"), StatusCode::OK),
    ] {
        let mut req = Request::builder().uri("/apis");
        if let Some(a) = auth {
            req = req.header("authorization", a);
        }
        let resp = app
            .clone()
            .oneshot(req.body(Body::empty()).unwrap())
            .await
            .unwrap();
        assert_eq!(resp.status(), want, "{auth:?}");
    }
}

/// `dryRun=All` runs every check of every verb and stores nothing: the
/// object, its resourceVersion and the watchers are as before.
#[tokio::test]
async fn dry_run_is_honoured_on_every_verb() {
    let (_d, s) = state();
    let json = "application/json";
    let obj = format!("{BASE}/robotstacks/a");
    let (code, body) = call(
        &s,
        "POST",
        &format!("{BASE}/robotstacks?dryRun=All"),
        Some(stack("a")),
        json,
    )
    .await;
    assert_eq!(code, StatusCode::CREATED, "{body}");
    assert_eq!(body["metadata"]["name"], "a");
    let (code, _) = call(&s, "GET", &obj, None, json).await;
    assert_eq!(
        code,
        StatusCode::NOT_FOUND,
        "a dry-run create stored the object"
    );

    let (_, created) = call(
        &s,
        "POST",
        &format!("{BASE}/robotstacks"),
        Some(stack("a")),
        json,
    )
    .await;
    let rv = created["metadata"]["resourceVersion"].clone();
    // A dry-run create of an existing object fails as the real one would.
    let (code, _) = call(
        &s,
        "POST",
        &format!("{BASE}/robotstacks?dryRun=All"),
        Some(stack("a")),
        json,
    )
    .await;
    assert_eq!(code, StatusCode::CONFLICT);

    let mut live = s.store.subscribe();
    let mut jackal = stack("a");
    jackal["spec"]["robot"] = json!({"model": "jackal"});
    let (code, body) = call(&s, "PUT", &format!("{obj}?dryRun=All"), Some(jackal), json).await;
    assert_eq!(code, StatusCode::OK, "{body}");
    assert_eq!(body["spec"]["robot"]["model"], "jackal");
    assert_eq!(body["metadata"]["generation"], 2, "the would-be generation");
    assert_eq!(body["metadata"]["resourceVersion"], rv);
    let (code, body) = call(
        &s,
        "PATCH",
        &format!("{obj}?dryRun=All"),
        Some(json!({"metadata": {"labels": {"x": "y"}}})),
        "application/merge-patch+json",
    )
    .await;
    assert_eq!(code, StatusCode::OK, "{body}");
    assert_eq!(body["metadata"]["labels"]["x"], "y");
    let (code, body) = call(
        &s,
        "PUT",
        &format!("{obj}/status?dryRun=All"),
        Some(json!({"status": {"phase": "Accepted"}})),
        json,
    )
    .await;
    assert_eq!(code, StatusCode::OK, "{body}");
    let (code, body) = call(
        &s,
        "PATCH",
        &format!("{obj}/status?dryRun=All"),
        Some(json!({"status": {"phase": "Accepted"}})),
        "application/merge-patch+json",
    )
    .await;
    assert_eq!(code, StatusCode::OK, "{body}");
    // kubectl puts dryRun in a DeleteOptions body; other clients in the query.
    let (code, body) = call(
        &s,
        "DELETE",
        &obj,
        Some(json!({"kind": "DeleteOptions", "apiVersion": "v1", "propagationPolicy": "Background", "dryRun": ["All"]})),
        json,
    )
    .await;
    assert_eq!(code, StatusCode::OK, "{body}");
    let (code, body) = call(&s, "DELETE", &format!("{obj}?dryRun=All"), None, json).await;
    assert_eq!(code, StatusCode::OK, "{body}");
    // A value other than All is refused, not taken for a real write.
    let (code, body) = call(&s, "DELETE", &format!("{obj}?dryRun=Yes"), None, json).await;
    assert_eq!(code, StatusCode::BAD_REQUEST, "{body}");
    assert!(
        body["message"].as_str().unwrap().contains("dryRun"),
        "{body}"
    );

    let (code, now) = call(&s, "GET", &obj, None, json).await;
    assert_eq!(code, StatusCode::OK, "a dry-run delete deleted the object");
    assert_eq!(now, created, "a dry run changed the stored object");
    assert!(
        matches!(
            live.try_recv(),
            Err(tokio::sync::broadcast::error::TryRecvError::Empty)
        ),
        "watchers heard of a dry run"
    );
    assert!(
        !s.store
            .events(None, None, Some("a"))
            .unwrap()
            .iter()
            .any(|e| e.reason != configbot_manifests::Reason::Created),
        "a dry run recorded an event"
    );
}

/// `DeleteOptions.preconditions` are checked in the delete's transaction.
#[tokio::test]
async fn delete_preconditions_are_checked() {
    let (_d, s) = state();
    let json = "application/json";
    let obj = format!("{BASE}/robotstacks/a");
    let (_, created) = call(
        &s,
        "POST",
        &format!("{BASE}/robotstacks"),
        Some(stack("a")),
        json,
    )
    .await;
    let (code, body) = call(
        &s,
        "DELETE",
        &obj,
        Some(json!({"preconditions": {"uid": "not-the-uid"}})),
        json,
    )
    .await;
    assert_eq!(code, StatusCode::CONFLICT, "{body}");
    assert!(
        body["message"].as_str().unwrap().contains("metadata.uid"),
        "{body}"
    );
    let (code, _) = call(&s, "GET", &obj, None, json).await;
    assert_eq!(code, StatusCode::OK);
    let (code, body) = call(
        &s,
        "DELETE",
        &obj,
        Some(json!({"preconditions": {"uid": created["metadata"]["uid"], "resourceVersion": created["metadata"]["resourceVersion"]}})),
        json,
    )
    .await;
    assert_eq!(code, StatusCode::OK, "{body}");
    let (code, _) = call(&s, "GET", &obj, None, json).await;
    assert_eq!(code, StatusCode::NOT_FOUND);
}

/// JSON patch (RFC 6902) on the main resource and on the status subresource:
/// a main-resource patch cannot touch status, a status patch cannot touch
/// the spec, and a patch that pins an old resourceVersion conflicts.
#[tokio::test]
async fn json_patch_on_resource_and_status() {
    let (_d, s) = state();
    let jp = "application/json-patch+json";
    let obj = format!("{BASE}/robotstacks/a");
    let (_, created) = call(
        &s,
        "POST",
        &format!("{BASE}/robotstacks"),
        Some(stack("a")),
        "application/json",
    )
    .await;
    let (code, body) = call(
        &s,
        "PATCH",
        &format!("{obj}/status"),
        Some(json!([
            {"op": "add", "path": "/status", "value": {"phase": "Running", "apps": 1, "nodes": 1}},
            {"op": "replace", "path": "/spec/apps/0/name", "value": "renamed"}
        ])),
        jp,
    )
    .await;
    assert_eq!(code, StatusCode::OK, "{body}");
    assert_eq!(body["status"]["phase"], "Running");
    assert_eq!(
        body["spec"]["apps"][0]["name"], "nav",
        "a status patch changed the spec"
    );
    let (code, body) = call(
        &s,
        "PATCH",
        &obj,
        Some(json!([
            {"op": "test", "path": "/status/phase", "value": "Running"},
            {"op": "replace", "path": "/status/phase", "value": "Hacked"},
            {"op": "move", "from": "/metadata/labels/robot", "path": "/metadata/labels/model"}
        ])),
        jp,
    )
    .await;
    assert_eq!(code, StatusCode::OK, "{body}");
    assert_eq!(
        body["status"]["phase"], "Running",
        "a main-resource patch changed status"
    );
    assert_eq!(body["metadata"]["labels"], json!({"model": "spot"}));
    let (code, body) = call(
        &s,
        "PATCH",
        &obj,
        Some(json!([{"op": "replace", "path": "/metadata/resourceVersion", "value": created["metadata"]["resourceVersion"]},
                    {"op": "add", "path": "/metadata/labels/x", "value": "y"}])),
        jp,
    )
    .await;
    assert_eq!(
        (code, body["reason"].as_str()),
        (StatusCode::CONFLICT, Some("Conflict")),
        "{body}"
    );
    let (code, body) = call(
        &s,
        "PATCH",
        &obj,
        Some(json!([{"op": "test", "path": "/metadata/labels/model", "value": "jackal"}])),
        jp,
    )
    .await;
    assert_eq!(code, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
    assert_eq!(
        body["details"]["causes"][0]["field"],
        "metadata.labels.model"
    );
    let (code, _) = call(&s, "PATCH", &obj, Some(json!({"op": "add"})), jp).await;
    assert_eq!(code, StatusCode::BAD_REQUEST);
    let (code, _) = call(
        &s,
        "PATCH",
        &obj,
        Some(json!({})),
        "application/strategic-merge-patch+json",
    )
    .await;
    assert_eq!(code, StatusCode::UNSUPPORTED_MEDIA_TYPE);
}

/// A watcher that does not read while more changes happen than the live
/// channel holds gets an ERROR event with a 410 Expired Status, then the
/// stream ends (so clients list again instead of missing changes).
#[tokio::test]
async fn a_lagging_watcher_gets_410_expired_and_the_stream_ends() {
    let dir = tempfile::tempdir().unwrap();
    let store = Arc::new(
        Store::open(&dir.path().join("api.db"))
            .unwrap()
            .with_watch_buffer(4),
    );
    let s = AppState {
        store,
        metrics: Arc::new(Metrics::new()),
    };
    call(
        &s,
        "POST",
        &format!("{BASE}/robotstacks"),
        Some(stack("a")),
        "application/json",
    )
    .await;
    let req = Request::builder()
        .uri(format!("{BASE}/robotstacks?watch=true"))
        .body(Body::empty())
        .unwrap();
    let resp = api::router(s.clone()).oneshot(req).await.unwrap();
    assert_eq!(resp.status(), StatusCode::OK);
    // The slow consumer: nothing is read while ten changes happen.
    for i in 0..10 {
        let mut st = stack("a");
        st["spec"]["robot"] = json!({"model": format!("m{i}")});
        let (code, body) = call(
            &s,
            "PUT",
            &format!("{BASE}/robotstacks/a"),
            Some(st),
            "application/json",
        )
        .await;
        assert_eq!(code, StatusCode::OK, "{body}");
    }
    let bytes = tokio::time::timeout(
        std::time::Duration::from_secs(10),
        resp.into_body().collect(),
    )
    .await
    .expect("the lagging watch stream did not end")
    .unwrap()
    .to_bytes();
    let events: Vec<Value> = bytes
        .split(|b| *b == b'\n')
        .filter(|l| !l.is_empty())
        .map(|l| serde_json::from_slice(l).unwrap())
        .collect();
    assert_eq!(events[0]["type"], "ADDED");
    let last = events.last().unwrap();
    assert_eq!(last["type"], "ERROR", "{events:?}");
    assert_eq!(last["object"]["kind"], "Status");
    assert_eq!(last["object"]["code"], 410);
    assert_eq!(last["object"]["reason"], "Expired");
    assert!(
        events[..events.len() - 1]
            .iter()
            .all(|e| e["type"] == "ADDED" || e["type"] == "MODIFIED"),
        "{events:?}"
    );
}

/// A watcher that keeps up gets every change in order and no ERROR.
#[tokio::test]
async fn a_watcher_that_keeps_up_sees_every_change() {
    let dir = tempfile::tempdir().unwrap();
    let store = Arc::new(
        Store::open(&dir.path().join("api.db"))
            .unwrap()
            .with_watch_buffer(4),
    );
    let s = AppState {
        store,
        metrics: Arc::new(Metrics::new()),
    };
    let req = Request::builder()
        .uri(format!("{BASE}/robotstacks?watch=true"))
        .body(Body::empty())
        .unwrap();
    let mut body = api::router(s.clone())
        .oneshot(req)
        .await
        .unwrap()
        .into_body();
    let mut models = Vec::new();
    for i in 0..10 {
        let mut st = stack("a");
        st["spec"]["robot"] = json!({"model": format!("m{i}")});
        let method = if i == 0 { "POST" } else { "PUT" };
        let uri = if i == 0 {
            format!("{BASE}/robotstacks")
        } else {
            format!("{BASE}/robotstacks/a")
        };
        call(&s, method, &uri, Some(st), "application/json").await;
        let frame = tokio::time::timeout(std::time::Duration::from_secs(10), body.frame())
            .await
            .expect("no watch event within 10 s")
            .unwrap()
            .unwrap();
        let ev: Value = serde_json::from_slice(frame.data_ref().unwrap()).unwrap();
        assert_ne!(ev["type"], "ERROR", "{ev}");
        models.push(
            ev["object"]["spec"]["robot"]["model"]
                .as_str()
                .unwrap()
                .to_string(),
        );
    }
    assert_eq!(models, (0..10).map(|i| format!("m{i}")).collect::<Vec<_>>());
}

/// Server-side apply over the router: it needs a field manager, creates the
/// object, and a conflict is a 409 whose causes name manager and field.
#[tokio::test]
async fn server_side_apply_needs_a_manager_and_names_conflicts() {
    let (_d, s) = state();
    let apply = "application/apply-patch+yaml";
    let obj = format!("{BASE}/robotstacks/a");
    let (code, body) = call(&s, "PATCH", &obj, Some(stack("a")), apply).await;
    assert_eq!(code, StatusCode::BAD_REQUEST, "{body}");
    assert!(
        body["message"].as_str().unwrap().contains("fieldManager"),
        "{body}"
    );
    let (code, body) = call(
        &s,
        "PATCH",
        &format!("{obj}?fieldManager=a"),
        Some(stack("a")),
        apply,
    )
    .await;
    assert_eq!(code, StatusCode::CREATED, "{body}");
    assert_eq!(body["metadata"]["managedFields"][0]["manager"], "a");
    // Another writer's PUT records an Update entry for the fields it changed.
    let mut edited = body.clone();
    edited["metadata"]["labels"]["robot"] = "jackal".into();
    let (code, body) = call(
        &s,
        "PUT",
        &format!("{obj}?fieldManager=editor"),
        Some(edited),
        "application/json",
    )
    .await;
    assert_eq!(code, StatusCode::OK, "{body}");
    let managers: Vec<(&str, &str)> = body["metadata"]["managedFields"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| {
            (
                e["manager"].as_str().unwrap(),
                e["operation"].as_str().unwrap(),
            )
        })
        .collect();
    assert_eq!(managers, [("a", "Apply"), ("editor", "Update")]);
    let (code, body) = call(
        &s,
        "PATCH",
        &format!("{obj}?fieldManager=a"),
        Some(stack("a")),
        apply,
    )
    .await;
    assert_eq!(code, StatusCode::CONFLICT, "{body}");
    assert_eq!(
        body["details"]["causes"][0]["field"],
        ".metadata.labels.robot"
    );
    assert_eq!(
        body["details"]["causes"][0]["reason"],
        "FieldManagerConflict"
    );
    assert!(
        body["message"]
            .as_str()
            .unwrap()
            .contains(r#"conflict with "editor""#),
        "{body}"
    );
    let (code, body) = call(
        &s,
        "PATCH",
        &format!("{obj}?fieldManager=a&force=true"),
        Some(stack("a")),
        apply,
    )
    .await;
    assert_eq!(code, StatusCode::OK, "{body}");
    assert_eq!(body["metadata"]["labels"]["robot"], "spot");
    let mut sneaky = stack("a");
    sneaky["metadata"]["managedFields"] = json!([]);
    let (code, _) = call(
        &s,
        "PATCH",
        &format!("{obj}?fieldManager=a"),
        Some(sneaky),
        apply,
    )
    .await;
    assert_eq!(code, StatusCode::BAD_REQUEST);
}
