//! Patch documents the API accepts, pure: RFC 7386 JSON merge patch and
//! RFC 6902 JSON patch (with RFC 6901 pointers), chosen by the request's
//! content type. A JSON patch applies whole or not at all.

use std::fmt;

use serde_json::{Value, json};

/// A parsed patch body.
#[derive(Debug, Clone, PartialEq)]
pub enum Patch {
    /// `application/merge-patch+json`.
    Merge(Value),
    /// `application/json-patch+json`: the operations, in order.
    Json(Vec<Op>),
}

/// Why a patch body is refused before it is applied.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PatchBodyError {
    #[error(
        "patch type {0:?} is not supported; use application/merge-patch+json (kubectl --type=merge) or application/json-patch+json (kubectl --type=json)"
    )]
    UnsupportedType(String),
    #[error("invalid patch body: {0}")]
    Invalid(String),
}

impl Patch {
    /// Parse `body` as the patch type named by `content_type`.
    pub fn parse(content_type: &str, body: &[u8]) -> Result<Patch, PatchBodyError> {
        let media = content_type.split(';').next().unwrap_or("").trim();
        let value = |what: &str| {
            serde_json::from_slice::<Value>(body)
                .map_err(|e| PatchBodyError::Invalid(format!("{what} is not JSON: {e}")))
        };
        match media {
            "application/merge-patch+json" => Ok(Patch::Merge(value("a merge patch")?)),
            "application/json-patch+json" => Ok(Patch::Json(parse_ops(&value("a JSON patch")?)?)),
            other => Err(PatchBodyError::UnsupportedType(other.to_string())),
        }
    }

    /// The patched copy of `target`; `target` itself is never changed.
    pub fn apply(&self, target: &Value) -> Result<Value, OpError> {
        match self {
            Patch::Merge(p) => {
                let mut out = target.clone();
                merge_patch(&mut out, p);
                Ok(out)
            }
            Patch::Json(ops) => json_patch(target, ops),
        }
    }
}

/// RFC 7386 JSON merge patch.
pub fn merge_patch(target: &mut Value, patch: &Value) {
    match patch {
        Value::Object(p) => {
            if !target.is_object() {
                *target = json!({});
            }
            if let Value::Object(t) = target {
                for (k, v) in p {
                    if v.is_null() {
                        t.remove(k);
                    } else {
                        merge_patch(t.entry(k.clone()).or_insert(Value::Null), v);
                    }
                }
            }
        }
        other => *target = other.clone(),
    }
}

/// One RFC 6902 operation.
#[derive(Debug, Clone, PartialEq)]
pub enum Op {
    Add { path: Pointer, value: Value },
    Remove { path: Pointer },
    Replace { path: Pointer, value: Value },
    Move { from: Pointer, path: Pointer },
    Copy { from: Pointer, path: Pointer },
    Test { path: Pointer, value: Value },
}

impl Op {
    fn name(&self) -> &'static str {
        match self {
            Op::Add { .. } => "add",
            Op::Remove { .. } => "remove",
            Op::Replace { .. } => "replace",
            Op::Move { .. } => "move",
            Op::Copy { .. } => "copy",
            Op::Test { .. } => "test",
        }
    }
    fn path(&self) -> &Pointer {
        match self {
            Op::Add { path, .. }
            | Op::Remove { path }
            | Op::Replace { path, .. }
            | Op::Move { path, .. }
            | Op::Copy { path, .. }
            | Op::Test { path, .. } => path,
        }
    }
}

/// An RFC 6901 JSON pointer, as its unescaped reference tokens.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Pointer(Vec<String>);

impl Pointer {
    pub fn parse(s: &str) -> Result<Pointer, String> {
        if s.is_empty() {
            return Ok(Pointer(Vec::new()));
        }
        let Some(rest) = s.strip_prefix('/') else {
            return Err(format!("pointer {s:?} must be empty or start with '/'"));
        };
        rest.split('/')
            .map(|t| {
                if t.replace("~0", "").replace("~1", "").contains('~') {
                    Err(format!(
                        "pointer {s:?}: '~' must be followed by 0 or 1 (token {t:?})"
                    ))
                } else {
                    Ok(t.replace("~1", "/").replace("~0", "~"))
                }
            })
            .collect::<Result<_, _>>()
            .map(Pointer)
    }

    fn is_proper_prefix_of(&self, other: &Pointer) -> bool {
        self.0.len() < other.0.len() && other.0.starts_with(&self.0)
    }
}

impl fmt::Display for Pointer {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for t in &self.0 {
            write!(f, "/{}", t.replace('~', "~0").replace('/', "~1"))?;
        }
        Ok(())
    }
}

/// Why an operation could not be applied: which one, and where.
#[derive(Debug, Clone, PartialEq)]
pub struct OpError {
    /// Position of the operation in the patch, from 0; `None` for a merge patch.
    pub index: Option<usize>,
    pub op: &'static str,
    pub path: String,
    pub message: String,
}

impl fmt::Display for OpError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.index {
            Some(i) => write!(
                f,
                "patch operation {i} ({} {:?}): {}",
                self.op, self.path, self.message
            ),
            None => write!(f, "{}", self.message),
        }
    }
}

impl std::error::Error for OpError {}

impl OpError {
    /// The operation's path as a field path (`spec.apps[0].name`), for `Status` causes.
    pub fn field(&self) -> String {
        let mut out = String::new();
        for t in Pointer::parse(&self.path).map(|p| p.0).unwrap_or_default() {
            if !t.is_empty() && t.bytes().all(|b| b.is_ascii_digit()) {
                out.push_str(&format!("[{t}]"));
            } else {
                if !out.is_empty() {
                    out.push('.');
                }
                out.push_str(&t);
            }
        }
        out
    }

    /// What went wrong, with the operation but without its path.
    pub fn cause(&self) -> String {
        match self.index {
            Some(i) => format!("patch operation {i} ({}): {}", self.op, self.message),
            None => self.message.clone(),
        }
    }
}

fn parse_ops(doc: &Value) -> Result<Vec<Op>, PatchBodyError> {
    let ops = doc.as_array().ok_or_else(|| {
        PatchBodyError::Invalid("a JSON patch must be an array of operations".into())
    })?;
    ops.iter()
        .enumerate()
        .map(|(i, o)| {
            parse_op(o).map_err(|m| PatchBodyError::Invalid(format!("operation {i}: {m}")))
        })
        .collect()
}

fn parse_op(o: &Value) -> Result<Op, String> {
    let o = o.as_object().ok_or("must be an object")?;
    let member = |name: &str| -> Result<&Value, String> {
        o.get(name)
            .ok_or_else(|| format!("missing member {name:?}"))
    };
    let pointer = |name: &str| -> Result<Pointer, String> {
        let s = member(name)?
            .as_str()
            .ok_or_else(|| format!("member {name:?} must be a string"))?;
        Pointer::parse(s).map_err(|e| format!("{name}: {e}"))
    };
    let op = member("op")?
        .as_str()
        .ok_or("member \"op\" must be a string")?;
    let path = pointer("path")?;
    Ok(match op {
        "add" => Op::Add {
            path,
            value: member("value")?.clone(),
        },
        "remove" => Op::Remove { path },
        "replace" => Op::Replace {
            path,
            value: member("value")?.clone(),
        },
        "move" => Op::Move {
            from: pointer("from")?,
            path,
        },
        "copy" => Op::Copy {
            from: pointer("from")?,
            path,
        },
        "test" => Op::Test {
            path,
            value: member("value")?.clone(),
        },
        other => {
            return Err(format!(
                "unknown op {other:?}; use add, remove, replace, move, copy or test"
            ));
        }
    })
}

/// Apply RFC 6902 operations in order to a copy of `doc`; the first failing
/// operation fails the whole patch.
pub fn json_patch(doc: &Value, ops: &[Op]) -> Result<Value, OpError> {
    let mut out = doc.clone();
    for (i, op) in ops.iter().enumerate() {
        apply_op(&mut out, op).map_err(|message| OpError {
            index: Some(i),
            op: op.name(),
            path: op.path().to_string(),
            message,
        })?;
    }
    Ok(out)
}

fn apply_op(doc: &mut Value, op: &Op) -> Result<(), String> {
    match op {
        Op::Add { path, value } => add(doc, path, value.clone()),
        Op::Remove { path } => remove(doc, path).map(|_| ()),
        Op::Replace { path, value } => {
            *get_mut(doc, &path.0)? = value.clone();
            Ok(())
        }
        Op::Move { from, path } => {
            if from.is_proper_prefix_of(path) {
                return Err(format!("cannot move {from} into its own child {path}"));
            }
            let v = remove(doc, from).map_err(|e| format!("from: {e}"))?;
            add(doc, path, v)
        }
        Op::Copy { from, path } => {
            let v = get_mut(doc, &from.0)
                .map_err(|e| format!("from: {e}"))?
                .clone();
            add(doc, path, v)
        }
        Op::Test { path, value } => {
            let found = get_mut(doc, &path.0)?;
            if json_equal(found, value) {
                Ok(())
            } else {
                Err(format!("test failed: the value is {found}, not {value}"))
            }
        }
    }
}

/// RFC 6902 §4.6 equality: numbers by value, objects regardless of member order.
pub fn json_equal(a: &Value, b: &Value) -> bool {
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => match (x.as_i64(), y.as_i64()) {
            (Some(x), Some(y)) => x == y,
            _ => match (x.as_u64(), y.as_u64()) {
                (Some(x), Some(y)) => x == y,
                _ => x.as_f64() == y.as_f64(),
            },
        },
        (Value::Array(x), Value::Array(y)) => {
            x.len() == y.len() && x.iter().zip(y).all(|(a, b)| json_equal(a, b))
        }
        (Value::Object(x), Value::Object(y)) => {
            x.len() == y.len()
                && x.iter()
                    .all(|(k, v)| y.get(k).is_some_and(|w| json_equal(v, w)))
        }
        _ => a == b,
    }
}

/// An array index token: `0` or digits without a leading zero, below `len` (or
/// equal to it when `allow_end`).
fn index(token: &str, len: usize, allow_end: bool) -> Result<usize, String> {
    let digits = !token.is_empty()
        && token.bytes().all(|b| b.is_ascii_digit())
        && (token == "0" || !token.starts_with('0'));
    let i = if digits {
        token.parse::<usize>().ok()
    } else {
        None
    };
    match i {
        Some(i) if i < len || (allow_end && i == len) => Ok(i),
        Some(i) => Err(format!("index {i} is out of bounds (array length {len})")),
        None => Err(format!("{token:?} is not an array index")),
    }
}

fn get_mut<'a>(doc: &'a mut Value, tokens: &[String]) -> Result<&'a mut Value, String> {
    let mut cur = doc;
    for (depth, t) in tokens.iter().enumerate() {
        let here = || Pointer(tokens[..=depth].to_vec());
        cur = match cur {
            Value::Object(m) => m
                .get_mut(t)
                .ok_or_else(|| format!("{} does not exist", here()))?,
            Value::Array(a) => {
                let len = a.len();
                let i = index(t, len, false).map_err(|e| format!("{}: {e}", here()))?;
                &mut a[i]
            }
            _ => {
                return Err(format!(
                    "{} does not exist (its parent is not an object or array)",
                    here()
                ));
            }
        };
    }
    Ok(cur)
}

fn split_last(path: &Pointer) -> Option<(&[String], &String)> {
    path.0.split_last().map(|(last, parent)| (parent, last))
}

fn add(doc: &mut Value, path: &Pointer, value: Value) -> Result<(), String> {
    let Some((parent, last)) = split_last(path) else {
        *doc = value;
        return Ok(());
    };
    match get_mut(doc, parent)? {
        Value::Object(m) => {
            m.insert(last.clone(), value);
            Ok(())
        }
        Value::Array(a) => {
            let i = if last == "-" {
                a.len()
            } else {
                index(last, a.len(), true)?
            };
            a.insert(i, value);
            Ok(())
        }
        _ => Err(format!(
            "{} is not an object or array",
            Pointer(parent.to_vec())
        )),
    }
}

fn remove(doc: &mut Value, path: &Pointer) -> Result<Value, String> {
    let Some((parent, last)) = split_last(path) else {
        return Err("cannot remove the whole document".into());
    };
    match get_mut(doc, parent)? {
        Value::Object(m) => m
            .remove(last)
            .ok_or_else(|| format!("{path} does not exist")),
        Value::Array(a) => {
            let i = index(last, a.len(), false)?;
            Ok(a.remove(i))
        }
        _ => Err(format!("{path} does not exist")),
    }
}

#[cfg(test)]
#[path = "patch_tests.rs"]
mod tests;
