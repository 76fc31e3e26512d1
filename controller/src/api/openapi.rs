//! OpenAPI v3 documents, as `kubectl` reads them before `apply`: the index
//! `/openapi/v3` and one document per group-version. Each kind's `patch`
//! operation lists the `fieldValidation` query parameter, which tells kubectl
//! that this server validates fields itself (it does: unknown fields are
//! rejected with their path), so `kubectl apply` needs no `--validate=false`.

use axum::Json;
use configbot_manifests::{API_VERSION, GROUP, Kind, VERSION, schema};
use serde_json::{Map, Value, json};

/// The group-version's path in the index, without the leading slash.
fn gv_path() -> String {
    format!("apis/{API_VERSION}")
}

/// `GET /openapi/v3`: where each group-version's document is.
pub async fn index() -> Json<Value> {
    let doc = document();
    // The hash only has to change when the document does (kubectl caches by it).
    let hash = fnv1a(doc.to_string().as_bytes());
    Json(json!({ "paths": {
        gv_path(): { "serverRelativeURL": format!("/openapi/v3/{}?hash={hash:016X}", gv_path()) }
    }}))
}

/// `GET /openapi/v3/apis/configbot.dev/v1alpha1`.
pub async fn group_version() -> Json<Value> {
    Json(document())
}

/// The OpenAPI document of `configbot.dev/v1alpha1` (pure).
pub fn document() -> Value {
    let mut paths = Map::new();
    let mut schemas = Map::new();
    for kind in Kind::ALL {
        let gvk = json!({ "group": GROUP, "version": VERSION, "kind": kind.name() });
        let schema_name = format!("dev.configbot.{VERSION}.{}", kind.name());
        let mut s = schema::openapi_schema(kind);
        if let Some(o) = s.as_object_mut() {
            o.insert(
                "x-kubernetes-group-version-kind".into(),
                json!([gvk.clone()]),
            );
        }
        schemas.insert(schema_name.clone(), s);
        let body = json!({ "content": { "application/json": {
            "schema": { "$ref": format!("#/components/schemas/{schema_name}") } } } });
        let ok = json!({ "200": { "description": "OK", "content": { "application/json": {
            "schema": { "$ref": format!("#/components/schemas/{schema_name}") } } } } });
        let op = |action: &str, with_body: bool| {
            let mut o = json!({
                "operationId": format!("{action}{}", kind.name()),
                "parameters": [
                    { "name": "fieldValidation", "in": "query", "schema": { "type": "string" },
                      "description": "Strict (default here): unknown or duplicate fields are rejected with their path." },
                    { "name": "dryRun", "in": "query", "schema": { "type": "string" } },
                ],
                "responses": ok,
                "x-kubernetes-action": action,
                "x-kubernetes-group-version-kind": gvk,
            });
            if with_body {
                o["requestBody"] = body.clone();
            }
            o
        };
        let base = format!(
            "/apis/{API_VERSION}/namespaces/{{namespace}}/{}",
            kind.plural()
        );
        paths.insert(base.clone(), json!({ "post": op("post", true) }));
        paths.insert(
            format!("{base}/{{name}}"),
            json!({ "get": op("get", false), "put": op("put", true), "patch": op("patch", true) }),
        );
    }
    json!({
        "openapi": "3.0.0",
        "info": { "title": "ConfigBot", "version": VERSION },
        "paths": paths,
        "components": { "schemas": schemas },
    })
}

/// 64-bit FNV-1a: a stable, dependency-free content hash.
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ u64::from(*b)).wrapping_mul(0x0100_0000_01b3)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_kind_has_a_patch_operation_with_field_validation() {
        let doc = document();
        for kind in Kind::ALL {
            let path = format!(
                "/apis/{API_VERSION}/namespaces/{{namespace}}/{}/{{name}}",
                kind.plural()
            );
            let patch = &doc["paths"][&path]["patch"];
            assert_eq!(
                patch["x-kubernetes-group-version-kind"]["kind"],
                kind.name()
            );
            let params = patch["parameters"].as_array().unwrap();
            assert!(params.iter().any(|p| p["name"] == "fieldValidation"));
        }
    }

    #[test]
    fn the_hash_follows_the_content() {
        assert_ne!(fnv1a(b"a"), fnv1a(b"b"));
        assert_eq!(fnv1a(b""), 0xcbf2_9ce4_8422_2325);
    }
}
