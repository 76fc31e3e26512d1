//! Tables from RFC 6902 Appendix A and RFC 7386 Appendix A, and a seeded
//! property test of JSON patch over random documents.

use super::*;

fn ops(v: Value) -> Vec<Op> {
    parse_ops(&v).unwrap()
}

fn patched(doc: Value, p: Value) -> Result<Value, OpError> {
    json_patch(&doc, &ops(p))
}

#[test]
fn merge_patch_follows_rfc7386() {
    let mut t = json!({"a": "b", "c": {"d": "e", "f": "g"}});
    merge_patch(&mut t, &json!({"a": "z", "c": {"f": null}}));
    assert_eq!(t, json!({"a": "z", "c": {"d": "e"}}));
    let mut t = json!({"a": [1, 2]});
    merge_patch(&mut t, &json!({"a": [3]}));
    assert_eq!(t, json!({"a": [3]}));
}

#[test]
fn json_patch_follows_rfc6902_appendix_a() {
    let ok = [
        // A.1 .. A.10
        (
            json!({"foo": "bar"}),
            json!([{"op": "add", "path": "/baz", "value": "qux"}]),
            json!({"baz": "qux", "foo": "bar"}),
        ),
        (
            json!({"foo": ["bar", "baz"]}),
            json!([{"op": "add", "path": "/foo/1", "value": "qux"}]),
            json!({"foo": ["bar", "qux", "baz"]}),
        ),
        (
            json!({"baz": "qux", "foo": "bar"}),
            json!([{"op": "remove", "path": "/baz"}]),
            json!({"foo": "bar"}),
        ),
        (
            json!({"foo": ["bar", "qux", "baz"]}),
            json!([{"op": "remove", "path": "/foo/1"}]),
            json!({"foo": ["bar", "baz"]}),
        ),
        (
            json!({"baz": "qux", "foo": "bar"}),
            json!([{"op": "replace", "path": "/baz", "value": "boo"}]),
            json!({"baz": "boo", "foo": "bar"}),
        ),
        (
            json!({"foo": {"bar": "baz", "waldo": "fred"}, "qux": {"corge": "grault"}}),
            json!([{"op": "move", "from": "/foo/waldo", "path": "/qux/thud"}]),
            json!({"foo": {"bar": "baz"}, "qux": {"corge": "grault", "thud": "fred"}}),
        ),
        (
            json!({"foo": ["all", "grass", "cows", "eat"]}),
            json!([{"op": "move", "from": "/foo/1", "path": "/foo/3"}]),
            json!({"foo": ["all", "cows", "eat", "grass"]}),
        ),
        (
            json!({"baz": "qux", "foo": ["a", 2, "c"]}),
            json!([{"op": "test", "path": "/baz", "value": "qux"}, {"op": "test", "path": "/foo/1", "value": 2}]),
            json!({"baz": "qux", "foo": ["a", 2, "c"]}),
        ),
        (
            json!({"foo": "bar"}),
            json!([{"op": "add", "path": "/child", "value": {"grandchild": {}}}]),
            json!({"foo": "bar", "child": {"grandchild": {}}}),
        ),
        // A.11: members other than op, path, value, from are ignored.
        (
            json!({"foo": "bar"}),
            json!([{"op": "add", "path": "/baz", "value": "qux", "xyz": 123}]),
            json!({"foo": "bar", "baz": "qux"}),
        ),
        // A.14: ~0 and ~1 escapes.
        (
            json!({"/": 9, "~1": 10}),
            json!([{"op": "test", "path": "/~01", "value": 10}]),
            json!({"/": 9, "~1": 10}),
        ),
        // A.16: append with "-".
        (
            json!({"foo": ["bar"]}),
            json!([{"op": "add", "path": "/foo/-", "value": ["abc", "def"]}]),
            json!({"foo": ["bar", ["abc", "def"]]}),
        ),
        // Numbers compare by value; the whole document can be replaced.
        (
            json!({"n": 1}),
            json!([{"op": "test", "path": "/n", "value": 1.0}]),
            json!({"n": 1}),
        ),
        (
            json!({"a": 1}),
            json!([{"op": "add", "path": "", "value": {"b": 2}}]),
            json!({"b": 2}),
        ),
        (
            json!({"a": {"b": 1}}),
            json!([{"op": "copy", "from": "/a", "path": "/c"}]),
            json!({"a": {"b": 1}, "c": {"b": 1}}),
        ),
    ];
    for (doc, p, want) in ok {
        assert_eq!(patched(doc.clone(), p.clone()), Ok(want), "{doc} + {p}");
    }
    let failing = [
        // A.9, A.12, A.13 (as a number, not a string), A.15
        (
            json!({"baz": "qux"}),
            json!([{"op": "test", "path": "/baz", "value": "bar"}]),
            0,
            "test failed",
        ),
        (
            json!({"foo": "bar"}),
            json!([{"op": "add", "path": "/baz/bat", "value": "qux"}]),
            0,
            "/baz does not exist",
        ),
        (
            json!({"/": 9, "~1": 10}),
            json!([{"op": "test", "path": "/~01", "value": "10"}]),
            0,
            "test failed",
        ),
        (
            json!({"foo": ["bar"]}),
            json!([{"op": "add", "path": "/foo/2", "value": 1}]),
            0,
            "out of bounds",
        ),
        (
            json!({"foo": ["bar"]}),
            json!([{"op": "remove", "path": "/foo/01"}]),
            0,
            "not an array index",
        ),
        (
            json!({"foo": 1}),
            json!([{"op": "replace", "path": "/bar", "value": 2}]),
            0,
            "/bar does not exist",
        ),
        (
            json!({"a": {"b": 1}}),
            json!([{"op": "move", "from": "/a", "path": "/a/b/c"}]),
            0,
            "own child",
        ),
        (
            json!({"a": 1}),
            json!([{"op": "remove", "path": "/a"}, {"op": "remove", "path": "/a"}]),
            1,
            "/a does not exist",
        ),
    ];
    for (doc, p, at, message) in failing {
        let err = patched(doc.clone(), p.clone()).unwrap_err();
        assert_eq!(err.index, Some(at), "{doc} + {p}: {err}");
        assert!(err.to_string().contains(message), "{doc} + {p}: {err}");
    }
}

#[test]
fn op_errors_name_the_field() {
    let err = patched(
        json!({"spec": {"apps": [{"name": "a"}]}}),
        json!([{"op": "test", "path": "/spec/apps/0/name", "value": "b"}]),
    )
    .unwrap_err();
    assert_eq!(err.field(), "spec.apps[0].name");
    assert_eq!(
        err.cause(),
        "patch operation 0 (test): test failed: the value is \"a\", not \"b\""
    );
}

#[test]
fn malformed_json_patches_are_refused_with_the_operation_named() {
    for (body, message) in [
        (r#"{"op": "add"}"#, "array of operations"),
        (
            r#"[{"path": "/a", "value": 1}]"#,
            "operation 0: missing member \"op\"",
        ),
        (
            r#"[{"op": "add", "path": "/a", "value": 1}, {"op": "add", "path": "/b"}]"#,
            "operation 1: missing member \"value\"",
        ),
        (r#"[{"op": "frobnicate", "path": "/a"}]"#, "unknown op"),
        (
            r#"[{"op": "remove", "path": "a"}]"#,
            "must be empty or start with '/'",
        ),
        (
            r#"[{"op": "remove", "path": "/a~2"}]"#,
            "'~' must be followed by 0 or 1",
        ),
        (
            r#"[{"op": "move", "path": "/a"}]"#,
            "missing member \"from\"",
        ),
        ("[", "not JSON"),
    ] {
        let err = Patch::parse("application/json-patch+json", body.as_bytes()).unwrap_err();
        assert!(err.to_string().contains(message), "{body}: {err}");
    }
    assert!(matches!(
        Patch::parse("application/strategic-merge-patch+json", b"{}"),
        Err(PatchBodyError::UnsupportedType(_))
    ));
    assert_eq!(
        Patch::parse("application/merge-patch+json; charset=utf-8", b"{\"a\":1}"),
        Ok(Patch::Merge(json!({"a": 1})))
    );
}

/// A small seeded generator (xorshift64*), so the property test needs no crate.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
    fn key(&mut self) -> String {
        ["a", "b", "c/d", "e~f", "0", "-"][self.below(6)].to_string()
    }
    fn value(&mut self, depth: u32) -> Value {
        match if depth == 0 {
            self.below(3)
        } else {
            self.below(5)
        } {
            0 => json!(self.below(100)),
            1 => json!(self.key()),
            2 => Value::Null,
            3 => Value::Array((0..self.below(4)).map(|_| self.value(depth - 1)).collect()),
            _ => Value::Object(
                (0..self.below(4))
                    .map(|_| (self.key(), self.value(depth - 1)))
                    .collect(),
            ),
        }
    }
}

/// Every location in `v`, as pointers.
fn locations(v: &Value, at: &mut Vec<String>, out: &mut Vec<Pointer>) {
    out.push(Pointer(at.clone()));
    match v {
        Value::Object(m) => {
            for (k, c) in m {
                at.push(k.clone());
                locations(c, at, out);
                at.pop();
            }
        }
        Value::Array(a) => {
            for (i, c) in a.iter().enumerate() {
                at.push(i.to_string());
                locations(c, at, out);
                at.pop();
            }
        }
        _ => {}
    }
}

fn value_at(v: &Value, p: &Pointer) -> Value {
    let mut v = v.clone();
    get_mut(&mut v, &p.0).unwrap().clone()
}

/// Over random documents and locations: a replace is seen by a test at the
/// same place; add then remove of a new member restores the document; copy
/// puts an equal value at the target; a patch whose last operation fails
/// is reported at that operation; pointers survive Display and parse.
#[test]
fn json_patch_properties_hold_on_random_documents() {
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    for _ in 0..500 {
        let doc = json!({"root": rng.value(3)});
        let mut all = Vec::new();
        locations(&doc, &mut Vec::new(), &mut all);
        let all: Vec<Pointer> = all.into_iter().filter(|p| !p.0.is_empty()).collect();
        let p = all[rng.below(all.len())].clone();
        assert_eq!(Pointer::parse(&p.to_string()), Ok(p.clone()));
        let v = rng.value(2);

        let after = json_patch(
            &doc,
            &[
                Op::Replace {
                    path: p.clone(),
                    value: v.clone(),
                },
                Op::Test {
                    path: p.clone(),
                    value: v.clone(),
                },
            ],
        )
        .unwrap();
        assert!(json_equal(&value_at(&after, &p), &v));

        let object_parents: Vec<&Pointer> = all
            .iter()
            .filter(|q| value_at(&doc, q).is_object())
            .collect();
        if let Some(parent) = object_parents.get(rng.below(object_parents.len().max(1))) {
            let mut fresh = (*parent).clone();
            fresh.0.push("new/~member".into());
            let back = json_patch(
                &doc,
                &[
                    Op::Add {
                        path: fresh.clone(),
                        value: v.clone(),
                    },
                    Op::Remove { path: fresh },
                ],
            )
            .unwrap();
            assert_eq!(back, doc);
        }

        let target = Pointer(vec!["copy".into()]);
        let copied = json_patch(
            &doc,
            &[Op::Copy {
                from: p.clone(),
                path: target.clone(),
            }],
        )
        .unwrap();
        assert_eq!(value_at(&copied, &target), value_at(&doc, &p));

        let failing = [
            Op::Replace {
                path: p.clone(),
                value: v.clone(),
            },
            Op::Remove {
                path: Pointer(vec!["copy".into()]),
            },
        ];
        let err = json_patch(&doc, &failing).unwrap_err();
        assert_eq!(
            (err.index, err.op, err.path.as_str()),
            (Some(1), "remove", "/copy")
        );
    }
}
