//! The reconciler runtime, kube-runtime style: store changes feed a work queue
//! de-duplicated per object; `reconcile(obj, ctx) -> Action` runs per key; errors
//! requeue with jittered exponential backoff (800 ms → 30 s, reset on success).
//! Reconcilers are not told why they run, so they are idempotent.

pub mod plan;

use std::collections::{HashMap, HashSet};
use std::sync::Arc;
use std::time::Duration;

use configbot_api::backoff::{Backoff, XorShift};
use configbot_manifests::{Kind, Phase};
use serde_json::Value;
use tokio::sync::mpsc;
use tokio::time::Instant;

use crate::metrics::Metrics;
use crate::store::{Store, StoreError};

/// Which object to reconcile.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct ObjectKey {
    pub kind: Kind,
    pub namespace: String,
    pub name: String,
}

/// What to do after a reconcile.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Action {
    /// Wait for the next change.
    AwaitChange,
    /// Run again after this long.
    Requeue(Duration),
}

/// A jittered backoff per key (800 ms → 30 s, ±25 %), each from its own
/// seed so keys that fail together retry apart.
#[derive(Debug, Clone)]
pub struct Backoffs {
    initial: Duration,
    max: Duration,
    by_key: HashMap<ObjectKey, Backoff>,
    seeds: XorShift,
}

impl Backoffs {
    pub fn new(initial: Duration, max: Duration) -> Backoffs {
        Backoffs {
            initial,
            max,
            by_key: HashMap::new(),
            seeds: XorShift::default(),
        }
    }

    /// The delay before the next retry of `key`: doubling from `initial` up to `max`, ±25 % jitter.
    pub fn next_delay(&mut self, key: &ObjectKey) -> Duration {
        let (initial, max, seeds) = (self.initial, self.max, &mut self.seeds);
        self.by_key
            .entry(key.clone())
            .or_insert_with(|| {
                Backoff::jittered(initial, max, 0.25, XorShift::new(seeds.next_u64()))
            })
            .next_delay()
    }

    pub fn reset(&mut self, key: &ObjectKey) {
        self.by_key.remove(key);
    }
}

/// Context handed to reconcilers.
#[derive(Debug, Clone)]
pub struct Context {
    pub store: Arc<Store>,
    pub metrics: Arc<Metrics>,
    /// Tuning runners, when the server has a robot attached.
    pub tuning: Option<Arc<crate::tuning::runner::TuningManager>>,
}

/// Reconcile one object; `None` when it was deleted.
pub fn reconcile(key: &ObjectKey, obj: Option<Value>, ctx: &Context) -> Result<Action, StoreError> {
    let Some(obj) = obj else {
        if key.kind == Kind::PerformanceSpec
            && let Some(t) = &ctx.tuning
        {
            t.forget(&key.namespace, &key.name);
        }
        return Ok(Action::AwaitChange);
    };
    let (status, events) = match key.kind {
        Kind::RobotStack => plan::robot_stack_status(&obj, &now()),
        Kind::PerformanceSpec => {
            let stack_name = obj["spec"]["stackRef"]["name"].as_str().unwrap_or("");
            let stack = ctx
                .store
                .get(Kind::RobotStack, &key.namespace, stack_name)?;
            plan::performance_spec_status(&obj, stack.as_ref(), &now())
        }
        // Library entries have no status; the tuning runners read them.
        Kind::ConfigProfile => (None, Vec::new()),
    };
    let phase = status
        .as_ref()
        .or(obj.get("status"))
        .and_then(|s| s["phase"].as_str())
        .map_or(Phase::Pending, Phase::parse);
    if let Some(status) = status {
        let rv = obj["metadata"]["resourceVersion"].as_str();
        ctx.store
            .put_status(key.kind, &key.namespace, &key.name, status, rv)?;
    }
    // A valid spec whose stack exists gets a tuning runner (when a robot is attached).
    if key.kind == Kind::PerformanceSpec
        && let Some(t) = &ctx.tuning
        && !matches!(phase, Phase::Pending | Phase::Invalid)
    {
        t.ensure(&key.namespace, &key.name);
    }
    for e in events {
        ctx.store
            .record_event(&obj, e.type_, &e.reason, &e.message)?;
    }
    Ok(Action::AwaitChange)
}

fn now() -> String {
    crate::store::now_rfc3339()
}

/// Run the controller until the store is dropped: watch changes, queue keys, reconcile.
pub async fn run(ctx: Context) {
    let mut changes = ctx.store.subscribe();
    let (tx, mut rx) = mpsc::unbounded_channel::<(ObjectKey, Instant)>();
    // Initial sync: everything in the store.
    for kind in Kind::ALL {
        if let Ok((objs, _)) = ctx.store.list(kind, None) {
            for o in objs {
                let (namespace, name) = crate::store::key_of(&o);
                let _ = tx.send((
                    ObjectKey {
                        kind,
                        namespace,
                        name,
                    },
                    Instant::now(),
                ));
            }
        }
    }
    let mut backoff = Backoffs::new(Duration::from_millis(800), Duration::from_secs(30));
    let mut queued: HashSet<ObjectKey> = HashSet::new();
    let mut pending: Vec<(ObjectKey, Instant)> = Vec::new();
    loop {
        // Take every key that is due, once each.
        let next_due = pending.iter().map(|(_, t)| *t).min();
        tokio::select! {
            change = changes.recv() => match change {
                Ok(c) => {
                    for key in keys_for_change(&ctx, c.kind, &c.object) {
                        let _ = tx.send((key, Instant::now()));
                    }
                }
                Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => {
                    for kind in Kind::ALL {
                        if let Ok((objs, _)) = ctx.store.list(kind, None) {
                            for o in objs {
                                let (namespace, name) = crate::store::key_of(&o);
                                let _ = tx.send((ObjectKey { kind, namespace, name }, Instant::now()));
                            }
                        }
                    }
                }
                Err(_) => return,
            },
            Some((key, at)) = rx.recv() => {
                if queued.insert(key.clone()) {
                    pending.push((key, at));
                } else if let Some(p) = pending.iter_mut().find(|(k, _)| *k == key) {
                    p.1 = p.1.min(at);
                }
            }
            _ = sleep_until(next_due) => {}
        }
        let now = Instant::now();
        let (due, later): (Vec<_>, Vec<_>) = pending.drain(..).partition(|(_, t)| *t <= now);
        pending = later;
        for (key, _) in due {
            queued.remove(&key);
            let obj = ctx.store.get(key.kind, &key.namespace, &key.name);
            let result = obj.and_then(|o| reconcile(&key, o, &ctx));
            let kind = key.kind.name();
            match result {
                Ok(action) => {
                    ctx.metrics
                        .reconciles
                        .with_label_values(&[kind, "ok"])
                        .inc();
                    backoff.reset(&key);
                    if let Action::Requeue(d) = action {
                        let _ = tx.send((key, Instant::now() + d));
                    }
                }
                Err(e) => {
                    ctx.metrics
                        .reconciles
                        .with_label_values(&[kind, error_label(&e)])
                        .inc();
                    let delay = backoff.next_delay(&key);
                    let _ = tx.send((key, Instant::now() + delay));
                }
            }
        }
    }
}

async fn sleep_until(t: Option<Instant>) {
    match t {
        Some(t) => tokio::time::sleep_until(t).await,
        None => std::future::pending().await,
    }
}

fn error_label(e: &StoreError) -> &'static str {
    match e {
        StoreError::Conflict { .. } | StoreError::Precondition { .. } => "conflict",
        StoreError::NotFound { .. } => "not_found",
        StoreError::AlreadyExists { .. } => "exists",
        StoreError::Db { .. } => "db",
        StoreError::Corrupt(_) => "corrupt",
    }
}

/// The keys a change affects: the object itself, and for a stack every spec naming it.
fn keys_for_change(ctx: &Context, kind: Kind, obj: &Value) -> Vec<ObjectKey> {
    let (namespace, name) = crate::store::key_of(obj);
    let mut keys = vec![ObjectKey {
        kind,
        namespace: namespace.clone(),
        name: name.clone(),
    }];
    if kind == Kind::RobotStack
        && let Ok((specs, _)) = ctx.store.list(Kind::PerformanceSpec, Some(&namespace))
    {
        keys.extend(
            specs
                .iter()
                .filter(|s| s["spec"]["stackRef"]["name"].as_str() == Some(name.as_str()))
                .map(|s| ObjectKey {
                    kind: Kind::PerformanceSpec,
                    namespace: namespace.clone(),
                    name: crate::store::key_of(s).1,
                }),
        );
    }
    keys
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backoff_doubles_with_jitter_and_resets() {
        let key = ObjectKey {
            kind: Kind::RobotStack,
            namespace: "default".into(),
            name: "a".into(),
        };
        let mut b = Backoffs::new(Duration::from_millis(800), Duration::from_secs(30));
        let delays: Vec<Duration> = (0..8).map(|_| b.next_delay(&key)).collect();
        for (i, d) in delays.iter().enumerate() {
            let base = (800.0 * 2f64.powi(i as i32)).min(30_000.0);
            let ms = d.as_millis() as f64;
            assert!(
                ms >= base * 0.75 - 1.0 && ms <= (base * 1.25).min(30_000.0) + 1.0,
                "attempt {i}: {ms} ms vs base {base}"
            );
        }
        assert_eq!(delays[7], delays[7].min(Duration::from_secs(30)));
        b.reset(&key);
        assert!(b.next_delay(&key) <= Duration::from_millis(1000));
        // Keys that fail together draw their jitter apart.
        let others: Vec<Duration> = ["b", "c", "d"]
            .map(|name| {
                let key = ObjectKey {
                    name: name.into(),
                    ..key.clone()
                };
                b.next_delay(&key)
            })
            .into();
        assert!(others.windows(2).any(|w| w[0] != w[1]), "{others:?}");
    }
}
