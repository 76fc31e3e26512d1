//! Store tests on real SQLite files in temp dirs.

use super::*;
use serde_json::json;

fn stack(name: &str, model: &str) -> Value {
    json!({"apiVersion": "configbot.dev/v1alpha1", "kind": "RobotStack",
           "metadata": {"name": name}, "spec": {"robot": {"model": model}, "apps": []}})
}

fn store() -> (tempfile::TempDir, Store) {
    let dir = tempfile::tempdir().unwrap();
    let s = Store::open(&dir.path().join("t.db")).unwrap();
    (dir, s)
}

#[test]
fn generation_moves_with_spec_only_and_identical_writes_change_nothing() {
    let (_d, s) = store();
    let (a, changed) = s.put(Kind::RobotStack, stack("a", "spot"), true).unwrap();
    assert!(changed);
    assert_eq!(a["metadata"]["generation"], 1);
    let (b, changed) = s.put(Kind::RobotStack, stack("a", "spot"), false).unwrap();
    assert!(!changed);
    assert_eq!(
        a["metadata"]["resourceVersion"],
        b["metadata"]["resourceVersion"]
    );
    let (c, _) = s
        .put_status(
            Kind::RobotStack,
            "default",
            "a",
            json!({"phase": "Accepted"}),
            None,
        )
        .unwrap();
    assert_eq!(c["metadata"]["generation"], 1);
    let (d, changed) = s
        .put(Kind::RobotStack, stack("a", "jackal"), false)
        .unwrap();
    assert!(changed);
    assert_eq!(d["metadata"]["generation"], 2);
    assert_eq!(
        d["status"]["phase"], "Accepted",
        "status survives spec updates"
    );
    assert_eq!(d["metadata"]["uid"], a["metadata"]["uid"]);
}

#[test]
fn stale_resource_version_conflicts() {
    let (_d, s) = store();
    let (a, _) = s.put(Kind::RobotStack, stack("a", "spot"), true).unwrap();
    let mut newer = stack("a", "jackal");
    newer["metadata"]["resourceVersion"] = a["metadata"]["resourceVersion"].clone();
    s.put(Kind::RobotStack, newer.clone(), false).unwrap();
    newer["spec"]["robot"]["model"] = "cobot".into();
    assert!(matches!(
        s.put(Kind::RobotStack, newer, false),
        Err(StoreError::Conflict { .. })
    ));
    assert!(matches!(
        s.put(Kind::RobotStack, stack("a", "x"), true),
        Err(StoreError::AlreadyExists { .. })
    ));
}

#[test]
fn change_log_resumes_and_deletes_are_logged() {
    let (_d, s) = store();
    s.put(Kind::RobotStack, stack("a", "spot"), true).unwrap();
    let (_, rv) = s.list(Kind::RobotStack, None).unwrap();
    s.put(Kind::RobotStack, stack("b", "spot"), true).unwrap();
    s.delete(Kind::RobotStack, "default", "a").unwrap();
    let changes = s.changes_since(rv).unwrap().unwrap();
    let kinds: Vec<_> = changes.iter().map(|c| c.type_).collect();
    assert_eq!(kinds, vec![ChangeType::Added, ChangeType::Deleted]);
    assert!(matches!(
        s.delete(Kind::RobotStack, "default", "a"),
        Err(StoreError::NotFound { .. })
    ));
}

#[test]
fn dry_runs_check_everything_and_store_nothing() {
    let (_d, s) = store();
    let (dry, changed) = s
        .put_with(Kind::RobotStack, stack("a", "spot"), true, Mode::DryRun)
        .unwrap();
    assert!(changed);
    assert!(dry["metadata"].get("resourceVersion").is_none());
    assert_eq!(s.get(Kind::RobotStack, "default", "a").unwrap(), None);
    let (a, _) = s.put(Kind::RobotStack, stack("a", "spot"), true).unwrap();
    let mut live = s.subscribe();
    assert!(matches!(
        s.put_with(Kind::RobotStack, stack("a", "x"), true, Mode::DryRun),
        Err(StoreError::AlreadyExists { .. })
    ));
    let (b, changed) = s
        .put_with(Kind::RobotStack, stack("a", "jackal"), false, Mode::DryRun)
        .unwrap();
    assert!(changed);
    assert_eq!(b["metadata"]["generation"], 2);
    assert_eq!(
        b["metadata"]["resourceVersion"],
        a["metadata"]["resourceVersion"]
    );
    s.put_status_with(
        Kind::RobotStack,
        "default",
        "a",
        json!({"phase": "X"}),
        None,
        Mode::DryRun,
    )
    .unwrap();
    s.delete_with(
        Kind::RobotStack,
        "default",
        "a",
        &Preconditions::default(),
        Mode::DryRun,
    )
    .unwrap();
    assert_eq!(
        s.get(Kind::RobotStack, "default", "a").unwrap(),
        Some(a.clone())
    );
    assert!(live.try_recv().is_err(), "watchers heard of a dry run");
    let (_, rv) = s.list(Kind::RobotStack, None).unwrap();
    assert_eq!(
        rv.to_string(),
        a["metadata"]["resourceVersion"],
        "the change log moved"
    );
    let stale = Preconditions {
        resource_version: Some("0".into()),
        ..Preconditions::default()
    };
    assert!(matches!(
        s.delete_with(Kind::RobotStack, "default", "a", &stale, Mode::Commit),
        Err(StoreError::Precondition {
            field: "resourceVersion",
            ..
        })
    ));
}

#[test]
fn controller_state_round_trips_and_survives_reopen() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.db");
    {
        let s = Store::open(&path).unwrap();
        s.put_state("tuning", "default/a", "{\"n\":1}").unwrap();
        s.put_state("tuning", "default/a", "{\"n\":2}").unwrap();
        s.put_state("tuning", "default/b", "{}").unwrap();
        s.delete_state("tuning", "default/b").unwrap();
    }
    let s = Store::open(&path).unwrap();
    assert_eq!(
        s.get_state("tuning", "default/a").unwrap().as_deref(),
        Some("{\"n\":2}")
    );
    assert_eq!(s.get_state("tuning", "default/b").unwrap(), None);
    assert_eq!(s.get_state("other", "default/a").unwrap(), None);
}

#[test]
fn data_survives_reopen() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.db");
    {
        let s = Store::open(&path).unwrap();
        s.put(Kind::RobotStack, stack("a", "spot"), true).unwrap();
        s.record_event(&stack("a", "spot"), "Normal", &Reason::Created, "hello")
            .unwrap();
    }
    let s = Store::open(&path).unwrap();
    assert!(s.get(Kind::RobotStack, "default", "a").unwrap().is_some());
    assert_eq!(
        s.events(None, None, Some("a")).unwrap()[0].reason,
        Reason::Created
    );
}

/// A tuning step's resume point and its events are written together: both
/// are there after a reopen, the events in order, and live subscribers get
/// each once.
#[test]
fn state_and_events_are_written_together() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.db");
    {
        let s = Store::open(&path).unwrap();
        let mut live = s.subscribe_events();
        let events = [
            ("Normal", Reason::Created, "trial 3".to_string()),
            ("Warning", Reason::Created, "trial 3 again".to_string()),
        ];
        s.put_state_and_events(
            Some(("tuning", "default/a", "{\"n\":3}")),
            &stack("a", "spot"),
            &events,
        )
        .unwrap();
        let got: Vec<String> = (0..2).map(|_| live.try_recv().unwrap().message).collect();
        assert_eq!(got, ["trial 3", "trial 3 again"]);
        assert!(live.try_recv().is_err(), "each event once");
    }
    let s = Store::open(&path).unwrap();
    assert_eq!(
        s.get_state("tuning", "default/a").unwrap().as_deref(),
        Some("{\"n\":3}")
    );
    let events = s.events(None, None, Some("a")).unwrap();
    let seen: Vec<(&str, &str)> = events
        .iter()
        .map(|e| (e.type_.as_str(), e.message.as_str()))
        .collect();
    assert_eq!(seen, [("Normal", "trial 3"), ("Warning", "trial 3 again")]);
    assert!(events[0].id < events[1].id);
}

/// A commit does not wait for the disk; the checkpointer makes it durable
/// within a few intervals: the object is then in the database file itself,
/// read with the write-ahead log ignored (`immutable=1`).
#[test]
fn the_checkpointer_folds_commits_into_the_database_file() {
    let (dir, s) = store();
    s.put(Kind::RobotStack, stack("folded", "spot"), true)
        .unwrap();
    let uri = format!("file:{}?immutable=1", dir.path().join("t.db").display());
    let in_file = || {
        let c = Connection::open_with_flags(
            &uri,
            rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY | rusqlite::OpenFlags::SQLITE_OPEN_URI,
        )
        .ok()?;
        c.query_row(
            "SELECT count(*) FROM objects WHERE name = 'folded'",
            [],
            |r| r.get::<_, i64>(0),
        )
        .ok()
        .filter(|n| *n == 1)
    };
    configbot_test_support::try_wait_until(
        "the commit to reach the database file",
        CHECKPOINT_EVERY * 10,
        Duration::from_millis(50),
        in_file,
    )
    .unwrap();
    // Dropping the store stops the thread at once (the test would hang on
    // a join that waited for a stop it never saw).
    drop(s);
}
