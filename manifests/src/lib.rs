//! ConfigBot's typed API: the `RobotStack`, `PerformanceSpec` and `ConfigProfile` manifests,
//! their parsing with precise errors (file, document, field path, line:column),
//! semantic validation and defaults. No IO beyond reading text.
//!
//! Pipeline: text → [`yaml::parse_documents`] (located JSON) → [`decode`]
//! (typed, unknown fields rejected) → [`validate::validate`] (all rule
//! violations at once). [`load`] runs all three and maps every error to a line.

pub mod config;
pub mod config_profile;
pub mod kind;
pub mod meta;
pub mod names;
pub mod performance_spec;
pub mod robot_stack;
pub mod schema;
pub mod validate;
pub mod vocab;
pub mod yaml;

use std::fmt;

pub use config::{AdaptorRate, ResourceConfig};
pub use config_profile::{ConfigProfile, ConfigProfileSpec, ProfileContext, ProfileTrial};
pub use kind::Kind;
pub use meta::{
    API_VERSION, Condition, ConditionStatus, DEFAULT_NAMESPACE, GROUP, ObjectMeta, VERSION,
};
pub use performance_spec::{PerformanceSpec, PerformanceSpecSpec, PerformanceSpecStatus};
pub use robot_stack::{RobotStack, RobotStackSpec, RobotStackStatus};
pub use validate::FieldError;
pub use vocab::{Phase, Reason, StackPhase};

/// A decoded manifest of any kind.
#[allow(clippy::large_enum_variant)] // short-lived values; boxing would only add noise
#[derive(Debug, Clone, PartialEq)]
pub enum Manifest {
    RobotStack(RobotStack),
    PerformanceSpec(PerformanceSpec),
    ConfigProfile(ConfigProfile),
}

impl Manifest {
    pub fn kind(&self) -> Kind {
        match self {
            Manifest::RobotStack(_) => Kind::RobotStack,
            Manifest::PerformanceSpec(_) => Kind::PerformanceSpec,
            Manifest::ConfigProfile(_) => Kind::ConfigProfile,
        }
    }

    pub fn metadata(&self) -> &ObjectMeta {
        match self {
            Manifest::RobotStack(s) => &s.metadata,
            Manifest::PerformanceSpec(p) => &p.metadata,
            Manifest::ConfigProfile(c) => &c.metadata,
        }
    }

    /// The object as JSON, the form the control plane stores.
    pub fn to_json(&self) -> serde_json::Value {
        let v = match self {
            Manifest::RobotStack(s) => serde_json::to_value(s),
            Manifest::PerformanceSpec(p) => serde_json::to_value(p),
            Manifest::ConfigProfile(c) => serde_json::to_value(c),
        };
        // Serializing plain data types into a JSON value cannot fail.
        v.unwrap_or(serde_json::Value::Null)
    }
}

/// Decode a JSON object into a typed manifest. Errors carry the field path.
pub fn decode(value: &serde_json::Value) -> Result<Manifest, FieldError> {
    let field = |path: &str, message: String| FieldError {
        path: path.into(),
        message,
    };
    let obj = value
        .as_object()
        .ok_or_else(|| field("", "a manifest must be a mapping".into()))?;
    let api_version = match obj.get("apiVersion") {
        Some(serde_json::Value::String(s)) => s.as_str(),
        Some(_) => return Err(field("apiVersion", "must be a string".into())),
        None => return Err(field("apiVersion", format!("missing; use {API_VERSION:?}"))),
    };
    if api_version != API_VERSION {
        return Err(field(
            "apiVersion",
            format!("{api_version:?} is not served; use {API_VERSION:?}"),
        ));
    }
    let kind_name = match obj.get("kind") {
        Some(serde_json::Value::String(s)) => s.as_str(),
        Some(_) => return Err(field("kind", "must be a string".into())),
        None => return Err(field("kind", "missing".into())),
    };
    let kind = Kind::from_name(kind_name).ok_or_else(|| {
        field(
            "kind",
            format!(
                "unknown kind {kind_name:?}; expected one of {}",
                Kind::ALL.map(Kind::name).join(", ")
            ),
        )
    })?;
    match kind {
        Kind::RobotStack => typed(value).map(Manifest::RobotStack),
        Kind::PerformanceSpec => typed(value).map(Manifest::PerformanceSpec),
        Kind::ConfigProfile => typed(value).map(Manifest::ConfigProfile),
    }
}

fn typed<T: serde::de::DeserializeOwned>(value: &serde_json::Value) -> Result<T, FieldError> {
    serde_path_to_error::deserialize(value).map_err(|e| {
        let path = e.path().to_string();
        let path = if path == "." { String::new() } else { path };
        FieldError {
            path,
            message: e.into_inner().to_string(),
        }
    })
}

/// The `status` of a stored object as `T` (PerformanceSpecStatus,
/// RobotStackStatus), or its default when the object has none yet.
pub fn decode_status<T: serde::de::DeserializeOwned + Default>(
    obj: &serde_json::Value,
) -> Result<T, serde_json::Error> {
    match obj.get("status") {
        None | Some(serde_json::Value::Null) => Ok(T::default()),
        Some(status) => T::deserialize(status),
    }
}

/// Decode and validate one JSON object (the API server's entry point).
pub fn decode_and_validate(value: &serde_json::Value) -> Result<Manifest, Vec<FieldError>> {
    let m = decode(value).map_err(|e| vec![e])?;
    let errors = validate::validate(&m);
    if errors.is_empty() {
        Ok(m)
    } else {
        Err(errors)
    }
}

/// An error located in a manifest input.
#[derive(Debug, Clone, PartialEq)]
pub struct ManifestError {
    /// File name, `-` for standard input, or a request description.
    pub source: String,
    /// 1-based document index, when known.
    pub document: Option<usize>,
    /// Field path such as `spec.apps[1].nodes[0].name`; empty for the whole document.
    pub path: String,
    pub line: Option<u64>,
    pub column: Option<u64>,
    pub message: String,
}

impl fmt::Display for ManifestError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.source)?;
        if let Some(l) = self.line {
            write!(f, ":{l}")?;
            if let Some(c) = self.column {
                write!(f, ":{c}")?;
            }
        }
        if let Some(d) = self.document {
            write!(f, ": document {d}")?;
        }
        if !self.path.is_empty() {
            write!(f, ": {}", self.path)?;
        }
        write!(f, ": {}", self.message)
    }
}

/// All errors found in an input; non-empty.
#[derive(Debug, Clone, PartialEq)]
pub struct ManifestErrors(pub Vec<ManifestError>);

impl fmt::Display for ManifestErrors {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, e) in self.0.iter().enumerate() {
            if i > 0 {
                writeln!(f)?;
            }
            write!(f, "{e}")?;
        }
        Ok(())
    }
}

impl std::error::Error for ManifestErrors {}

/// A manifest read from text, with its source position.
#[derive(Debug, Clone)]
pub struct Loaded {
    pub manifest: Manifest,
    /// The document as written (no defaults filled in): what `apply` sends.
    pub value: serde_json::Value,
    pub source: String,
    pub document: usize,
    /// `items[N].` when the manifest is item N of a `v1` `List` document
    /// (what `get -o yaml` prints for a list), else empty.
    pub path_prefix: String,
}

/// The manifests of one document: the document itself, or the items of a
/// `v1` `List`, each with the path prefix its errors get.
fn manifests_of(value: &serde_json::Value) -> Vec<(String, &serde_json::Value)> {
    if value["kind"] == "List" && value["apiVersion"] == "v1" {
        match value["items"].as_array() {
            Some(items) => items
                .iter()
                .enumerate()
                .map(|(i, item)| (format!("items[{i}]."), item))
                .collect(),
            None => vec![(String::new(), value)],
        }
    } else {
        vec![(String::new(), value)]
    }
}

/// `prefix` + `path`, without a dangling dot.
fn prefixed(prefix: &str, path: &str) -> String {
    if path.is_empty() || path.starts_with('[') {
        format!("{}{path}", prefix.trim_end_matches('.'))
    } else {
        format!("{prefix}{path}")
    }
}

/// Parse, decode and validate every document of `text`. Either every document
/// is good, or every error found is returned (nothing is half-accepted).
pub fn load(source: &str, text: &str) -> Result<Vec<Loaded>, ManifestErrors> {
    let docs = yaml::parse_documents(text).map_err(|e| {
        ManifestErrors(vec![ManifestError {
            source: source.into(),
            document: None,
            path: String::new(),
            line: e.pos.map(|p| p.line),
            column: e.pos.map(|p| p.column),
            message: e.message,
        }])
    })?;
    let mut out = Vec::new();
    let mut errors = Vec::new();
    for doc in &docs {
        for (prefix, value) in manifests_of(&doc.value) {
            let located = |fe: FieldError| {
                let path = prefixed(&prefix, &fe.path);
                let pos = doc.position_of(&path);
                ManifestError {
                    source: source.into(),
                    document: Some(doc.index),
                    path,
                    line: pos.map(|p| p.line),
                    column: pos.map(|p| p.column),
                    message: fe.message,
                }
            };
            let decoded = match value.as_str() {
                // `--- ---`: YAML reads the second marker as a scalar document.
                Some(text) if text.starts_with("---") => Err(vec![FieldError {
                    path: String::new(),
                    message: format!(
                        "invalid document separator {text:?}: \"---\" must stand alone on its line"
                    ),
                }]),
                _ => decode_and_validate(value),
            };
            match decoded {
                Ok(manifest) => out.push(Loaded {
                    manifest,
                    value: value.clone(),
                    source: source.into(),
                    document: doc.index,
                    path_prefix: prefix.clone(),
                }),
                Err(es) => errors.extend(es.into_iter().map(located)),
            }
        }
    }
    // Cross-document checks: a spec against a stack given in the same input.
    for l in &out {
        let Manifest::PerformanceSpec(p) = &l.manifest else {
            continue;
        };
        let stack = out.iter().find_map(|o| match &o.manifest {
            Manifest::RobotStack(s)
                if s.metadata.name == p.spec.stack_ref.name
                    && s.metadata.namespace() == p.metadata.namespace() =>
            {
                Some(s)
            }
            _ => None,
        });
        if let Some(stack) = stack {
            let doc = docs.iter().find(|d| d.index == l.document);
            for fe in validate::validate_against_stack(p, stack) {
                let path = prefixed(&l.path_prefix, &fe.path);
                let pos = doc.and_then(|d| d.position_of(&path));
                errors.push(ManifestError {
                    source: source.into(),
                    document: Some(l.document),
                    path,
                    line: pos.map(|p| p.line),
                    column: pos.map(|p| p.column),
                    message: fe.message,
                });
            }
        }
    }
    if errors.is_empty() {
        Ok(out)
    } else {
        Err(ManifestErrors(errors))
    }
}
