//! Property tests of the API's RFC 7386 JSON merge patch: on random
//! documents and patches, the result is what the RFC defines key by key,
//! applying a patch twice changes nothing more, and a patch that is not an
//! object replaces the target.

use configbot_controller::api::patch::merge_patch;
use proptest::prelude::*;
use serde_json::Value;

/// JSON values with keys from a small alphabet, so patches and targets share keys.
fn json() -> impl Strategy<Value = Value> {
    let leaf = prop_oneof![
        Just(Value::Null),
        any::<bool>().prop_map(Value::Bool),
        any::<i64>().prop_map(Value::from),
        "[a-z ]{0,6}".prop_map(Value::String),
    ];
    leaf.prop_recursive(5, 64, 5, |inner| {
        prop_oneof![
            prop::collection::vec(inner.clone(), 0..4).prop_map(Value::Array),
            prop::collection::btree_map("[a-e]", inner, 0..5)
                .prop_map(|m| Value::Object(m.into_iter().collect())),
        ]
    })
}

fn patched(target: &Value, patch: &Value) -> Value {
    let mut t = target.clone();
    merge_patch(&mut t, patch);
    t
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn follows_the_rfc_key_by_key(target in json(), patch in json()) {
        let out = patched(&target, &patch);
        let Value::Object(p) = &patch else {
            prop_assert_eq!(&out, &patch);
            return Ok(());
        };
        let Value::Object(o) = &out else {
            return Err(TestCaseError::fail(format!("an object patch gave {out}")));
        };
        let empty = serde_json::Map::new();
        let t = target.as_object().unwrap_or(&empty);
        for (k, v) in p {
            if v.is_null() {
                prop_assert!(!o.contains_key(k), "{} kept", k);
            } else {
                let before = t.get(k).cloned().unwrap_or(Value::Null);
                prop_assert_eq!(o.get(k), Some(&patched(&before, v)));
            }
        }
        for (k, v) in t {
            if !p.contains_key(k) {
                prop_assert_eq!(o.get(k), Some(v));
            }
        }
        prop_assert!(o.keys().all(|k| p.contains_key(k) || t.contains_key(k)));
    }

    #[test]
    fn is_idempotent(target in json(), patch in json()) {
        let once = patched(&target, &patch);
        prop_assert_eq!(patched(&once, &patch), once);
    }
}
