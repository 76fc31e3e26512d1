//! Server-side apply (`PATCH` with `application/apply-patch+yaml`,
//! `kubectl apply --server-side`): the body is the manager's whole intent;
//! `managed.rs` merges it and finds conflicts, this handler reads, validates
//! and stores (creating the object when it does not exist).

use axum::Json;
use axum::body::Bytes;
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::IntoResponse;
use configbot_manifests::{Kind, Reason};
use serde_json::Value;

use super::AppState;
use super::managed;
use super::resources::{ApiResult, ListParams, admit};
use super::status::ApiError;
use crate::store::{Mode, StoreError, now_rfc3339};

/// How often an apply reads again after another write landed in between.
const ATTEMPTS: usize = 5;

/// Whether the request is a server-side apply.
pub fn is_apply(headers: &HeaderMap) -> bool {
    headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|ct| {
            ct.split(';').next().unwrap_or("").trim() == "application/apply-patch+yaml"
        })
}

fn applied_config(body: &Bytes) -> ApiResult<Value> {
    let text = std::str::from_utf8(body)
        .map_err(|_| ApiError::BadRequest("apply body is not UTF-8".into()))?;
    let docs = configbot_manifests::yaml::parse_documents(text)
        .map_err(|e| ApiError::BadRequest(format!("invalid YAML apply body: {}", e.message)))?;
    let mut docs = docs.into_iter();
    match (docs.next(), docs.next()) {
        (Some(d), None) if d.value.is_object() => Ok(d.value),
        (Some(_), None) => Err(ApiError::BadRequest(
            "an apply body must be one object".into(),
        )),
        (None, _) => Err(ApiError::BadRequest("empty apply body".into())),
        (Some(_), Some(_)) => Err(ApiError::BadRequest(
            "an apply body must be one object, not several documents".into(),
        )),
    }
}

pub fn server_side_apply(
    s: &AppState,
    kind: Kind,
    ns: &str,
    name: &str,
    p: &ListParams,
    mode: Mode,
    body: &Bytes,
) -> ApiResult {
    let Some(manager) = p.field_manager.as_deref().filter(|m| !m.is_empty()) else {
        return Err(ApiError::BadRequest(
            "fieldManager is required for apply requests (kubectl sends it)".into(),
        ));
    };
    let applied = applied_config(body)?;
    if applied["metadata"].get("managedFields").is_some() {
        return Err(ApiError::BadRequest(
            "metadata.managedFields must not be set in an apply request".into(),
        ));
    }
    let mut attempt = 0;
    loop {
        attempt += 1;
        let live = s.store.get(kind, ns, name)?;
        let mut merged =
            managed::apply(live.as_ref(), &applied, manager, p.force(), &now_rfc3339()).map_err(
                |conflicts| ApiError::ApplyConflict {
                    conflicts: conflicts
                        .into_iter()
                        .map(|c| (c.manager, c.field))
                        .collect(),
                },
            )?;
        let owners = merged["metadata"]["managedFields"].take();
        let mut obj = admit(s, kind, ns, Some(name), merged)?;
        if !owners.is_null() {
            obj["metadata"]["managedFields"] = owners;
        }
        let result = match &live {
            Some(l) => {
                obj["metadata"]["resourceVersion"] = l["metadata"]["resourceVersion"].clone();
                s.store.put_with(kind, obj, false, mode)
            }
            None => s.store.put_with(kind, obj, true, mode),
        };
        match result {
            Err(StoreError::Conflict { .. } | StoreError::AlreadyExists { .. })
                if attempt < ATTEMPTS =>
            {
                continue;
            }
            Err(e) => return Err(e.into()),
            Ok((stored, changed)) => {
                let created = live.is_none();
                if changed && mode == Mode::Commit {
                    let reason = if created {
                        Reason::Created
                    } else {
                        Reason::Updated
                    };
                    let _ = s.store.record_event(
                        &stored,
                        "Normal",
                        &reason,
                        &format!(
                            "{} {} by server-side apply ({manager})",
                            kind.name(),
                            reason.as_str().to_lowercase()
                        ),
                    );
                }
                let code = if created {
                    StatusCode::CREATED
                } else {
                    StatusCode::OK
                };
                return Ok((code, Json(stored)).into_response());
            }
        }
    }
}
