//! SQLite persistence of the master's state (registrations, topic types,
//! parameters, parameter subscriptions) and of adaptor settings, so an agent
//! restart keeps the graph. Each save rewrites the state in one transaction
//! (the state is small and changes only on registrations).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use configbot_dataplane::{AdaptorSetting, EdgeId};
use rusqlite::{Connection, params};

use crate::params::ParamTree;
use crate::state::MasterState;

/// Errors of the store.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("sqlite error on {path}")]
    Sqlite {
        path: PathBuf,
        #[source]
        source: rusqlite::Error,
    },
    #[error("bad stored parameters in {path}")]
    Json {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
}

/// The database handle.
#[derive(Debug)]
pub struct Store {
    conn: Connection,
    path: PathBuf,
}

const SCHEMA: &str = "
CREATE TABLE IF NOT EXISTS nodes (name TEXT PRIMARY KEY, api TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS registrations (kind TEXT NOT NULL, name TEXT NOT NULL, node TEXT NOT NULL, api TEXT NOT NULL DEFAULT '', PRIMARY KEY (kind, name, node));
CREATE TABLE IF NOT EXISTS topic_types (topic TEXT PRIMARY KEY, type TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS params (id INTEGER PRIMARY KEY CHECK (id = 1), tree TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS adaptors (topic TEXT NOT NULL, subscriber TEXT NOT NULL, rate_hz REAL, PRIMARY KEY (topic, subscriber));
";

impl Store {
    /// Opens (creating) the database at `path`.
    pub fn open(path: &Path) -> Result<Self, StoreError> {
        let err = |source| StoreError::Sqlite {
            path: path.to_path_buf(),
            source,
        };
        let conn = Connection::open(path).map_err(err)?;
        conn.pragma_update(None, "journal_mode", "WAL")
            .map_err(err)?;
        conn.pragma_update(None, "synchronous", "NORMAL")
            .map_err(err)?;
        conn.execute_batch(SCHEMA).map_err(err)?;
        Ok(Self {
            conn,
            path: path.to_path_buf(),
        })
    }

    fn err(&self, source: rusqlite::Error) -> StoreError {
        StoreError::Sqlite {
            path: self.path.clone(),
            source,
        }
    }

    /// Replaces the stored master state with `s`.
    pub fn save(&mut self, s: &MasterState) -> Result<(), StoreError> {
        let tree = serde_json::to_string(&s.params).map_err(|source| StoreError::Json {
            path: self.path.clone(),
            source,
        })?;
        let path = self.path.clone();
        let err = |source| StoreError::Sqlite {
            path: path.clone(),
            source,
        };
        let tx = self.conn.transaction().map_err(err)?;
        tx.execute_batch("DELETE FROM nodes; DELETE FROM registrations; DELETE FROM topic_types;")
            .map_err(err)?;
        {
            let mut n = tx
                .prepare("INSERT INTO nodes (name, api) VALUES (?1, ?2)")
                .map_err(err)?;
            for (name, api) in &s.nodes {
                n.execute(params![name, api]).map_err(err)?;
            }
            let mut r = tx
                .prepare(
                    "INSERT INTO registrations (kind, name, node, api) VALUES (?1, ?2, ?3, ?4)",
                )
                .map_err(err)?;
            for (kind, map) in [
                ("pub", &s.publishers),
                ("sub", &s.subscribers),
                ("param", &s.param_subscribers),
            ] {
                for (name, nodes) in map {
                    for node in nodes {
                        r.execute(params![kind, name, node, ""]).map_err(err)?;
                    }
                }
            }
            for (name, (node, api)) in &s.services {
                r.execute(params!["srv", name, node, api]).map_err(err)?;
            }
            let mut t = tx
                .prepare("INSERT INTO topic_types (topic, type) VALUES (?1, ?2)")
                .map_err(err)?;
            for (topic, ty) in &s.topic_types {
                t.execute(params![topic, ty]).map_err(err)?;
            }
        }
        tx.execute(
            "INSERT OR REPLACE INTO params (id, tree) VALUES (1, ?1)",
            params![tree],
        )
        .map_err(err)?;
        tx.commit().map_err(err)
    }

    /// Loads the stored master state (empty if none).
    pub fn load(&self) -> Result<MasterState, StoreError> {
        let err = |e| self.err(e);
        let mut s = MasterState::default();
        let mut q = self
            .conn
            .prepare("SELECT name, api FROM nodes")
            .map_err(err)?;
        let rows = q
            .query_map([], |r| Ok((r.get::<_, String>(0)?, r.get::<_, String>(1)?)))
            .map_err(err)?;
        for row in rows {
            let (n, a) = row.map_err(err)?;
            s.nodes.insert(n, a);
        }
        let mut q = self
            .conn
            .prepare("SELECT kind, name, node, api FROM registrations")
            .map_err(err)?;
        let rows = q
            .query_map([], |r| {
                Ok((
                    r.get::<_, String>(0)?,
                    r.get::<_, String>(1)?,
                    r.get::<_, String>(2)?,
                    r.get::<_, String>(3)?,
                ))
            })
            .map_err(err)?;
        for row in rows {
            let (kind, name, node, api) = row.map_err(err)?;
            match kind.as_str() {
                "pub" => {
                    s.publishers.entry(name).or_default().insert(node);
                }
                "sub" => {
                    s.subscribers.entry(name).or_default().insert(node);
                }
                "param" => {
                    s.param_subscribers.entry(name).or_default().insert(node);
                }
                "srv" => {
                    s.services.insert(name, (node, api));
                }
                _ => {}
            }
        }
        let mut q = self
            .conn
            .prepare("SELECT topic, type FROM topic_types")
            .map_err(err)?;
        let rows = q
            .query_map([], |r| Ok((r.get::<_, String>(0)?, r.get::<_, String>(1)?)))
            .map_err(err)?;
        for row in rows {
            let (t, ty) = row.map_err(err)?;
            s.topic_types.insert(t, ty);
        }
        let tree: Option<String> = self
            .conn
            .query_row("SELECT tree FROM params WHERE id = 1", [], |r| r.get(0))
            .map_or_else(
                |e| match e {
                    rusqlite::Error::QueryReturnedNoRows => Ok(None),
                    e => Err(e),
                },
                |t| Ok(Some(t)),
            )
            .map_err(err)?;
        if let Some(t) = tree {
            s.params =
                serde_json::from_str::<ParamTree>(&t).map_err(|source| StoreError::Json {
                    path: self.path.clone(),
                    source,
                })?;
        }
        Ok(s)
    }

    /// Replaces the stored adaptor settings.
    pub fn save_adaptors(
        &mut self,
        a: &BTreeMap<EdgeId, AdaptorSetting>,
    ) -> Result<(), StoreError> {
        let path = self.path.clone();
        let err = |source| StoreError::Sqlite {
            path: path.clone(),
            source,
        };
        let tx = self.conn.transaction().map_err(err)?;
        tx.execute("DELETE FROM adaptors", []).map_err(err)?;
        {
            let mut q = tx
                .prepare("INSERT INTO adaptors (topic, subscriber, rate_hz) VALUES (?1, ?2, ?3)")
                .map_err(err)?;
            for (e, s) in a {
                q.execute(params![e.topic, e.subscriber, s.rate_hz])
                    .map_err(err)?;
            }
        }
        tx.commit().map_err(err)
    }

    /// Loads the stored adaptor settings.
    pub fn load_adaptors(&self) -> Result<BTreeMap<EdgeId, AdaptorSetting>, StoreError> {
        let err = |e| self.err(e);
        let mut q = self
            .conn
            .prepare("SELECT topic, subscriber, rate_hz FROM adaptors")
            .map_err(err)?;
        let rows = q
            .query_map([], |r| {
                Ok((
                    EdgeId {
                        topic: r.get(0)?,
                        subscriber: r.get(1)?,
                    },
                    AdaptorSetting { rate_hz: r.get(2)? },
                ))
            })
            .map_err(err)?;
        rows.collect::<Result<_, _>>().map_err(err)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::xmlrpc::Value;

    #[test]
    fn state_and_adaptors_survive_reopen() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("ros1.db");
        let mut s = MasterState::default();
        s.register_publisher("/t", "http://t/", "/a", "x/Y");
        s.register_subscriber("/l", "http://l/", "/a", "x/Y");
        s.register_service("/t", "http://t/", "/srv", "rosrpc://t:1");
        s.subscribe_param("/l", "http://l/", "/p");
        s.set_param("/p/q", Value::Double(2.5));
        let mut a = BTreeMap::new();
        a.insert(
            EdgeId {
                topic: "/a".into(),
                subscriber: "/l".into(),
            },
            AdaptorSetting {
                rate_hz: Some(20.0),
            },
        );
        {
            let mut st = Store::open(&path).unwrap();
            st.save(&s).unwrap();
            st.save_adaptors(&a).unwrap();
        }
        let st = Store::open(&path).unwrap();
        assert_eq!(st.load().unwrap(), s);
        assert_eq!(st.load_adaptors().unwrap(), a);
    }
}
