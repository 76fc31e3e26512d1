//! Label and field selectors (`-l robot=spot,stack!=terrain,gpu`, `metadata.name=x`).

use std::collections::BTreeMap;

/// One requirement of a selector.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Requirement {
    Equals(String, String),
    NotEquals(String, String),
    Exists(String),
    NotExists(String),
}

/// A parsed selector; empty selects everything.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Selector(pub Vec<Requirement>);

impl Selector {
    pub fn parse(text: &str) -> Result<Selector, String> {
        let mut reqs = Vec::new();
        for part in text.split(',').map(str::trim).filter(|p| !p.is_empty()) {
            let req = if let Some((k, v)) = part.split_once("!=") {
                Requirement::NotEquals(k.trim().into(), v.trim().into())
            } else if let Some((k, v)) = part.split_once("==").or_else(|| part.split_once('=')) {
                Requirement::Equals(k.trim().into(), v.trim().into())
            } else if let Some(k) = part.strip_prefix('!') {
                Requirement::NotExists(k.trim().into())
            } else {
                Requirement::Exists(part.into())
            };
            let key = match &req {
                Requirement::Equals(k, _)
                | Requirement::NotEquals(k, _)
                | Requirement::Exists(k)
                | Requirement::NotExists(k) => k,
            };
            if key.is_empty() || key.contains(' ') {
                return Err(format!("invalid selector requirement {part:?}"));
            }
            reqs.push(req);
        }
        Ok(Selector(reqs))
    }

    pub fn matches(&self, labels: &BTreeMap<String, String>) -> bool {
        self.0.iter().all(|r| match r {
            Requirement::Equals(k, v) => labels.get(k) == Some(v),
            Requirement::NotEquals(k, v) => labels.get(k) != Some(v),
            Requirement::Exists(k) => labels.contains_key(k),
            Requirement::NotExists(k) => !labels.contains_key(k),
        })
    }

    /// Match against a JSON object's `metadata.labels`.
    pub fn matches_object(&self, obj: &serde_json::Value) -> bool {
        let labels = obj["metadata"]["labels"]
            .as_object()
            .map(|m| {
                m.iter()
                    .map(|(k, v)| (k.clone(), v.as_str().unwrap_or("").to_string()))
                    .collect()
            })
            .unwrap_or_default();
        self.matches(&labels)
    }

    /// Match a field selector against flattened fields (`metadata.name` → value).
    pub fn matches_fields(&self, fields: &BTreeMap<String, String>) -> bool {
        self.matches(fields)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn selector_table() {
        let labels: BTreeMap<String, String> = [
            ("robot".to_string(), "spot".to_string()),
            ("gpu".into(), "".into()),
        ]
        .into();
        for (sel, want) in [
            ("", true),
            ("robot=spot", true),
            ("robot==spot", true),
            ("robot=jackal", false),
            ("robot!=jackal", true),
            ("gpu", true),
            ("!gpu", false),
            ("robot=spot,site", false),
            ("!site,robot=spot", true),
        ] {
            assert_eq!(
                Selector::parse(sel).unwrap().matches(&labels),
                want,
                "{sel}"
            );
        }
        assert!(Selector::parse("a b").is_err());
    }
}
