//! The embedded object store (SQLite): objects with uid, generation and
//! resourceVersion, status as a subresource, a change log that watches resume
//! from, and an event log. Every write is one transaction, so nothing that was
//! acknowledged is lost on `kill -9`.
//!
//! A commit appends to the write-ahead log without waiting for the disk
//! (`synchronous=NORMAL`); a background [`Checkpointer`] with its own
//! connection makes the log durable and folds it into the database every
//! [`CHECKPOINT_EVERY`]. So a slow disk (a commit once waited 32 s on
//! writeback here) delays neither the API nor the tuning loop's remediation;
//! a power cut loses at most that last interval, never consistency.
//!
//! Bodies are JSON objects in Kubernetes shape; validation happens before the
//! store (in the API layer), the store only manages metadata and versions.

use std::path::Path;
use std::sync::Mutex;
use std::sync::mpsc;
use std::time::Duration;

use configbot_manifests::{Kind, Reason};
use rusqlite::{Connection, OptionalExtension, params};
use serde_json::Value;
use tokio::sync::broadcast;

/// Store errors; each maps to one Kubernetes status reason.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("{kind} {namespace}/{name} not found")]
    NotFound {
        kind: Kind,
        namespace: String,
        name: String,
    },
    #[error("{kind} {namespace}/{name} already exists")]
    AlreadyExists {
        kind: Kind,
        namespace: String,
        name: String,
    },
    #[error(
        "{kind} {namespace}/{name} was modified (resourceVersion {current}, request had {given}); read it again and retry"
    )]
    Conflict {
        kind: Kind,
        namespace: String,
        name: String,
        current: String,
        given: String,
    },
    #[error(
        "{kind} {namespace}/{name}: precondition failed: metadata.{field} is {current:?}, the request expected {given:?}"
    )]
    Precondition {
        kind: Kind,
        namespace: String,
        name: String,
        field: &'static str,
        current: String,
        given: String,
    },
    #[error("database {path}: {source}")]
    Db {
        path: String,
        #[source]
        source: rusqlite::Error,
    },
    #[error("stored object is corrupt: {0}")]
    Corrupt(String),
}

pub type Result<T, E = StoreError> = std::result::Result<T, E>;

/// A change to an object, as watches stream it.
#[derive(Debug, Clone, PartialEq)]
pub struct Change {
    pub resource_version: i64,
    pub kind: Kind,
    pub type_: ChangeType,
    pub object: Value,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ChangeType {
    Added,
    Modified,
    Deleted,
}

impl ChangeType {
    pub fn as_str(self) -> &'static str {
        match self {
            ChangeType::Added => "ADDED",
            ChangeType::Modified => "MODIFIED",
            ChangeType::Deleted => "DELETED",
        }
    }
    fn parse(s: &str) -> ChangeType {
        match s {
            "ADDED" => ChangeType::Added,
            "DELETED" => ChangeType::Deleted,
            _ => ChangeType::Modified,
        }
    }
}

/// An event about an object (`kubectl get events` style).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Event {
    pub id: i64,
    pub time: String,
    pub namespace: String,
    pub kind: String,
    pub name: String,
    pub uid: String,
    /// `Normal` or `Warning`.
    pub type_: String,
    pub reason: Reason,
    pub message: String,
}

/// The store. Cheap to share behind an `Arc`.
#[derive(Debug)]
pub struct Store {
    conn: Mutex<Connection>,
    path: String,
    changes: broadcast::Sender<Change>,
    events: broadcast::Sender<Event>,
    /// Stops with the store (dropped last, after the connection).
    _checkpointer: Checkpointer,
}

/// How long a connection waits for another's lock before it fails.
const BUSY_TIMEOUT: Duration = Duration::from_secs(5);

/// How often the [`Checkpointer`] makes committed transactions durable.
pub const CHECKPOINT_EVERY: Duration = Duration::from_secs(1);

/// The log size (pages) at which a commit checkpoints by itself: a backstop
/// should the [`Checkpointer`] fall behind, far above what it leaves.
const AUTOCHECKPOINT_PAGES: u32 = 10_000;

/// A thread with its own connection that runs a passive checkpoint (the
/// log is synced, committed pages copied into the database, which is synced
/// too) every [`CHECKPOINT_EVERY`]; passive, it never blocks a reader or a
/// writer. It stops when dropped.
#[derive(Debug)]
struct Checkpointer {
    stop: Option<mpsc::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Checkpointer {
    fn start(path: &Path) -> rusqlite::Result<Checkpointer> {
        let conn = Connection::open(path)?;
        conn.busy_timeout(BUSY_TIMEOUT)?;
        let (stop, stopped) = mpsc::channel::<()>();
        let thread = std::thread::Builder::new()
            .name("configbot-checkpoint".into())
            .spawn(move || {
                while let Err(mpsc::RecvTimeoutError::Timeout) =
                    stopped.recv_timeout(CHECKPOINT_EVERY)
                {
                    // A failed checkpoint is retried next time; commits go
                    // on in the log meanwhile (and checkpoint themselves
                    // past AUTOCHECKPOINT_PAGES).
                    let _ = conn.query_row("PRAGMA wal_checkpoint(PASSIVE)", [], |_| Ok(()));
                }
            })
            .expect("spawn the store's checkpoint thread");
        Ok(Checkpointer {
            stop: Some(stop),
            thread: Some(thread),
        })
    }
}

impl Drop for Checkpointer {
    fn drop(&mut self) {
        // Closing the channel wakes the thread; it stops without waiting out
        // the interval.
        drop(self.stop.take());
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

const SCHEMA: &str = "
CREATE TABLE IF NOT EXISTS objects (
    kind TEXT NOT NULL, namespace TEXT NOT NULL, name TEXT NOT NULL,
    uid TEXT NOT NULL, resource_version INTEGER NOT NULL, body TEXT NOT NULL,
    PRIMARY KEY (kind, namespace, name));
CREATE TABLE IF NOT EXISTS changes (
    rv INTEGER PRIMARY KEY AUTOINCREMENT, kind TEXT NOT NULL, type TEXT NOT NULL, body TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS events (
    id INTEGER PRIMARY KEY AUTOINCREMENT, time TEXT NOT NULL, namespace TEXT NOT NULL,
    kind TEXT NOT NULL, name TEXT NOT NULL, uid TEXT NOT NULL, type TEXT NOT NULL,
    reason TEXT NOT NULL, message TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS controller_state (
    scope TEXT NOT NULL, key TEXT NOT NULL, body TEXT NOT NULL, PRIMARY KEY (scope, key));
";

/// Live changes (and events) a subscriber may fall behind by before it lags.
const WATCH_BUFFER: usize = 1024;

/// How many change rows are kept for watches to resume from.
const CHANGE_LOG_KEEP: i64 = 10_000;

/// Current time in RFC 3339, second precision, UTC.
pub fn now_rfc3339() -> String {
    let now = time::OffsetDateTime::now_utc()
        .replace_nanosecond(0)
        .unwrap_or(time::OffsetDateTime::UNIX_EPOCH);
    now.format(&time::format_description::well_known::Rfc3339)
        .unwrap_or_default()
}

fn kind_of(s: &str) -> Result<Kind> {
    Kind::from_name(s).ok_or_else(|| StoreError::Corrupt(format!("unknown kind {s:?}")))
}

fn parse_body(s: &str) -> Result<Value> {
    serde_json::from_str(s).map_err(|e| StoreError::Corrupt(e.to_string()))
}

impl Store {
    /// Open (or create) the database at `path`.
    pub fn open(path: &Path) -> Result<Store> {
        let p = path.display().to_string();
        let db = |source| StoreError::Db {
            path: p.clone(),
            source,
        };
        let conn = Connection::open(path).map_err(db)?;
        conn.pragma_update(None, "journal_mode", "WAL")
            .map_err(db)?;
        conn.pragma_update(None, "synchronous", "NORMAL")
            .map_err(db)?;
        conn.pragma_update(None, "wal_autocheckpoint", AUTOCHECKPOINT_PAGES)
            .map_err(db)?;
        conn.busy_timeout(BUSY_TIMEOUT).map_err(db)?;
        conn.execute_batch(SCHEMA).map_err(db)?;
        let checkpointer = Checkpointer::start(path).map_err(db)?;
        Ok(Store {
            conn: Mutex::new(conn),
            path: p,
            changes: broadcast::channel(WATCH_BUFFER).0,
            events: broadcast::channel(WATCH_BUFFER).0,
            _checkpointer: checkpointer,
        })
    }

    /// The same store with room for `n` live changes per watcher before a
    /// slow one is told it fell behind (tests make it small).
    pub fn with_watch_buffer(mut self, n: usize) -> Store {
        self.changes = broadcast::channel(n.max(1)).0;
        self
    }

    fn with<T>(&self, f: impl FnOnce(&mut Connection) -> rusqlite::Result<T>) -> Result<T> {
        let mut conn = self.conn.lock().unwrap_or_else(|p| p.into_inner());
        f(&mut conn).map_err(|source| StoreError::Db {
            path: self.path.clone(),
            source,
        })
    }

    /// Live changes after the moment of subscription.
    pub fn subscribe(&self) -> broadcast::Receiver<Change> {
        self.changes.subscribe()
    }

    /// Live events after the moment of subscription.
    pub fn subscribe_events(&self) -> broadcast::Receiver<Event> {
        self.events.subscribe()
    }

    pub fn get(&self, kind: Kind, namespace: &str, name: &str) -> Result<Option<Value>> {
        let body = self.with(|c| read_body(c, kind, namespace, name))?;
        body.as_deref().map(parse_body).transpose()
    }

    /// Objects of a kind (in one namespace or all), sorted by namespace and name,
    /// and the store's resourceVersion at the time of listing.
    pub fn list(&self, kind: Kind, namespace: Option<&str>) -> Result<(Vec<Value>, i64)> {
        let (bodies, rv) = self.with(|c| {
            let tx = c.transaction()?;
            let bodies: Vec<String> = {
                let mut st = tx.prepare(
                    "SELECT body FROM objects WHERE kind=?1 AND (?2 IS NULL OR namespace=?2) ORDER BY namespace, name",
                )?;
                st.query_map(params![kind.name(), namespace], |r| r.get(0))?
                    .collect::<rusqlite::Result<_>>()?
            };
            let rv: i64 = tx.query_row("SELECT COALESCE(MAX(rv), 0) FROM changes", [], |r| r.get(0))?;
            tx.commit()?;
            Ok((bodies, rv))
        })?;
        Ok((
            bodies
                .iter()
                .map(|b| parse_body(b))
                .collect::<Result<_>>()?,
            rv,
        ))
    }

    /// Changes after `rv` still in the log, oldest first; `None` when `rv` is
    /// older than the log keeps (the watcher must list again: 410 Gone).
    pub fn changes_since(&self, rv: i64) -> Result<Option<Vec<Change>>> {
        let rows: Option<Vec<(i64, String, String, String)>> = self.with(|c| {
            let oldest: i64 =
                c.query_row("SELECT COALESCE(MIN(rv), 0) FROM changes", [], |r| r.get(0))?;
            if oldest > 0 && rv + 1 < oldest {
                return Ok(None);
            }
            let mut st =
                c.prepare("SELECT rv, kind, type, body FROM changes WHERE rv > ?1 ORDER BY rv")?;
            let rows = st
                .query_map(params![rv], |r| {
                    Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?))
                })?
                .collect::<rusqlite::Result<_>>()?;
            Ok(Some(rows))
        })?;
        rows.map(|rows| {
            rows.into_iter()
                .map(|(rv, kind, t, body)| {
                    Ok(Change {
                        resource_version: rv,
                        kind: kind_of(&kind)?,
                        type_: ChangeType::parse(&t),
                        object: parse_body(&body)?,
                    })
                })
                .collect()
        })
        .transpose()
    }

    /// Create or update the object's main resource (everything but status).
    /// `metadata.resourceVersion`, when given, must match the stored one.
    /// Generation is bumped only when the spec changes; an identical write
    /// changes nothing. Returns the stored object and whether it changed.
    pub fn put(&self, kind: Kind, obj: Value, create_only: bool) -> Result<(Value, bool)> {
        self.put_with(kind, obj, create_only, Mode::Commit)
    }

    /// [`Store::put`], or with [`Mode::DryRun`] every check and the resulting
    /// object without storing anything or telling watchers.
    pub fn put_with(
        &self,
        kind: Kind,
        mut obj: Value,
        create_only: bool,
        mode: Mode,
    ) -> Result<(Value, bool)> {
        let (ns, name) = key_of(&obj);
        let given_rv = obj["metadata"]["resourceVersion"]
            .as_str()
            .map(str::to_string);
        let out = self.with(|c| {
            let tx = c.transaction()?;
            let old = read_object(&tx, kind, &ns, &name)?;
            let outcome = match &old {
                Some(_) if create_only => Outcome::Exists,
                Some(old) => {
                    let current = old["metadata"]["resourceVersion"]
                        .as_str()
                        .unwrap_or("")
                        .to_string();
                    if let Some(given) = &given_rv
                        && *given != current
                    {
                        Outcome::Conflict {
                            current,
                            given: given.clone(),
                        }
                    } else {
                        merge_server_fields(&mut obj, old);
                        if same_user_content(&obj, old) {
                            Outcome::Unchanged(old.clone())
                        } else {
                            Outcome::Write(ChangeType::Modified)
                        }
                    }
                }
                None => {
                    init_server_fields(&mut obj);
                    Outcome::Write(ChangeType::Added)
                }
            };
            let old_rv = old
                .as_ref()
                .map(|o| o["metadata"]["resourceVersion"].clone());
            let result = match outcome {
                Outcome::Write(t) => {
                    let mut change = write(&tx, kind, &ns, &name, obj.clone(), t)?;
                    if mode == Mode::DryRun {
                        set_dry_run_version(&mut change.object, old_rv);
                    }
                    Outcome::Written(change)
                }
                other => other,
            };
            mode.end(tx)?;
            Ok(result)
        })?;
        self.finish(kind, &ns, &name, out, mode)
    }

    /// Replace the status subresource only; the spec and generation are untouched.
    pub fn put_status(
        &self,
        kind: Kind,
        namespace: &str,
        name: &str,
        status: Value,
        given_rv: Option<&str>,
    ) -> Result<(Value, bool)> {
        self.put_status_with(kind, namespace, name, status, given_rv, Mode::Commit)
    }

    /// [`Store::put_status`], optionally as a dry run.
    pub fn put_status_with(
        &self,
        kind: Kind,
        namespace: &str,
        name: &str,
        status: Value,
        given_rv: Option<&str>,
        mode: Mode,
    ) -> Result<(Value, bool)> {
        let out = self.with(|c| {
            let tx = c.transaction()?;
            let old = read_object(&tx, kind, namespace, name)?;
            let Some(old) = old else {
                return Ok(Outcome::Missing);
            };
            let current = old["metadata"]["resourceVersion"]
                .as_str()
                .unwrap_or("")
                .to_string();
            if let Some(given) = given_rv
                && given != current
            {
                return Ok(Outcome::Conflict {
                    current,
                    given: given.into(),
                });
            }
            if old.get("status") == Some(&status) {
                return Ok(Outcome::Unchanged(old));
            }
            let old_rv = old["metadata"]["resourceVersion"].clone();
            let mut obj = old;
            obj["status"] = status;
            let mut w = write(&tx, kind, namespace, name, obj, ChangeType::Modified)?;
            if mode == Mode::DryRun {
                set_dry_run_version(&mut w.object, Some(old_rv));
            }
            mode.end(tx)?;
            Ok(Outcome::Written(w))
        })?;
        self.finish(kind, namespace, name, out, mode)
    }

    pub fn delete(&self, kind: Kind, namespace: &str, name: &str) -> Result<Value> {
        self.delete_with(
            kind,
            namespace,
            name,
            &Preconditions::default(),
            Mode::Commit,
        )
    }

    /// Delete when the stored object still has the `preconditions`' uid and
    /// resourceVersion (a [`StoreError::Conflict`] otherwise); a dry run only checks.
    pub fn delete_with(
        &self,
        kind: Kind,
        namespace: &str,
        name: &str,
        preconditions: &Preconditions,
        mode: Mode,
    ) -> Result<Value> {
        let out = self.with(|c| {
            let tx = c.transaction()?;
            let old = read_object(&tx, kind, namespace, name)?;
            let Some(old) = old else {
                return Ok(Outcome::Missing);
            };
            for (field, want) in [
                ("uid", &preconditions.uid),
                ("resourceVersion", &preconditions.resource_version),
            ] {
                let current = old["metadata"][field].as_str().unwrap_or("").to_string();
                if let Some(want) = want
                    && *want != current
                {
                    return Ok(Outcome::Precondition {
                        field,
                        current,
                        given: want.clone(),
                    });
                }
            }
            if mode == Mode::DryRun {
                return Ok(Outcome::Unchanged(old));
            }
            tx.execute(
                "DELETE FROM objects WHERE kind=?1 AND namespace=?2 AND name=?3",
                params![kind.name(), namespace, name],
            )?;
            let mut obj = old;
            tx.execute(
                "INSERT INTO changes (kind, type, body) VALUES (?1, 'DELETED', ?2)",
                params![kind.name(), obj.to_string()],
            )?;
            let rv = tx.last_insert_rowid();
            obj["metadata"]["resourceVersion"] = rv.to_string().into();
            tx.commit()?;
            Ok(Outcome::Written(Change {
                resource_version: rv,
                kind,
                type_: ChangeType::Deleted,
                object: obj,
            }))
        })?;
        self.finish(kind, namespace, name, out, mode)
            .map(|(v, _)| v)
    }

    fn finish(
        &self,
        kind: Kind,
        namespace: &str,
        name: &str,
        out: Outcome,
        mode: Mode,
    ) -> Result<(Value, bool)> {
        let (ns, name) = (namespace.to_string(), name.to_string());
        match out {
            Outcome::Written(change) => {
                let obj = change.object.clone();
                if mode == Mode::Commit {
                    let _ = self.changes.send(change);
                }
                Ok((obj, true))
            }
            Outcome::Unchanged(obj) => Ok((obj, false)),
            Outcome::Missing => Err(StoreError::NotFound {
                kind,
                namespace: ns,
                name,
            }),
            Outcome::Exists => Err(StoreError::AlreadyExists {
                kind,
                namespace: ns,
                name,
            }),
            Outcome::Conflict { current, given } => Err(StoreError::Conflict {
                kind,
                namespace: ns,
                name,
                current,
                given,
            }),
            Outcome::Precondition {
                field,
                current,
                given,
            } => Err(StoreError::Precondition {
                kind,
                namespace: ns,
                name,
                field,
                current,
                given,
            }),
            Outcome::Write(_) => Err(StoreError::Corrupt("unfinished write".into())),
        }
    }

    /// Record an event about an object.
    pub fn record_event(
        &self,
        obj: &Value,
        type_: &str,
        reason: &Reason,
        message: &str,
    ) -> Result<()> {
        self.put_state_and_events(None, obj, &[(type_, reason.clone(), message.to_string())])
    }

    /// Saves a controller-private document (as [`Store::put_state`]; `None`:
    /// none) and records `events` (type, reason, message) about `obj`, in one
    /// transaction: a crash leaves both or neither. A tuning run's step
    /// writes its next resume point with the events it emitted, so a run
    /// resumed after a kill neither repeats a step whose events were
    /// recorded nor loses them.
    pub fn put_state_and_events(
        &self,
        state: Option<(&str, &str, &str)>,
        obj: &Value,
        events: &[(&str, Reason, String)],
    ) -> Result<()> {
        let (ns, name) = key_of(obj);
        let kind = obj["kind"].as_str().unwrap_or("").to_string();
        let uid = obj["metadata"]["uid"].as_str().unwrap_or("").to_string();
        let time = now_rfc3339();
        let ids = self.with(|c| {
            let tx = c.transaction()?;
            if let Some((scope, key, body)) = state {
                upsert_state(&tx, scope, key, body)?;
            }
            let mut ids = Vec::with_capacity(events.len());
            for (type_, reason, message) in events {
                tx.execute(
                    "INSERT INTO events (time, namespace, kind, name, uid, type, reason, message) VALUES (?1,?2,?3,?4,?5,?6,?7,?8)",
                    params![time, ns, kind, name, uid, type_, reason.as_str(), message],
                )?;
                ids.push(tx.last_insert_rowid());
            }
            if let Some(last) = ids.last() {
                tx.execute("DELETE FROM events WHERE id <= ?1", params![last - 10_000])?;
            }
            tx.commit()?;
            Ok(ids)
        })?;
        for (id, (type_, reason, message)) in ids.into_iter().zip(events) {
            let _ = self.events.send(Event {
                id,
                time: time.clone(),
                namespace: ns.clone(),
                kind: kind.clone(),
                name: name.clone(),
                uid: uid.clone(),
                type_: (*type_).into(),
                reason: reason.clone(),
                message: message.clone(),
            });
        }
        Ok(())
    }

    /// Events, oldest first, optionally about one object.
    pub fn events(
        &self,
        namespace: Option<&str>,
        kind: Option<&str>,
        name: Option<&str>,
    ) -> Result<Vec<Event>> {
        self.with(|c| {
            let mut st = c.prepare(
                "SELECT id, time, namespace, kind, name, uid, type, reason, message FROM events
                 WHERE (?1 IS NULL OR namespace=?1) AND (?2 IS NULL OR kind=?2) AND (?3 IS NULL OR name=?3) ORDER BY id",
            )?;
            st.query_map(params![namespace, kind, name], |r| {
                Ok(Event {
                    id: r.get(0)?,
                    time: r.get(1)?,
                    namespace: r.get(2)?,
                    kind: r.get(3)?,
                    name: r.get(4)?,
                    uid: r.get(5)?,
                    type_: r.get(6)?,
                    reason: Reason::parse(&r.get::<_, String>(7)?),
                    message: r.get(8)?,
                })
            })?
            .collect()
        })
    }
}

impl Store {
    /// Save a controller-private document (e.g. a tuning run's resume point),
    /// replacing the previous one; one transaction, durable on return.
    pub fn put_state(&self, scope: &str, key: &str, body: &str) -> Result<()> {
        self.with(|c| upsert_state(c, scope, key, body))
    }

    /// A controller-private document saved by [`Store::put_state`].
    pub fn get_state(&self, scope: &str, key: &str) -> Result<Option<String>> {
        self.with(|c| {
            c.query_row(
                "SELECT body FROM controller_state WHERE scope=?1 AND key=?2",
                params![scope, key],
                |r| r.get(0),
            )
            .optional()
        })
    }

    pub fn delete_state(&self, scope: &str, key: &str) -> Result<()> {
        self.with(|c| {
            c.execute(
                "DELETE FROM controller_state WHERE scope=?1 AND key=?2",
                params![scope, key],
            )
            .map(|_| ())
        })
    }
}

/// The stored JSON text of one object.
fn read_body(
    c: &Connection,
    kind: Kind,
    namespace: &str,
    name: &str,
) -> rusqlite::Result<Option<String>> {
    c.query_row(
        "SELECT body FROM objects WHERE kind=?1 AND namespace=?2 AND name=?3",
        params![kind.name(), namespace, name],
        |r| r.get(0),
    )
    .optional()
}

/// The stored object, inside a write transaction (an unreadable body counts as absent).
fn read_object(
    c: &Connection,
    kind: Kind,
    namespace: &str,
    name: &str,
) -> rusqlite::Result<Option<Value>> {
    Ok(read_body(c, kind, namespace, name)?.and_then(|b| serde_json::from_str(&b).ok()))
}

/// Whether a write is stored or only checked (the API's `dryRun=All`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    Commit,
    /// Run every check and compute the result inside the transaction, then
    /// roll it back: nothing is stored and no watcher hears of it.
    DryRun,
}

impl Mode {
    fn end(self, tx: rusqlite::Transaction<'_>) -> rusqlite::Result<()> {
        match self {
            Mode::Commit => tx.commit(),
            Mode::DryRun => tx.rollback(),
        }
    }
}

/// Conditions a delete checks against the stored object (Kubernetes'
/// `DeleteOptions.preconditions`).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Preconditions {
    pub uid: Option<String>,
    pub resource_version: Option<String>,
}

/// A dry run's object keeps the stored resourceVersion (none for a create):
/// the one its rolled-back write drew was never stored.
fn set_dry_run_version(obj: &mut Value, old_rv: Option<Value>) {
    match old_rv {
        Some(rv) => obj["metadata"]["resourceVersion"] = rv,
        None => {
            if let Some(m) = obj["metadata"].as_object_mut() {
                m.remove("resourceVersion");
            }
        }
    }
}

enum Outcome {
    Write(ChangeType),
    Written(Change),
    Unchanged(Value),
    Missing,
    Exists,
    Conflict {
        current: String,
        given: String,
    },
    Precondition {
        field: &'static str,
        current: String,
        given: String,
    },
}

fn write(
    tx: &rusqlite::Transaction<'_>,
    kind: Kind,
    ns: &str,
    name: &str,
    mut obj: Value,
    t: ChangeType,
) -> rusqlite::Result<Change> {
    tx.execute(
        "INSERT INTO changes (kind, type, body) VALUES (?1, ?2, '{}')",
        params![kind.name(), t.as_str()],
    )?;
    let rv = tx.last_insert_rowid();
    obj["metadata"]["resourceVersion"] = rv.to_string().into();
    let body = obj.to_string();
    tx.execute("UPDATE changes SET body=?1 WHERE rv=?2", params![body, rv])?;
    tx.execute(
        "INSERT INTO objects (kind, namespace, name, uid, resource_version, body) VALUES (?1,?2,?3,?4,?5,?6)
         ON CONFLICT(kind, namespace, name) DO UPDATE SET uid=excluded.uid, resource_version=excluded.resource_version, body=excluded.body",
        params![kind.name(), ns, name, obj["metadata"]["uid"].as_str().unwrap_or(""), rv, body],
    )?;
    tx.execute(
        "DELETE FROM changes WHERE rv <= ?1",
        params![rv - CHANGE_LOG_KEEP],
    )?;
    Ok(Change {
        resource_version: rv,
        kind,
        type_: t,
        object: obj,
    })
}

/// `(namespace, name)` of an object, namespace defaulted.
pub fn key_of(obj: &Value) -> (String, String) {
    let ns = obj["metadata"]["namespace"]
        .as_str()
        .unwrap_or(configbot_manifests::DEFAULT_NAMESPACE);
    let name = obj["metadata"]["name"].as_str().unwrap_or("");
    (ns.to_string(), name.to_string())
}

fn init_server_fields(obj: &mut Value) {
    let ns = key_of(obj).0;
    let m = &mut obj["metadata"];
    m["namespace"] = ns.into();
    m["uid"] = uuid::Uuid::new_v4().to_string().into();
    m["generation"] = 1.into();
    m["creationTimestamp"] = now_rfc3339().into();
    if let Some(o) = obj.as_object_mut() {
        o.remove("status");
    }
}

/// Carry server-owned fields and status over from the stored object; bump generation on spec change.
fn merge_server_fields(obj: &mut Value, old: &Value) {
    let ns = key_of(obj).0;
    let generation = old["metadata"]["generation"].as_i64().unwrap_or(1);
    let spec_changed = obj.get("spec") != old.get("spec");
    let m = &mut obj["metadata"];
    m["namespace"] = ns.into();
    for f in ["uid", "creationTimestamp", "resourceVersion"] {
        m[f] = old["metadata"][f].clone();
    }
    // A writer that records no field ownership (the controller's own) keeps the old.
    if m.get("managedFields").is_none()
        && let Some(mf) = old["metadata"].get("managedFields")
    {
        m["managedFields"] = mf.clone();
    }
    m["generation"] = (if spec_changed {
        generation + 1
    } else {
        generation
    })
    .into();
    match old.get("status") {
        Some(s) => obj["status"] = s.clone(),
        None => {
            if let Some(o) = obj.as_object_mut() {
                o.remove("status");
            }
        }
    }
}

fn same_user_content(a: &Value, b: &Value) -> bool {
    a.get("spec") == b.get("spec")
        && a["metadata"]["labels"] == b["metadata"]["labels"]
        && a["metadata"]["annotations"] == b["metadata"]["annotations"]
        && a["metadata"]["managedFields"] == b["metadata"]["managedFields"]
}

#[cfg(test)]
#[path = "store_tests.rs"]
mod tests;

/// Writes a controller-private document, replacing the previous one (for
/// [`Store::put_state`] and [`Store::put_state_and_events`]).
fn upsert_state(c: &Connection, scope: &str, key: &str, body: &str) -> rusqlite::Result<()> {
    c.execute(
        "INSERT INTO controller_state (scope, key, body) VALUES (?1, ?2, ?3)
         ON CONFLICT(scope, key) DO UPDATE SET body=excluded.body",
        params![scope, key, body],
    )
    .map(|_| ())
}
