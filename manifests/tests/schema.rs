//! The checked-in JSON Schemas (`schema/`) and CRDs (`charts/configbot/crds/`)
//! are exactly what the types generate. Regenerate with
//! `CONFIGBOT_UPDATE_SCHEMAS=1 cargo test -p configbot-manifests --test schema`.

use std::fs;
use std::path::{Path, PathBuf};

use configbot_manifests::{Kind, schema};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn check(path: PathBuf, generated: String, stale: &mut Vec<String>) {
    if std::env::var_os("CONFIGBOT_UPDATE_SCHEMAS").is_some() {
        fs::create_dir_all(path.parent().unwrap()).unwrap();
        fs::write(&path, generated).unwrap();
    } else if fs::read_to_string(&path).ok().as_deref() != Some(generated.as_str()) {
        stale.push(path.display().to_string());
    }
}

#[test]
fn checked_in_schemas_are_fresh() {
    let mut stale = Vec::new();
    for kind in Kind::ALL {
        check(
            repo().join("schema").join(schema::file_name(kind)),
            schema::json_schema(kind),
            &mut stale,
        );
        let crd = serde_saphyr::to_string(&schema::crd(kind)).unwrap();
        let text = format!(
            "# Generated from the Rust types by manifests/tests/schema.rs; do not edit.\n{crd}"
        );
        check(
            repo()
                .join("charts/configbot/crds")
                .join(schema::crd_file_name(kind)),
            text,
            &mut stale,
        );
    }
    assert!(
        stale.is_empty(),
        "stale generated files (run CONFIGBOT_UPDATE_SCHEMAS=1 cargo test -p configbot-manifests --test schema): {stale:?}"
    );
}

#[test]
fn schema_pins_the_api_version_and_rejects_unknown_fields() {
    let s: serde_json::Value =
        serde_json::from_str(&schema::json_schema(Kind::RobotStack)).unwrap();
    assert_eq!(s["additionalProperties"], false);
    assert_eq!(configbot_manifests::API_VERSION, "configbot.dev/v1alpha1");
}
