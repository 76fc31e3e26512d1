//! YAML text → located JSON documents.
//!
//! Every document of a multi-document stream is read into a tree that keeps the
//! line and column of each value, then turned into a `serde_json::Value` plus an
//! index from field paths (`spec.apps[1].name`) to positions. Typed decoding and
//! validation then work on the JSON value and report positions through the index,
//! so errors from every stage name the same path and the same line.

use std::collections::BTreeMap;
use std::fmt;

use serde::Deserialize;
use serde::de::{self, MapAccess, SeqAccess, Visitor};
use serde_saphyr::Spanned;

/// Largest manifest input accepted (a file, or standard input), in bytes.
pub const MAX_INPUT_BYTES: usize = 4 * 1024 * 1024;
/// Most values an alias expansion may produce across one input (alias bombs stop here).
pub const MAX_ALIAS_REPLAYED_EVENTS: usize = 100_000;
/// Deepest nesting of sequences and mappings. Manifests nest about ten
/// levels; the YAML reader recurses once per level with large frames (a debug
/// build overflowed a 2 MiB thread stack at 60 levels, under the reader's own
/// default budget of 64), so deeper input is refused before it is read.
pub const MAX_NESTING: usize = 32;

/// A line and column, both 1-based.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Pos {
    pub line: u64,
    pub column: u64,
}

/// One YAML document as JSON, with the position of every field path.
#[derive(Debug, Clone)]
pub struct Document {
    /// 1-based index of the document among the stream's non-empty documents.
    pub index: usize,
    pub value: serde_json::Value,
    /// Field path → where its value starts.
    pub positions: BTreeMap<String, Pos>,
}

impl Document {
    /// Position of `path`, or of its nearest ancestor that has one.
    pub fn position_of(&self, path: &str) -> Option<Pos> {
        let mut p = path.to_string();
        loop {
            if let Some(pos) = self.positions.get(&p) {
                return Some(*pos);
            }
            let cut = p.rfind(['.', '['])?;
            p.truncate(cut);
        }
    }
}

/// A YAML syntax or limit error, before any document could be read.
#[derive(Debug, Clone, PartialEq)]
pub struct SyntaxError {
    pub message: String,
    pub pos: Option<Pos>,
}

/// Read every non-empty document of `text`.
pub fn parse_documents(text: &str) -> Result<Vec<Document>, SyntaxError> {
    if text.len() > MAX_INPUT_BYTES {
        return Err(SyntaxError {
            message: format!(
                "input is {} bytes, more than the {} byte limit for manifests",
                text.len(),
                MAX_INPUT_BYTES
            ),
            pos: None,
        });
    }
    let mut options = serde_saphyr::options! { with_snippet: false };
    options.alias_limits.max_total_replayed_events = MAX_ALIAS_REPLAYED_EVENTS;
    let mut budget = options.budget.take().unwrap_or_default();
    budget.max_depth = MAX_NESTING;
    budget.flow_nesting_limit = MAX_NESTING;
    options.budget = Some(budget);
    let raw: Vec<Spanned<Raw>> =
        serde_saphyr::from_multiple_with_options(text, options).map_err(|e| SyntaxError {
            message: clean_saphyr_message(&e.to_string()),
            pos: e.location().and_then(to_pos),
        })?;
    let mut docs = Vec::new();
    for (i, node) in raw.into_iter().enumerate() {
        if matches!(node.value, Raw::Null) {
            continue;
        }
        let mut positions = BTreeMap::new();
        let value = to_json(node, String::new(), &mut positions)?;
        docs.push(Document {
            index: i + 1,
            value,
            positions,
        });
    }
    Ok(docs)
}

fn to_pos(loc: serde_saphyr::Location) -> Option<Pos> {
    (loc.line() > 0).then(|| Pos {
        line: loc.line(),
        column: loc.column(),
    })
}

fn clean_saphyr_message(msg: &str) -> String {
    // The library appends its own " at line X column Y"; positions are reported separately.
    // Hints addressed to the library's programmer are dropped.
    let msg = match msg.find(" at line ") {
        Some(i) => &msg[..i],
        None => msg,
    };
    let msg = msg.split(", set DuplicateKeyPolicy").next().unwrap_or(msg);
    if msg.starts_with("alias replay limit exceeded") {
        format!("{msg} (aliases expand to too many values)")
    } else {
        msg.to_string()
    }
}

/// Append a map key to a path, quoting keys that are not plain identifiers.
pub fn join_key(path: &str, key: &str) -> String {
    let plain = !key.is_empty()
        && key
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
    match (path.is_empty(), plain) {
        (true, true) => key.to_string(),
        (false, true) => format!("{path}.{key}"),
        (_, false) => format!("{path}[{key:?}]"),
    }
}

fn to_json(
    node: Spanned<Raw>,
    path: String,
    positions: &mut BTreeMap<String, Pos>,
) -> Result<serde_json::Value, SyntaxError> {
    let pos = to_pos(node.referenced);
    if let Some(p) = pos {
        positions.insert(path.clone(), p);
    }
    Ok(match node.value {
        Raw::Null => serde_json::Value::Null,
        Raw::Bool(b) => b.into(),
        Raw::Int(i) => i.into(),
        Raw::UInt(u) => u.into(),
        Raw::Float(f) => match serde_json::Number::from_f64(f) {
            Some(n) => serde_json::Value::Number(n),
            None => {
                return Err(SyntaxError {
                    message: format!("{path}: {f} is not a finite number"),
                    pos,
                });
            }
        },
        Raw::Str(s) => s.into(),
        Raw::Seq(items) => {
            let mut out = Vec::with_capacity(items.len());
            for (i, item) in items.into_iter().enumerate() {
                out.push(to_json(item, format!("{path}[{i}]"), positions)?);
            }
            serde_json::Value::Array(out)
        }
        Raw::Map(entries) => {
            let mut out = serde_json::Map::new();
            for (key, value) in entries {
                let child = join_key(&path, &key);
                out.insert(key, to_json(value, child, positions)?);
            }
            serde_json::Value::Object(out)
        }
    })
}

/// A YAML node with the position of each child.
#[derive(Debug)]
enum Raw {
    Null,
    Bool(bool),
    Int(i64),
    UInt(u64),
    Float(f64),
    Str(String),
    Seq(Vec<Spanned<Raw>>),
    Map(Vec<(String, Spanned<Raw>)>),
}

impl<'de> Deserialize<'de> for Raw {
    fn deserialize<D: de::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_any(RawVisitor)
    }
}

struct RawVisitor;

impl<'de> Visitor<'de> for RawVisitor {
    type Value = Raw;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("any YAML value")
    }
    fn visit_unit<E>(self) -> Result<Raw, E> {
        Ok(Raw::Null)
    }
    fn visit_none<E>(self) -> Result<Raw, E> {
        Ok(Raw::Null)
    }
    fn visit_some<D: de::Deserializer<'de>>(self, d: D) -> Result<Raw, D::Error> {
        Raw::deserialize(d)
    }
    fn visit_bool<E>(self, v: bool) -> Result<Raw, E> {
        Ok(Raw::Bool(v))
    }
    fn visit_i64<E>(self, v: i64) -> Result<Raw, E> {
        Ok(Raw::Int(v))
    }
    fn visit_u64<E>(self, v: u64) -> Result<Raw, E> {
        Ok(Raw::UInt(v))
    }
    fn visit_f64<E>(self, v: f64) -> Result<Raw, E> {
        Ok(Raw::Float(v))
    }
    fn visit_str<E>(self, v: &str) -> Result<Raw, E> {
        Ok(Raw::Str(v.to_string()))
    }
    fn visit_string<E>(self, v: String) -> Result<Raw, E> {
        Ok(Raw::Str(v))
    }
    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Raw, A::Error> {
        let mut items = Vec::new();
        while let Some(item) = seq.next_element::<Spanned<Raw>>()? {
            items.push(item);
        }
        Ok(Raw::Seq(items))
    }
    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Raw, A::Error> {
        let mut entries = Vec::new();
        while let Some(key) = map.next_key::<Key>()? {
            let value = map.next_value::<Spanned<Raw>>()?;
            entries.push((key.0, value));
        }
        Ok(Raw::Map(entries))
    }
}

/// A mapping key: any scalar, as text.
struct Key(String);

impl<'de> Deserialize<'de> for Key {
    fn deserialize<D: de::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct KeyVisitor;
        impl Visitor<'_> for KeyVisitor {
            type Value = Key;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a scalar mapping key")
            }
            fn visit_str<E>(self, v: &str) -> Result<Key, E> {
                Ok(Key(v.to_string()))
            }
            fn visit_bool<E>(self, v: bool) -> Result<Key, E> {
                Ok(Key(v.to_string()))
            }
            fn visit_i64<E>(self, v: i64) -> Result<Key, E> {
                Ok(Key(v.to_string()))
            }
            fn visit_u64<E>(self, v: u64) -> Result<Key, E> {
                Ok(Key(v.to_string()))
            }
            fn visit_f64<E>(self, v: f64) -> Result<Key, E> {
                Ok(Key(v.to_string()))
            }
            fn visit_unit<E>(self) -> Result<Key, E> {
                Ok(Key("null".into()))
            }
        }
        d.deserialize_any(KeyVisitor)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn positions_follow_paths() {
        let text = "a: 1\n---\nspec:\n  apps:\n    - name: x\n    - name: y\n";
        let docs = parse_documents(text).unwrap();
        assert_eq!(docs.len(), 2);
        assert_eq!(docs[1].index, 2);
        let p = docs[1].positions["spec.apps[1].name"];
        assert_eq!((p.line, p.column), (6, 13));
        let p = docs[1].position_of("spec.apps[1].nodes[3]").unwrap();
        assert_eq!(p.line, 6);
    }

    #[test]
    fn empty_documents_are_skipped() {
        let docs = parse_documents("---\n---\na: 1\n---\n").unwrap();
        assert_eq!(docs.len(), 1);
        assert_eq!(
            docs[0].index, 1,
            "documents are counted without the empty ones"
        );
    }

    #[test]
    fn odd_keys_are_quoted_in_paths() {
        assert_eq!(
            join_key("metadata.labels", "a.b/c"),
            "metadata.labels[\"a.b/c\"]"
        );
        assert_eq!(join_key("", "spec"), "spec");
    }
}
