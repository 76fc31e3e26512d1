//! The parameter tree of the ROS Parameter Server: name resolution, set/get/
//! delete/search semantics as rosmaster implements them, and which
//! subscriptions a change touches. Pure.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::xmlrpc::Value;

/// Resolves `name` relative to the namespace of node `caller_id`
/// (`/ns/node` → `/ns/`), as rosgraph.names.resolve_name does.
pub fn resolve(name: &str, caller_id: &str) -> String {
    let name = name.trim();
    let full = if name.starts_with('/') {
        name.to_string()
    } else {
        let ns = namespace_of(caller_id);
        let name = name.strip_prefix('~').map_or(name.to_string(), |rest| {
            format!("{}/{rest}", caller_id.trim_end_matches('/'))
        });
        if name.starts_with('/') {
            name
        } else {
            format!("{ns}{name}")
        }
    };
    canonical(&full)
}

/// `/a//b/` → `/a/b`; the root stays `/`.
pub fn canonical(name: &str) -> String {
    let parts: Vec<&str> = name.split('/').filter(|p| !p.is_empty()).collect();
    format!("/{}", parts.join("/"))
}

/// The namespace of a node name, with trailing slash: `/ns/node` → `/ns/`.
pub fn namespace_of(node: &str) -> String {
    let c = canonical(node);
    match c.rfind('/') {
        Some(0) | None => "/".to_string(),
        Some(i) => format!("{}/", &c[..i]),
    }
}

fn segments(key: &str) -> Vec<&str> {
    key.split('/').filter(|p| !p.is_empty()).collect()
}

/// How deep `value` set at canonical `key` reaches into the parameter tree:
/// the key's names plus the value's nesting below its first level.
pub fn depth(key: &str, value: &Value) -> usize {
    segments(key).len() + value.depth() - 1
}

/// The parameter tree; namespaces are `Value::Struct`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ParamTree {
    root: BTreeMap<String, Value>,
}

impl ParamTree {
    /// Value at canonical `key`; the root is the whole tree.
    pub fn get(&self, key: &str) -> Option<Value> {
        let segs = segments(key);
        let mut cur = &self.root;
        let Some((last, path)) = segs.split_last() else {
            return Some(Value::Struct(self.root.clone()));
        };
        for s in path {
            match cur.get(*s) {
                Some(Value::Struct(m)) => cur = m,
                _ => return None,
            }
        }
        cur.get(*last).cloned()
    }

    pub fn has(&self, key: &str) -> bool {
        self.get(key).is_some()
    }

    /// Sets `key` to `value`, replacing whatever was there (a struct value
    /// replaces the whole namespace, as rosmaster does).
    pub fn set(&mut self, key: &str, value: Value) {
        let segs = segments(key);
        let Some((last, path)) = segs.split_last() else {
            if let Value::Struct(m) = value {
                self.root = m;
            }
            return;
        };
        let mut cur = &mut self.root;
        for s in path {
            let e = cur
                .entry((*s).to_string())
                .or_insert_with(|| Value::Struct(BTreeMap::new()));
            if !matches!(e, Value::Struct(_)) {
                *e = Value::Struct(BTreeMap::new());
            }
            let Value::Struct(m) = e else { return };
            cur = m;
        }
        cur.insert((*last).to_string(), value);
    }

    /// Deletes `key`; false if it was not set.
    pub fn delete(&mut self, key: &str) -> bool {
        let segs = segments(key);
        let Some((last, path)) = segs.split_last() else {
            self.root.clear();
            return true;
        };
        let mut cur = &mut self.root;
        for s in path {
            match cur.get_mut(*s) {
                Some(Value::Struct(m)) => cur = m,
                _ => return false,
            }
        }
        cur.remove(*last).is_some()
    }

    /// Every leaf parameter name (namespaces expanded).
    pub fn names(&self) -> Vec<String> {
        fn walk(prefix: &str, m: &BTreeMap<String, Value>, out: &mut Vec<String>) {
            for (k, v) in m {
                let name = format!("{prefix}/{k}");
                match v {
                    Value::Struct(sub) if !sub.is_empty() => walk(&name, sub, out),
                    _ => out.push(name),
                }
            }
        }
        let mut out = Vec::new();
        walk("", &self.root, &mut out);
        out
    }

    /// searchParam: the closest `key` going up from the caller's namespace.
    pub fn search(&self, caller_id: &str, key: &str) -> Option<String> {
        if key.starts_with('/') {
            let k = canonical(key);
            return self.has(&k).then_some(k);
        }
        let k = key.trim_start_matches('~');
        let segs = segments(k);
        let first = segs.first()?;
        let mut ns = namespace_of(caller_id);
        loop {
            let cand = canonical(&format!("{ns}{first}"));
            if self.has(&cand) {
                let rest: Vec<&str> = segs[1..].to_vec();
                return Some(if rest.is_empty() {
                    cand
                } else {
                    canonical(&format!("{cand}/{}", rest.join("/")))
                });
            }
            if ns == "/" {
                return None;
            }
            ns = namespace_of(ns.trim_end_matches('/'));
        }
    }
}

/// Subscribed keys affected by a change of `changed`: the key itself, keys
/// under it and keys above it.
pub fn affected<'a>(changed: &str, subscribed: impl Iterator<Item = &'a String>) -> Vec<String> {
    let under = |a: &str, b: &str| a == b || b == "/" || a.starts_with(&format!("{b}/"));
    subscribed
        .filter(|s| under(s, changed) || under(changed, s))
        .cloned()
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resolves_names() {
        assert_eq!(resolve("a", "/rosparam_1"), "/a");
        assert_eq!(resolve("a/b", "/ns/node"), "/ns/a/b");
        assert_eq!(resolve("/x/", "/ns/node"), "/x");
        assert_eq!(resolve("~p", "/ns/node"), "/ns/node/p");
        assert_eq!(namespace_of("/node"), "/");
    }

    #[test]
    fn set_get_delete_namespaces() {
        let mut t = ParamTree::default();
        t.set("/a/b", Value::Int(1));
        t.set("/a/c", Value::str("x"));
        assert_eq!(t.get("/a/b"), Some(Value::Int(1)));
        let Some(Value::Struct(a)) = t.get("/a") else {
            panic!()
        };
        assert_eq!(a.len(), 2);
        assert_eq!(t.names(), vec!["/a/b", "/a/c"]);
        // a struct replaces the namespace
        let mut m = BTreeMap::new();
        m.insert("d".to_string(), Value::Bool(true));
        t.set("/a", Value::Struct(m));
        assert_eq!(t.get("/a/b"), None);
        assert_eq!(t.get("/a/d"), Some(Value::Bool(true)));
        // a scalar under a scalar turns it into a namespace
        t.set("/a/d/e", Value::Int(2));
        assert_eq!(t.get("/a/d/e"), Some(Value::Int(2)));
        assert!(t.delete("/a/d"));
        assert!(!t.delete("/a/d"));
        assert!(!t.has("/a/d/e"));
        assert!(t.get("/").is_some());
    }

    #[test]
    fn search_goes_up_namespaces() {
        let mut t = ParamTree::default();
        t.set("/robot/rate", Value::Int(1));
        t.set("/rate", Value::Int(2));
        t.set("/robot/arm/x", Value::Int(3));
        assert_eq!(
            t.search("/robot/arm/node", "rate").as_deref(),
            Some("/robot/rate")
        );
        assert_eq!(t.search("/other/node", "rate").as_deref(), Some("/rate"));
        assert_eq!(
            t.search("/robot/arm/node", "arm/x").as_deref(),
            Some("/robot/arm/x")
        );
        assert_eq!(t.search("/n", "missing"), None);
    }

    #[test]
    fn affected_subscriptions() {
        let subs: Vec<String> = vec!["/a".into(), "/a/b".into(), "/ab".into(), "/c".into()];
        let mut got = affected("/a/b", subs.iter());
        got.sort();
        assert_eq!(got, vec!["/a", "/a/b"]);
        assert_eq!(affected("/a", subs.iter()), vec!["/a", "/a/b"]);
    }
}
