//! Property tests of the YAML loader (`yaml::parse_documents`), which reads
//! manifests from files, standard input and API bodies: JSON documents (YAML
//! 1.2 is a superset) read back as the same value, any text is read or
//! refused without panicking, and nesting past [`MAX_NESTING`] is refused
//! rather than recursed into (before the limit, 60 levels overflowed a test
//! thread's stack).

use configbot_manifests::yaml::{MAX_NESTING, parse_documents};
use proptest::prelude::*;
use serde_json::Value;

fn json() -> impl Strategy<Value = Value> {
    let leaf = prop_oneof![
        Just(Value::Null),
        any::<bool>().prop_map(Value::Bool),
        any::<i64>().prop_map(Value::from),
        any::<String>().prop_map(Value::String),
    ];
    leaf.prop_recursive(5, 64, 5, |inner| {
        prop_oneof![
            prop::collection::vec(inner.clone(), 0..4).prop_map(Value::Array),
            prop::collection::btree_map("[a-z_]{1,8}", inner, 0..5)
                .prop_map(|m| Value::Object(m.into_iter().collect())),
        ]
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn json_documents_read_back_as_the_same_value(
        doc in prop::collection::btree_map("[a-z_]{1,8}", json(), 1..5)
    ) {
        let v = Value::Object(doc.into_iter().collect());
        for text in [serde_json::to_string(&v).unwrap(), serde_json::to_string_pretty(&v).unwrap()] {
            let docs = parse_documents(&text).map_err(|e| TestCaseError::fail(format!("{}: {text}", e.message)))?;
            prop_assert_eq!(docs.len(), 1);
            prop_assert_eq!(&docs[0].value, &v);
        }
    }

    #[test]
    fn any_text_is_read_or_refused(text in any::<String>(), lines in prop::collection::vec("[ -]{0,4}[a-z:\\[\\]{},&*!|>'\"#-]{0,8}", 0..20)) {
        let _ = parse_documents(&text);
        let _ = parse_documents(&lines.join("\n"));
    }

    #[test]
    fn nesting_is_refused_exactly_past_the_limit(depth in 1usize..50_000, flow in any::<bool>()) {
        let text = if flow {
            format!("{}{}", "[".repeat(depth), "]".repeat(depth))
        } else {
            // `- - - x`: compact nested block sequences.
            format!("{}x", "- ".repeat(depth))
        };
        let r = parse_documents(&text);
        prop_assert_eq!(r.is_ok(), depth <= MAX_NESTING, "{:?}", r.err().map(|e| e.message));
    }
}
