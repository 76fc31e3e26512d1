//! Kubernetes-style resource handlers: list, get, create, replace, patch (merge
//! and JSON patch, see `patch.rs`), delete, dry runs of every write, the
//! status subresource, watch streams and `Table` output.

use std::collections::BTreeMap;

use axum::Json;
use axum::body::Bytes;
use axum::extract::{Path, Query, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use configbot_manifests::{Kind, Manifest, Reason};
use serde::Deserialize;
use serde_json::{Value, json};

use super::managed;
use super::patch::{Patch, PatchBodyError};
use super::status::{ApiError, status_body};
use super::{AppState, selector::Selector};
use crate::store::{Mode, Preconditions, key_of, now_rfc3339};
use crate::table;

pub(super) type ApiResult<T = Response> = Result<T, ApiError>;

#[derive(Debug, Default, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct ListParams {
    label_selector: Option<String>,
    field_selector: Option<String>,
    watch: Option<String>,
    resource_version: Option<String>,
    dry_run: Option<String>,
    pub(super) field_manager: Option<String>,
    force: Option<String>,
}

impl ListParams {
    /// The writer's field manager: `fieldManager`, else the User-Agent's
    /// program (as the apiserver does), else `unknown`.
    pub(super) fn manager(&self, headers: &HeaderMap) -> String {
        self.field_manager
            .clone()
            .filter(|m| !m.is_empty())
            .or_else(|| {
                headers
                    .get(header::USER_AGENT)
                    .and_then(|v| v.to_str().ok())
                    .and_then(|ua| ua.split('/').next())
                    .filter(|p| !p.is_empty())
                    .map(str::to_string)
            })
            .unwrap_or_else(|| "unknown".into())
    }

    pub(super) fn force(&self) -> bool {
        matches!(self.force.as_deref(), Some("true" | "1"))
    }
}

pub(super) fn kind_of(plural: &str) -> ApiResult<Kind> {
    Kind::from_plural(plural).ok_or_else(|| {
        ApiError::NotFound(format!(
            "the server could not find the requested resource {plural:?}"
        ))
    })
}

fn wants_table(headers: &HeaderMap) -> bool {
    headers
        .get(header::ACCEPT)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|a| a.contains("as=Table"))
}

pub(super) fn table_of(kind: Kind, objs: &[Value], rv: &str) -> Value {
    let now = time::OffsetDateTime::now_utc();
    let mut cols = vec![json!({"name": "Name", "type": "string", "format": "name", "priority": 0})];
    cols.extend(kind.printer_columns().iter().map(|c| {
        json!({"name": c.name, "type": if c.type_ == "number" { "string" } else { c.type_ }, "format": "", "priority": if c.wide { 1 } else { 0 }})
    }));
    cols.push(json!({"name": "Age", "type": "string", "format": "", "priority": 0}));
    let rows: Vec<Value> = objs
        .iter()
        .map(|o| {
            let cells: Vec<Value> = table::row(kind, o, true, false, now)
                .into_iter()
                .enumerate()
                .map(|(i, c)| {
                    // Integer columns stay numbers for kubectl's printer.
                    let col = if i == 0 { None } else { kind.printer_columns().get(i - 1) };
                    match col {
                        Some(c) if c.type_ == "integer" => c.value(o).cloned().unwrap_or(Value::Null),
                        _ => Value::String(c),
                    }
                })
                .collect();
            json!({"cells": cells, "object": {"kind": "PartialObjectMetadata", "apiVersion": "meta.k8s.io/v1", "metadata": o["metadata"]}})
        })
        .collect();
    json!({"kind": "Table", "apiVersion": "meta.k8s.io/v1", "metadata": {"resourceVersion": rv}, "columnDefinitions": cols, "rows": rows})
}

fn field_map(obj: &Value) -> BTreeMap<String, String> {
    let (ns, name) = key_of(obj);
    [
        ("metadata.name".to_string(), name),
        ("metadata.namespace".to_string(), ns),
    ]
    .into()
}

pub(super) struct Filter {
    pub(super) kind: Kind,
    pub(super) namespace: Option<String>,
    labels: Selector,
    fields: Selector,
}

impl Filter {
    fn new(kind: Kind, namespace: Option<String>, p: &ListParams) -> ApiResult<Filter> {
        let parse = |s: &Option<String>| {
            Selector::parse(s.as_deref().unwrap_or("")).map_err(ApiError::BadRequest)
        };
        Ok(Filter {
            kind,
            namespace,
            labels: parse(&p.label_selector)?,
            fields: parse(&p.field_selector)?,
        })
    }
    pub(super) fn admits(&self, kind: Kind, obj: &Value) -> bool {
        kind == self.kind
            && self
                .namespace
                .as_deref()
                .is_none_or(|ns| key_of(obj).0 == ns)
            && self.labels.matches_object(obj)
            && self.fields.matches_fields(&field_map(obj))
    }
}

pub async fn list_all(
    State(s): State<AppState>,
    Path(plural): Path<String>,
    Query(p): Query<ListParams>,
    headers: HeaderMap,
) -> ApiResult {
    list(s, plural, None, p, headers).await
}

pub async fn list_ns(
    State(s): State<AppState>,
    Path((ns, plural)): Path<(String, String)>,
    Query(p): Query<ListParams>,
    headers: HeaderMap,
) -> ApiResult {
    list(s, plural, Some(ns), p, headers).await
}

async fn list(
    s: AppState,
    plural: String,
    ns: Option<String>,
    p: ListParams,
    headers: HeaderMap,
) -> ApiResult {
    let kind = kind_of(&plural)?;
    let filter = Filter::new(kind, ns.clone(), &p)?;
    if matches!(p.watch.as_deref(), Some("true" | "1")) {
        return super::watch::watch(s, filter, p.resource_version, wants_table(&headers));
    }
    let (objs, rv) = s.store.list(kind, ns.as_deref())?;
    let objs: Vec<Value> = objs
        .into_iter()
        .filter(|o| filter.admits(kind, o))
        .collect();
    if wants_table(&headers) {
        return Ok(Json(table_of(kind, &objs, &rv.to_string())).into_response());
    }
    Ok(Json(json!({
        "apiVersion": configbot_manifests::API_VERSION, "kind": format!("{}List", kind.name()),
        "metadata": {"resourceVersion": rv.to_string()}, "items": objs,
    }))
    .into_response())
}

pub async fn get(
    State(s): State<AppState>,
    Path((ns, plural, name)): Path<(String, String, String)>,
    headers: HeaderMap,
) -> ApiResult {
    let kind = kind_of(&plural)?;
    let obj = s.store.get(kind, &ns, &name)?.ok_or_else(|| {
        ApiError::NotFound(format!(
            "{} {name:?} not found in namespace {ns:?}",
            kind.plural()
        ))
    })?;
    if wants_table(&headers) {
        let rv = obj["metadata"]["resourceVersion"]
            .as_str()
            .unwrap_or("")
            .to_string();
        return Ok(Json(table_of(kind, &[obj], &rv)).into_response());
    }
    Ok(Json(obj).into_response())
}

fn parse_body(headers: &HeaderMap, body: &Bytes) -> ApiResult<Value> {
    let ct = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("application/json");
    if ct.contains("yaml") {
        let text = std::str::from_utf8(body)
            .map_err(|_| ApiError::BadRequest("body is not UTF-8".into()))?;
        let docs = configbot_manifests::yaml::parse_documents(text)
            .map_err(|e| ApiError::BadRequest(format!("invalid YAML body: {}", e.message)))?;
        return match docs.into_iter().next() {
            Some(d) => Ok(d.value),
            None => Err(ApiError::BadRequest("empty body".into())),
        };
    }
    serde_json::from_slice(body)
        .map_err(|e| ApiError::BadRequest(format!("invalid JSON body: {e}")))
}

/// Decode and validate an object for `kind` at `ns`/`name` (when the path names one),
/// returning it as the client wrote it. Defaults are not written into the
/// stored object (readers decode it, which fills them in): a default inside a
/// list item would make every `kubectl apply` of an unchanged file compute a
/// non-empty patch (a merge patch replaces whole lists) and say "configured".
pub(super) fn admit(
    s: &AppState,
    kind: Kind,
    ns: &str,
    name: Option<&str>,
    mut obj: Value,
) -> ApiResult<Value> {
    let body_name = obj["metadata"]["name"].as_str().unwrap_or("").to_string();
    if let Some(name) = name
        && !body_name.is_empty()
        && body_name != name
    {
        return Err(ApiError::BadRequest(format!(
            "the name in the body ({body_name:?}) does not match the name in the URL ({name:?})"
        )));
    }
    if let Some(name) = name {
        obj["metadata"]["name"] = name.into();
    }
    match obj["metadata"]["namespace"].as_str() {
        Some(body_ns) if body_ns != ns => {
            return Err(ApiError::BadRequest(format!(
                "the namespace of the object ({body_ns:?}) does not match the namespace of the request ({ns:?})"
            )));
        }
        _ => obj["metadata"]["namespace"] = ns.into(),
    }
    if obj["kind"].as_str() != Some(kind.name()) {
        return Err(ApiError::BadRequest(format!(
            "kind {:?} does not match the resource {:?}",
            obj["kind"],
            kind.plural()
        )));
    }
    let status = obj.as_object_mut().and_then(|o| o.remove("status"));
    // Server-owned: the handler records the write's own managedFields.
    if let Some(m) = obj["metadata"].as_object_mut() {
        m.remove("managedFields");
    }
    let manifest = configbot_manifests::decode_and_validate(&obj)
        .map_err(|c| ApiError::invalid(kind.name(), &body_name, c))?;
    if let Manifest::PerformanceSpec(p) = &manifest
        && let Some(stack) = s.store.get(Kind::RobotStack, ns, &p.spec.stack_ref.name)?
        && let Ok(Manifest::RobotStack(stack)) = configbot_manifests::decode(&stack)
    {
        let errs = configbot_manifests::validate::validate_against_stack(p, &stack);
        if !errs.is_empty() {
            return Err(ApiError::invalid(kind.name(), &body_name, errs));
        }
    }
    if let Some(st) = status {
        obj["status"] = st;
    }
    Ok(obj)
}

/// `dryRun`: absent (store), or `All` (check everything, store nothing).
fn mode_of(dry_run: Option<&str>) -> ApiResult<Mode> {
    match dry_run {
        None | Some("") => Ok(Mode::Commit),
        Some("All") => Ok(Mode::DryRun),
        Some(other) => Err(ApiError::BadRequest(format!(
            "dryRun: unsupported value {other:?}; the only value is \"All\""
        ))),
    }
}

pub(super) fn mode(p: &ListParams) -> ApiResult<Mode> {
    mode_of(p.dry_run.as_deref())
}

pub async fn create(
    State(s): State<AppState>,
    Path((ns, plural)): Path<(String, String)>,
    Query(p): Query<ListParams>,
    headers: HeaderMap,
    body: Bytes,
) -> ApiResult {
    let kind = kind_of(&plural)?;
    let mode = mode(&p)?;
    let mut obj = admit(&s, kind, &ns, None, parse_body(&headers, &body)?)?;
    managed::record_update(None, &mut obj, &p.manager(&headers), &now_rfc3339());
    let (stored, _) = s.store.put_with(kind, obj, true, mode)?;
    if mode == Mode::DryRun {
        return Ok((StatusCode::CREATED, Json(stored)).into_response());
    }
    let _ = s.store.record_event(
        &stored,
        "Normal",
        &Reason::Created,
        &format!("{} created", kind.name()),
    );
    Ok((StatusCode::CREATED, Json(stored)).into_response())
}

pub async fn replace(
    State(s): State<AppState>,
    Path((ns, plural, name)): Path<(String, String, String)>,
    Query(p): Query<ListParams>,
    headers: HeaderMap,
    body: Bytes,
) -> ApiResult {
    let kind = kind_of(&plural)?;
    let mode = mode(&p)?;
    let mut obj = admit(&s, kind, &ns, Some(&name), parse_body(&headers, &body)?)?;
    let old = s.store.get(kind, &ns, &name)?;
    let existed = old.is_some();
    managed::record_update(old.as_ref(), &mut obj, &p.manager(&headers), &now_rfc3339());
    let (stored, changed) = s.store.put_with(kind, obj, false, mode)?;
    if changed && mode == Mode::Commit {
        let reason = if existed {
            Reason::Updated
        } else {
            Reason::Created
        };
        let _ = s.store.record_event(
            &stored,
            "Normal",
            &reason,
            &format!("{} {}", kind.name(), reason.as_str().to_lowercase()),
        );
    }
    Ok((
        if existed {
            StatusCode::OK
        } else {
            StatusCode::CREATED
        },
        Json(stored),
    )
        .into_response())
}

/// How often a patch is read and applied again when another write landed
/// between its read and its write (as the apiserver does for unpinned patches).
const PATCH_ATTEMPTS: usize = 5;

pub(super) fn parse_patch(headers: &HeaderMap, body: &Bytes) -> ApiResult<Patch> {
    let ct = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("");
    Patch::parse(ct, body).map_err(|e| match e {
        PatchBodyError::UnsupportedType(_) => ApiError::UnsupportedMediaType(e.to_string()),
        PatchBodyError::Invalid(_) => ApiError::BadRequest(e.to_string()),
    })
}

/// Read the object, apply `patch` and hand the result to `write` with the
/// resourceVersion it must still have. A patch that sets
/// `metadata.resourceVersion` itself pins it: a conflict is then the
/// client's; otherwise a conflict means "read again", up to [`PATCH_ATTEMPTS`].
fn patch_stored(
    s: &AppState,
    kind: Kind,
    ns: &str,
    name: &str,
    patch: &Patch,
    write: impl Fn(&Value, Value) -> ApiResult<(Value, bool)>,
) -> ApiResult<(Value, bool)> {
    let mut attempt = 0;
    loop {
        attempt += 1;
        let current = s.store.get(kind, ns, name)?.ok_or_else(|| {
            ApiError::NotFound(format!(
                "{} {name:?} not found in namespace {ns:?}",
                kind.plural()
            ))
        })?;
        let mut patched = patch.apply(&current).map_err(|e| {
            ApiError::invalid(
                kind.name(),
                name,
                vec![configbot_manifests::FieldError {
                    path: e.field(),
                    message: e.cause(),
                }],
            )
        })?;
        let current_rv = &current["metadata"]["resourceVersion"];
        let pinned = match &patched["metadata"]["resourceVersion"] {
            Value::Null => false,
            rv => rv != current_rv,
        };
        if !pinned {
            patched["metadata"]["resourceVersion"] = current_rv.clone();
        }
        match write(&current, patched) {
            Err(ApiError::Conflict(_)) if !pinned && attempt < PATCH_ATTEMPTS => continue,
            other => return other,
        }
    }
}

/// PATCH of the main resource: merge patch or JSON patch; status is ignored.
pub async fn patch(
    State(s): State<AppState>,
    Path((ns, plural, name)): Path<(String, String, String)>,
    Query(p): Query<ListParams>,
    headers: HeaderMap,
    body: Bytes,
) -> ApiResult {
    let kind = kind_of(&plural)?;
    let mode = mode(&p)?;
    if super::apply::is_apply(&headers) {
        return super::apply::server_side_apply(&s, kind, &ns, &name, &p, mode, &body);
    }
    let patch = parse_patch(&headers, &body)?;
    let manager = p.manager(&headers);
    let (stored, changed) = patch_stored(&s, kind, &ns, &name, &patch, |current, patched| {
        let rv = patched["metadata"]["resourceVersion"].clone();
        let mut obj = admit(&s, kind, &ns, Some(&name), patched)?;
        obj["metadata"]["resourceVersion"] = rv;
        managed::record_update(Some(current), &mut obj, &manager, &now_rfc3339());
        Ok(s.store.put_with(kind, obj, false, mode)?)
    })?;
    if changed && mode == Mode::Commit {
        let _ = s.store.record_event(
            &stored,
            "Normal",
            &Reason::Updated,
            &format!("{} updated", kind.name()),
        );
    }
    Ok(Json(stored).into_response())
}

/// The parts of a `DeleteOptions` body that the store honours.
#[derive(Debug, Default, Deserialize)]
#[serde(rename_all = "camelCase")]
struct DeleteOptions {
    #[serde(default)]
    dry_run: Vec<String>,
    #[serde(default)]
    preconditions: Option<DeletePreconditions>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(rename_all = "camelCase")]
struct DeletePreconditions {
    uid: Option<String>,
    resource_version: Option<String>,
}

/// kubectl sends `dryRun` in a `DeleteOptions` body; other clients in the query.
pub async fn delete(
    State(s): State<AppState>,
    Path((ns, plural, name)): Path<(String, String, String)>,
    Query(p): Query<ListParams>,
    body: Bytes,
) -> ApiResult {
    let kind = kind_of(&plural)?;
    let opts: DeleteOptions = if body.iter().all(u8::is_ascii_whitespace) {
        DeleteOptions::default()
    } else {
        serde_path_to_error::deserialize(&mut serde_json::Deserializer::from_slice(&body)).map_err(
            |e| {
                ApiError::BadRequest(format!(
                    "invalid DeleteOptions body at {}: {}",
                    e.path(),
                    e.inner()
                ))
            },
        )?
    };
    let mut mode = mode(&p)?;
    for d in &opts.dry_run {
        if mode_of(Some(d))? == Mode::DryRun {
            mode = Mode::DryRun;
        }
    }
    let pre = opts.preconditions.unwrap_or_default();
    let pre = Preconditions {
        uid: pre.uid,
        resource_version: pre.resource_version,
    };
    let obj = s.store.delete_with(kind, &ns, &name, &pre, mode)?;
    if mode == Mode::Commit {
        let _ = s.store.record_event(
            &obj,
            "Normal",
            &Reason::Deleted,
            &format!("{} deleted", kind.name()),
        );
    }
    let details = json!({"name": name, "kind": kind.plural(), "uid": obj["metadata"]["uid"]});
    Ok(Json(status_body(StatusCode::OK, "", "", details)).into_response())
}

pub(super) fn validate_status(kind: Kind, status: &Value) -> ApiResult<()> {
    let r = match kind {
        Kind::RobotStack => {
            serde_path_to_error::deserialize::<_, configbot_manifests::RobotStackStatus>(status)
                .map(|_| ())
        }
        Kind::PerformanceSpec => serde_path_to_error::deserialize::<
            _,
            configbot_manifests::PerformanceSpecStatus,
        >(status)
        .map(|_| ()),
        // A ConfigProfile has no status of its own.
        Kind::ConfigProfile => Ok(()),
    };
    r.map_err(|e| {
        ApiError::invalid(
            kind.name(),
            "",
            vec![configbot_manifests::FieldError {
                path: format!("status.{}", e.path()),
                message: e.into_inner().to_string(),
            }],
        )
    })
}

pub async fn put_status(
    State(s): State<AppState>,
    Path((ns, plural, name)): Path<(String, String, String)>,
    Query(p): Query<ListParams>,
    headers: HeaderMap,
    body: Bytes,
) -> ApiResult {
    let kind = kind_of(&plural)?;
    let mode = mode(&p)?;
    let obj = parse_body(&headers, &body)?;
    let status = obj.get("status").cloned().unwrap_or(Value::Null);
    validate_status(kind, &status)?;
    let rv = obj["metadata"]["resourceVersion"].as_str();
    let (stored, _) = s
        .store
        .put_status_with(kind, &ns, &name, status, rv, mode)?;
    Ok(Json(stored).into_response())
}

/// PATCH of the status subresource: the patch applies to the whole object,
/// and only the resulting status is kept.
pub async fn patch_status(
    State(s): State<AppState>,
    Path((ns, plural, name)): Path<(String, String, String)>,
    Query(p): Query<ListParams>,
    headers: HeaderMap,
    body: Bytes,
) -> ApiResult {
    let kind = kind_of(&plural)?;
    let mode = mode(&p)?;
    let patch = parse_patch(&headers, &body)?;
    let (stored, _) = patch_stored(&s, kind, &ns, &name, &patch, |_, patched| {
        let status = patched.get("status").cloned().unwrap_or(json!({}));
        validate_status(kind, &status)?;
        let rv = patched["metadata"]["resourceVersion"].as_str();
        Ok(s.store
            .put_status_with(kind, &ns, &name, status, rv, mode)?)
    })?;
    Ok(Json(stored).into_response())
}

pub async fn get_status(
    State(s): State<AppState>,
    Path((ns, plural, name)): Path<(String, String, String)>,
) -> ApiResult {
    let kind = kind_of(&plural)?;
    let obj = s
        .store
        .get(kind, &ns, &name)?
        .ok_or_else(|| ApiError::NotFound(format!("{} {name:?} not found", kind.plural())))?;
    Ok(Json(obj).into_response())
}

/// Core v1 events about our objects, for `kubectl describe` and `kubectl get events`.
pub async fn events(
    State(s): State<AppState>,
    ns: Option<Path<String>>,
    Query(p): Query<ListParams>,
) -> ApiResult {
    let ns = ns.map(|Path(n)| n);
    let fields =
        Selector::parse(p.field_selector.as_deref().unwrap_or("")).map_err(ApiError::BadRequest)?;
    let items: Vec<Value> = s
        .store
        .events(ns.as_deref(), None, None)?
        .into_iter()
        .map(|e| {
            json!({
                "apiVersion": "v1", "kind": "Event",
                "metadata": {"name": format!("{}.{}", e.name, e.id), "namespace": e.namespace, "resourceVersion": e.id.to_string(), "creationTimestamp": e.time},
                "involvedObject": {"apiVersion": configbot_manifests::API_VERSION, "kind": e.kind, "name": e.name, "namespace": e.namespace, "uid": e.uid},
                "reason": e.reason, "message": e.message, "type": e.type_, "count": 1,
                "firstTimestamp": e.time, "lastTimestamp": e.time, "source": {"component": "configbot"},
            })
        })
        .filter(|ev| {
            let f: BTreeMap<String, String> = ["name", "namespace", "kind", "uid"]
                .iter()
                .map(|k| (format!("involvedObject.{k}"), ev["involvedObject"][k].as_str().unwrap_or("").to_string()))
                .collect();
            fields.matches_fields(&f)
        })
        .collect();
    Ok(
        Json(json!({"apiVersion": "v1", "kind": "EventList", "metadata": {}, "items": items}))
            .into_response(),
    )
}

pub async fn namespaces() -> Json<Value> {
    Json(
        json!({"apiVersion": "v1", "kind": "NamespaceList", "metadata": {}, "items": [
            {"apiVersion": "v1", "kind": "Namespace", "metadata": {"name": "default"}, "status": {"phase": "Active"}}
        ]}),
    )
}
