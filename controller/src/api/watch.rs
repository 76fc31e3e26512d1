//! Watch streams: the current objects (or the logged changes after a
//! `resourceVersion`), then live changes, as newline-delimited JSON
//! `{"type", "object"}` events. A watcher that falls behind the live channel
//! gets an `ERROR` event with a 410 Expired `Status` and the stream ends, as
//! the apiserver does, so kubectl and kube-rs list again instead of missing
//! changes silently.

use std::convert::Infallible;

use axum::body::{Body, Bytes};
use axum::http::{StatusCode, header};
use axum::response::Response;
use futures_util::StreamExt;
use serde_json::{Value, json};
use tokio_stream::wrappers::BroadcastStream;
use tokio_stream::wrappers::errors::BroadcastStreamRecvError;

use super::AppState;
use super::resources::{ApiResult, Filter, table_of};
use super::status::{ApiError, status_body};
use crate::store::{Change, ChangeType};

/// One line of a watch stream.
fn line(type_: &str, object: Value) -> Bytes {
    let mut line = json!({"type": type_, "object": object}).to_string();
    line.push('\n');
    Bytes::from(line)
}

/// The `ERROR` event a watcher gets when it fell `missed` changes behind.
pub fn expired_event(missed: u64) -> Bytes {
    line(
        "ERROR",
        status_body(
            StatusCode::GONE,
            "Expired",
            &format!(
                "the watch fell {missed} changes behind and was closed; list again and watch from the list's resourceVersion"
            ),
            json!({}),
        ),
    )
}

pub(super) fn watch(
    s: AppState,
    filter: Filter,
    from: Option<String>,
    as_table: bool,
) -> ApiResult {
    let live = s.store.subscribe();
    let from_rv = from
        .as_deref()
        .and_then(|v| v.parse::<i64>().ok())
        .filter(|v| *v > 0);
    let (initial, start_rv) = match from_rv {
        Some(rv) => {
            let changes = s
                .store
                .changes_since(rv)?
                .ok_or_else(|| ApiError::Gone(format!("too old resource version: {rv}")))?;
            let last = changes.last().map_or(rv, |c| c.resource_version);
            (changes, last)
        }
        None => {
            let (objs, rv) = s.store.list(filter.kind, filter.namespace.as_deref())?;
            let changes = objs
                .into_iter()
                .map(|o| Change {
                    resource_version: rv,
                    kind: filter.kind,
                    type_: ChangeType::Added,
                    object: o,
                })
                .collect();
            (changes, rv)
        }
    };
    let kind = filter.kind;
    let encode = move |c: &Change| -> Bytes {
        let object = if as_table {
            table_of(
                kind,
                std::slice::from_ref(&c.object),
                &c.resource_version.to_string(),
            )
        } else {
            c.object.clone()
        };
        line(c.type_.as_str(), object)
    };
    let first: Vec<Result<Bytes, Infallible>> = initial
        .iter()
        .filter(|c| filter.admits(c.kind, &c.object))
        .map(|c| Ok(encode(c)))
        .collect();
    // `ended` turns true with the ERROR event; the next poll ends the stream.
    let rest = BroadcastStream::new(live)
        .scan(false, move |ended, c| {
            let step = if *ended {
                None
            } else {
                match c {
                    Ok(c) if c.resource_version > start_rv && filter.admits(c.kind, &c.object) => {
                        Some(Some(encode(&c)))
                    }
                    Ok(_) => Some(None),
                    Err(BroadcastStreamRecvError::Lagged(missed)) => {
                        *ended = true;
                        Some(Some(expired_event(missed)))
                    }
                }
            };
            std::future::ready(step)
        })
        .filter_map(|b| std::future::ready(b.map(Ok::<_, Infallible>)));
    let stream = futures_util::stream::iter(first).chain(rest);
    Response::builder()
        .header(header::CONTENT_TYPE, "application/json")
        .header(header::CACHE_CONTROL, "no-cache")
        .body(Body::from_stream(stream))
        .map_err(|e| ApiError::Internal(e.to_string()))
}
