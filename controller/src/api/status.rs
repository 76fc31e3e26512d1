//! API errors as Kubernetes `Status` objects: one enum, one response shape, a
//! message that says what is wrong, and no internals in 5xx bodies.

use axum::Json;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use configbot_manifests::FieldError;
use serde_json::{Value, json};

use crate::store::StoreError;

#[derive(Debug, thiserror::Error)]
pub enum ApiError {
    #[error("{0}")]
    BadRequest(String),
    #[error("{kind} {name:?} is invalid: {summary}")]
    Invalid {
        kind: String,
        name: String,
        summary: String,
        causes: Vec<FieldError>,
    },
    #[error("{0}")]
    NotFound(String),
    #[error("{0}")]
    AlreadyExists(String),
    #[error("{0}")]
    Conflict(String),
    #[error("{}", apply_conflict_message(.conflicts))]
    ApplyConflict {
        /// `(manager, field)` pairs, e.g. `("kubectl", ".spec.robot.model")`.
        conflicts: Vec<(String, String)>,
    },
    #[error("{0}")]
    Gone(String),
    #[error("{0}")]
    UnsupportedMediaType(String),
    #[error("{0}")]
    PayloadTooLarge(String),
    #[error("{0}")]
    RequestTimeout(String),
    #[error("internal error")]
    Internal(String),
}

impl ApiError {
    fn code_reason(&self) -> (StatusCode, &'static str) {
        match self {
            ApiError::BadRequest(_) => (StatusCode::BAD_REQUEST, "BadRequest"),
            ApiError::Invalid { .. } => (StatusCode::UNPROCESSABLE_ENTITY, "Invalid"),
            ApiError::NotFound(_) => (StatusCode::NOT_FOUND, "NotFound"),
            ApiError::AlreadyExists(_) => (StatusCode::CONFLICT, "AlreadyExists"),
            ApiError::Conflict(_) | ApiError::ApplyConflict { .. } => {
                (StatusCode::CONFLICT, "Conflict")
            }
            ApiError::Gone(_) => (StatusCode::GONE, "Expired"),
            ApiError::UnsupportedMediaType(_) => {
                (StatusCode::UNSUPPORTED_MEDIA_TYPE, "UnsupportedMediaType")
            }
            ApiError::PayloadTooLarge(_) => {
                (StatusCode::PAYLOAD_TOO_LARGE, "RequestEntityTooLarge")
            }
            ApiError::RequestTimeout(_) => (StatusCode::REQUEST_TIMEOUT, "Timeout"),
            ApiError::Internal(_) => (StatusCode::INTERNAL_SERVER_ERROR, "InternalError"),
        }
    }

    /// The error for a body that failed decoding or validation.
    pub fn invalid(kind: &str, name: &str, causes: Vec<FieldError>) -> ApiError {
        let summary = causes
            .iter()
            .map(|c| {
                if c.path.is_empty() {
                    c.message.clone()
                } else {
                    format!("{}: {}", c.path, c.message)
                }
            })
            .collect::<Vec<_>>()
            .join("; ");
        ApiError::Invalid {
            kind: kind.into(),
            name: name.into(),
            summary,
            causes,
        }
    }
}

/// "Apply failed with 2 conflicts: conflict with "a": .spec.x; ...", as the apiserver words it.
fn apply_conflict_message(conflicts: &[(String, String)]) -> String {
    let list: Vec<String> = conflicts
        .iter()
        .map(|(m, f)| format!("conflict with {m:?}: {f}"))
        .collect();
    let n = conflicts.len();
    format!(
        "Apply failed with {n} conflict{}: {}",
        if n == 1 { "" } else { "s" },
        list.join("; ")
    )
}

/// A Kubernetes `Status` body.
pub fn status_body(code: StatusCode, reason: &str, message: &str, details: Value) -> Value {
    json!({
        "kind": "Status", "apiVersion": "v1", "metadata": {},
        "status": if code.is_success() { "Success" } else { "Failure" },
        "message": message, "reason": reason, "details": details, "code": code.as_u16(),
    })
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let (code, reason) = self.code_reason();
        let details = match &self {
            ApiError::Invalid {
                kind, name, causes, ..
            } => json!({
                "name": name, "kind": kind,
                "causes": causes.iter().map(|c| json!({"reason": "FieldValueInvalid", "field": c.path, "message": c.message})).collect::<Vec<_>>(),
            }),
            ApiError::ApplyConflict { conflicts } => json!({
                "causes": conflicts.iter().map(|(m, f)| json!({"reason": "FieldManagerConflict", "message": format!("conflict with {m:?}"), "field": f})).collect::<Vec<_>>(),
            }),
            _ => json!({}),
        };
        if let ApiError::Internal(detail) = &self {
            tracing::error!(%detail, "internal error answered as 500");
        }
        (
            code,
            Json(status_body(code, reason, &self.to_string(), details)),
        )
            .into_response()
    }
}

impl From<StoreError> for ApiError {
    fn from(e: StoreError) -> Self {
        match e {
            StoreError::NotFound { .. } => ApiError::NotFound(e.to_string()),
            StoreError::AlreadyExists { .. } => ApiError::AlreadyExists(e.to_string()),
            StoreError::Conflict { .. } | StoreError::Precondition { .. } => {
                ApiError::Conflict(e.to_string())
            }
            StoreError::Db { .. } | StoreError::Corrupt(_) => ApiError::Internal(e.to_string()),
        }
    }
}
