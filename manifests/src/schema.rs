//! JSON Schemas generated from the types: one per kind for editors (`schema/`),
//! and the OpenAPI v3 form used in the CRDs and the API server's discovery.

use schemars::generate::SchemaSettings;

use crate::{ConfigProfile, Kind, PerformanceSpec, RobotStack};

/// The JSON Schema (draft 2020-12) of a kind, as pretty JSON with a trailing newline.
pub fn json_schema(kind: Kind) -> String {
    let generator = SchemaSettings::draft2020_12().into_generator();
    let schema = match kind {
        Kind::RobotStack => generator.into_root_schema_for::<RobotStack>(),
        Kind::PerformanceSpec => generator.into_root_schema_for::<PerformanceSpec>(),
        Kind::ConfigProfile => generator.into_root_schema_for::<ConfigProfile>(),
    };
    let mut text = serde_json::to_string_pretty(&schema).unwrap_or_default();
    text.push('\n');
    text
}

/// The schema's file name under `schema/`.
pub fn file_name(kind: Kind) -> String {
    format!("{}.schema.json", kind.singular())
}

/// The kind's schema in the OpenAPI v3 subset Kubernetes accepts (everything inlined).
pub fn openapi_schema(kind: Kind) -> serde_json::Value {
    let mut settings = SchemaSettings::openapi3();
    settings.inline_subschemas = true;
    let generator = settings.into_generator();
    let schema = match kind {
        Kind::RobotStack => generator.into_root_schema_for::<RobotStack>(),
        Kind::PerformanceSpec => generator.into_root_schema_for::<PerformanceSpec>(),
        Kind::ConfigProfile => generator.into_root_schema_for::<ConfigProfile>(),
    };
    let mut v = schema.to_value();
    if let Some(o) = v.as_object_mut() {
        o.remove("$schema");
        o.remove("title");
    }
    v
}

/// The kind as a Kubernetes CustomResourceDefinition (for `charts/`), so the
/// same manifests can live in a real cluster's GitOps repository.
pub fn crd(kind: Kind) -> serde_json::Value {
    let mut schema = openapi_schema(kind);
    if let Some(o) = schema.as_object_mut() {
        o.remove("description");
    }
    let columns: Vec<serde_json::Value> = kind
        .printer_columns()
        .iter()
        .map(|c| {
            let mut col =
                serde_json::json!({"name": c.name, "type": c.type_, "jsonPath": c.json_path});
            if c.wide {
                col["priority"] = 1.into();
            }
            col
        })
        .chain(std::iter::once(serde_json::json!({
            "name": "Age", "type": "date", "jsonPath": ".metadata.creationTimestamp"
        })))
        .collect();
    serde_json::json!({
        "apiVersion": "apiextensions.k8s.io/v1",
        "kind": "CustomResourceDefinition",
        "metadata": {"name": format!("{}.{}", kind.plural(), crate::GROUP)},
        "spec": {
            "group": crate::GROUP,
            "scope": "Namespaced",
            "names": {
                "kind": kind.name(),
                "plural": kind.plural(),
                "singular": kind.singular(),
                "shortNames": kind.short_names(),
                "categories": ["configbot"],
            },
            "versions": [{
                "name": crate::VERSION,
                "served": true,
                "storage": true,
                "subresources": {"status": {}},
                "additionalPrinterColumns": columns,
                "schema": {"openAPIV3Schema": schema},
            }],
        },
    })
}

/// The CRD's file name under `charts/configbot/crds/`.
pub fn crd_file_name(kind: Kind) -> String {
    format!("{}.{}.yaml", kind.plural(), crate::GROUP)
}
