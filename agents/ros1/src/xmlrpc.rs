//! A small XML-RPC codec: values, method calls and responses (including
//! faults), enough for the ROS master, parameter server and slave APIs.
//! Pure: bytes in, values out. Documents nested deeper than
//! [`MAX_XML_DEPTH`] elements, or with more than [`MAX_XML_TOKENS`] tags and
//! texts, are refused before any value is built, so the recursive decoder's
//! stack and memory stay bounded whatever a peer sends.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use serde::{Deserialize, Serialize};

use crate::limits::{MAX_XML_DEPTH, MAX_XML_TOKENS};

/// An XML-RPC value.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Value {
    Int(i64),
    Bool(bool),
    Str(String),
    Double(f64),
    /// dateTime.iso8601, kept as text.
    DateTime(String),
    /// base64, kept as text.
    Base64(String),
    Array(Vec<Value>),
    Struct(BTreeMap<String, Value>),
    Nil,
}

impl Value {
    pub fn as_str(&self) -> Option<&str> {
        match self {
            Value::Str(s) => Some(s),
            _ => None,
        }
    }
    pub fn as_i64(&self) -> Option<i64> {
        match self {
            Value::Int(i) => Some(*i),
            _ => None,
        }
    }
    pub fn as_array(&self) -> Option<&[Value]> {
        match self {
            Value::Array(a) => Some(a),
            _ => None,
        }
    }
    /// How many values nest here: 1 for a scalar or an empty container.
    /// Recursive; decoded values are bounded by [`MAX_XML_DEPTH`].
    pub fn depth(&self) -> usize {
        1 + match self {
            Value::Array(a) => a.iter().map(Value::depth).max().unwrap_or(0),
            Value::Struct(m) => m.values().map(Value::depth).max().unwrap_or(0),
            _ => 0,
        }
    }
    pub fn str(s: impl Into<String>) -> Value {
        Value::Str(s.into())
    }
    /// The ROS API's `[code, statusMessage, value]` triple.
    pub fn ros(code: i64, msg: impl Into<String>, v: Value) -> Value {
        Value::Array(vec![Value::Int(code), Value::Str(msg.into()), v])
    }
}

/// A decoded `methodCall`.
#[derive(Debug, Clone, PartialEq)]
pub struct MethodCall {
    pub method: String,
    pub params: Vec<Value>,
}

/// A decoded `methodResponse`.
#[derive(Debug, Clone, PartialEq)]
pub enum Response {
    Ok(Value),
    Fault { code: i64, message: String },
}

/// Errors of the codec.
#[derive(Debug, thiserror::Error)]
pub enum XmlRpcError {
    #[error("malformed xml-rpc at byte {pos}: {what}")]
    Malformed { pos: usize, what: String },
}

// ---------- encoding ----------

fn escape(out: &mut String, s: &str) {
    for c in s.chars() {
        match c {
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '&' => out.push_str("&amp;"),
            '"' => out.push_str("&quot;"),
            '\r' => out.push_str("&#13;"),
            c => out.push(c),
        }
    }
}

fn encode_value(out: &mut String, v: &Value) {
    out.push_str("<value>");
    match v {
        Value::Int(i) => {
            if i32::try_from(*i).is_ok() {
                let _ = write!(out, "<i4>{i}</i4>");
            } else {
                let _ = write!(out, "<i8>{i}</i8>");
            }
        }
        Value::Bool(b) => {
            let _ = write!(out, "<boolean>{}</boolean>", u8::from(*b));
        }
        Value::Str(s) => {
            out.push_str("<string>");
            escape(out, s);
            out.push_str("</string>");
        }
        Value::Double(d) => {
            let _ = write!(out, "<double>{d:?}</double>");
        }
        Value::DateTime(s) => {
            out.push_str("<dateTime.iso8601>");
            escape(out, s);
            out.push_str("</dateTime.iso8601>");
        }
        Value::Base64(s) => {
            out.push_str("<base64>");
            escape(out, s);
            out.push_str("</base64>");
        }
        Value::Array(a) => {
            out.push_str("<array><data>");
            for x in a {
                encode_value(out, x);
            }
            out.push_str("</data></array>");
        }
        Value::Struct(m) => {
            out.push_str("<struct>");
            for (k, x) in m {
                out.push_str("<member><name>");
                escape(out, k);
                out.push_str("</name>");
                encode_value(out, x);
                out.push_str("</member>");
            }
            out.push_str("</struct>");
        }
        Value::Nil => out.push_str("<nil/>"),
    }
    out.push_str("</value>");
}

/// Encodes a method call.
pub fn encode_call(method: &str, params: &[Value]) -> String {
    let mut out = String::from("<?xml version=\"1.0\"?>\n<methodCall><methodName>");
    escape(&mut out, method);
    out.push_str("</methodName><params>");
    for p in params {
        out.push_str("<param>");
        encode_value(&mut out, p);
        out.push_str("</param>");
    }
    out.push_str("</params></methodCall>\n");
    out
}

/// Encodes a response.
pub fn encode_response(r: &Response) -> String {
    let mut out = String::from("<?xml version=\"1.0\"?>\n<methodResponse>");
    match r {
        Response::Ok(v) => {
            out.push_str("<params><param>");
            encode_value(&mut out, v);
            out.push_str("</param></params>");
        }
        Response::Fault { code, message } => {
            let mut m = BTreeMap::new();
            m.insert("faultCode".to_string(), Value::Int(*code));
            m.insert("faultString".to_string(), Value::Str(message.clone()));
            out.push_str("<fault>");
            encode_value(&mut out, &Value::Struct(m));
            out.push_str("</fault>");
        }
    }
    out.push_str("</methodResponse>\n");
    out
}

// ---------- decoding ----------

#[derive(Debug, Clone, PartialEq)]
enum Tok {
    Open(String),
    Close(String),
    /// `<x/>`
    Empty(String),
    Text(String),
}

fn malformed(pos: usize, what: impl Into<String>) -> XmlRpcError {
    XmlRpcError::Malformed {
        pos,
        what: what.into(),
    }
}

fn unescape(s: &str, pos: usize) -> Result<String, XmlRpcError> {
    if !s.contains('&') {
        return Ok(s.to_string());
    }
    let mut out = String::with_capacity(s.len());
    let mut rest = s;
    while let Some(i) = rest.find('&') {
        out.push_str(&rest[..i]);
        let after = &rest[i + 1..];
        let end = after
            .find(';')
            .ok_or_else(|| malformed(pos, "unterminated entity"))?;
        let ent = &after[..end];
        let c = match ent {
            "lt" => '<',
            "gt" => '>',
            "amp" => '&',
            "quot" => '"',
            "apos" => '\'',
            _ => {
                let code = if let Some(h) = ent.strip_prefix("#x").or(ent.strip_prefix("#X")) {
                    u32::from_str_radix(h, 16).ok()
                } else if let Some(d) = ent.strip_prefix('#') {
                    d.parse().ok()
                } else {
                    None
                };
                code.and_then(char::from_u32)
                    .ok_or_else(|| malformed(pos, format!("bad entity &{ent};")))?
            }
        };
        out.push(c);
        rest = &after[end + 1..];
    }
    out.push_str(rest);
    Ok(out)
}

fn tokenize(src: &str) -> Result<Vec<(usize, Tok)>, XmlRpcError> {
    let mut toks = Vec::new();
    let b = src.as_bytes();
    let mut i = 0;
    // Open elements; a well-formed document never goes below zero, and the
    // parser reports mismatched tags itself.
    let mut depth = 0usize;
    while i < b.len() {
        if toks.len() >= MAX_XML_TOKENS {
            return Err(malformed(
                i,
                format!("more than {MAX_XML_TOKENS} tags and texts"),
            ));
        }
        if b[i] == b'<' {
            if src[i..].starts_with("<?") {
                let e = src[i..]
                    .find("?>")
                    .ok_or_else(|| malformed(i, "unterminated <?"))?;
                i += e + 2;
            } else if src[i..].starts_with("<!--") {
                let e = src[i..]
                    .find("-->")
                    .ok_or_else(|| malformed(i, "unterminated comment"))?;
                i += e + 3;
            } else if src[i..].starts_with("<![CDATA[") {
                let e = src[i..]
                    .find("]]>")
                    .ok_or_else(|| malformed(i, "unterminated cdata"))?;
                toks.push((i, Tok::Text(src[i + 9..i + e].to_string())));
                i += e + 3;
            } else if src[i..].starts_with("<!") {
                let e = src[i..]
                    .find('>')
                    .ok_or_else(|| malformed(i, "unterminated <!"))?;
                i += e + 1;
            } else {
                let e = src[i..]
                    .find('>')
                    .ok_or_else(|| malformed(i, "unterminated tag"))?;
                let inner = src[i + 1..i + e].trim();
                let tok = if let Some(n) = inner.strip_prefix('/') {
                    depth = depth.saturating_sub(1);
                    Tok::Close(n.trim().to_string())
                } else if let Some(n) = inner.strip_suffix('/') {
                    Tok::Empty(tag_name(n))
                } else {
                    depth += 1;
                    if depth > MAX_XML_DEPTH {
                        return Err(malformed(
                            i,
                            format!("elements nested deeper than {MAX_XML_DEPTH}"),
                        ));
                    }
                    Tok::Open(tag_name(inner))
                };
                toks.push((i, tok));
                i += e + 1;
            }
        } else {
            let e = src[i..].find('<').unwrap_or(src.len() - i);
            toks.push((i, Tok::Text(unescape(&src[i..i + e], i)?)));
            i += e;
        }
    }
    Ok(toks)
}

fn tag_name(inner: &str) -> String {
    inner.split_whitespace().next().unwrap_or("").to_string()
}

struct Parser {
    toks: Vec<(usize, Tok)>,
    i: usize,
}

impl Parser {
    fn pos(&self) -> usize {
        self.toks.get(self.i).map_or(usize::MAX, |t| t.0)
    }
    /// Skips whitespace-only text.
    fn skip_ws(&mut self) {
        while let Some((_, Tok::Text(t))) = self.toks.get(self.i) {
            if t.trim().is_empty() {
                self.i += 1;
            } else {
                break;
            }
        }
    }
    fn peek(&mut self) -> Option<&Tok> {
        self.skip_ws();
        self.toks.get(self.i).map(|t| &t.1)
    }
    fn open(&mut self, name: &str) -> Result<(), XmlRpcError> {
        match self.peek().cloned() {
            Some(Tok::Open(n)) if n == name => {
                self.i += 1;
                Ok(())
            }
            other => Err(malformed(
                self.pos(),
                format!("expected <{name}>, got {other:?}"),
            )),
        }
    }
    fn close(&mut self, name: &str) -> Result<(), XmlRpcError> {
        match self.peek().cloned() {
            Some(Tok::Close(n)) if n == name => {
                self.i += 1;
                Ok(())
            }
            other => Err(malformed(
                self.pos(),
                format!("expected </{name}>, got {other:?}"),
            )),
        }
    }
    /// Raw text (not whitespace-skipped) up to the closing tag `name`.
    fn text_until(&mut self, name: &str) -> Result<String, XmlRpcError> {
        let mut s = String::new();
        while let Some((_, Tok::Text(t))) = self.toks.get(self.i) {
            s.push_str(t);
            self.i += 1;
        }
        self.close(name)?;
        Ok(s)
    }

    fn value(&mut self) -> Result<Value, XmlRpcError> {
        match self.peek() {
            Some(Tok::Empty(n)) if n == "value" => {
                self.i += 1;
                return Ok(Value::Str(String::new()));
            }
            _ => self.open("value")?,
        }
        // Untyped text is a string.
        let mut raw = String::new();
        while let Some((_, Tok::Text(t))) = self.toks.get(self.i) {
            raw.push_str(t);
            self.i += 1;
        }
        let tok = self.toks.get(self.i).map(|t| t.1.clone());
        let v = match tok {
            Some(Tok::Close(n)) if n == "value" => Value::Str(raw),
            Some(Tok::Empty(n)) => {
                self.i += 1;
                match n.as_str() {
                    "nil" => Value::Nil,
                    "string" => Value::Str(String::new()),
                    "array" => Value::Array(Vec::new()),
                    "struct" => Value::Struct(BTreeMap::new()),
                    other => return Err(malformed(self.pos(), format!("empty <{other}/>"))),
                }
            }
            Some(Tok::Open(n)) => {
                self.i += 1;
                let p = self.pos();
                match n.as_str() {
                    "string" => Value::Str(self.text_until("string")?),
                    "i4" | "int" | "i8" => {
                        let t = self.text_until(&n)?;
                        Value::Int(
                            t.trim()
                                .parse()
                                .map_err(|_| malformed(p, format!("bad int {t:?}")))?,
                        )
                    }
                    "boolean" => {
                        let t = self.text_until("boolean")?;
                        Value::Bool(matches!(t.trim(), "1" | "true"))
                    }
                    "double" => {
                        let t = self.text_until("double")?;
                        Value::Double(
                            t.trim()
                                .parse()
                                .map_err(|_| malformed(p, format!("bad double {t:?}")))?,
                        )
                    }
                    "dateTime.iso8601" => Value::DateTime(self.text_until(&n)?),
                    "base64" => Value::Base64(self.text_until("base64")?),
                    "nil" => {
                        self.close("nil")?;
                        Value::Nil
                    }
                    "array" => {
                        let mut items = Vec::new();
                        match self.peek() {
                            Some(Tok::Empty(d)) if d == "data" => self.i += 1,
                            _ => {
                                self.open("data")?;
                                while !matches!(self.peek(), Some(Tok::Close(_))) {
                                    items.push(self.value()?);
                                }
                                self.close("data")?;
                            }
                        }
                        self.close("array")?;
                        Value::Array(items)
                    }
                    "struct" => {
                        let mut m = BTreeMap::new();
                        while matches!(self.peek(), Some(Tok::Open(x)) if x == "member") {
                            self.i += 1;
                            self.open("name")?;
                            let k = self.text_until("name")?;
                            let v = self.value()?;
                            self.close("member")?;
                            m.insert(k, v);
                        }
                        self.close("struct")?;
                        Value::Struct(m)
                    }
                    other => return Err(malformed(p, format!("unknown type <{other}>"))),
                }
            }
            other => {
                return Err(malformed(
                    self.pos(),
                    format!("unexpected {other:?} in value"),
                ));
            }
        };
        self.close("value")?;
        Ok(v)
    }

    fn params(&mut self) -> Result<Vec<Value>, XmlRpcError> {
        let mut out = Vec::new();
        match self.peek() {
            Some(Tok::Empty(n)) if n == "params" => {
                self.i += 1;
                return Ok(out);
            }
            Some(Tok::Open(n)) if n == "params" => self.i += 1,
            _ => return Ok(out),
        }
        while matches!(self.peek(), Some(Tok::Open(n)) if n == "param") {
            self.i += 1;
            out.push(self.value()?);
            self.close("param")?;
        }
        self.close("params")?;
        Ok(out)
    }
}

/// Decodes a `methodCall` document.
pub fn decode_call(src: &str) -> Result<MethodCall, XmlRpcError> {
    let mut p = Parser {
        toks: tokenize(src)?,
        i: 0,
    };
    p.open("methodCall")?;
    p.open("methodName")?;
    let method = p.text_until("methodName")?.trim().to_string();
    let params = p.params()?;
    p.close("methodCall")?;
    Ok(MethodCall { method, params })
}

/// Decodes a `methodResponse` document.
pub fn decode_response(src: &str) -> Result<Response, XmlRpcError> {
    let mut p = Parser {
        toks: tokenize(src)?,
        i: 0,
    };
    p.open("methodResponse")?;
    if matches!(p.peek(), Some(Tok::Open(n)) if n == "fault") {
        p.i += 1;
        let v = p.value()?;
        p.close("fault")?;
        let (code, message) = match &v {
            Value::Struct(m) => (
                m.get("faultCode").and_then(Value::as_i64).unwrap_or(-1),
                m.get("faultString")
                    .and_then(Value::as_str)
                    .unwrap_or("")
                    .to_string(),
            ),
            _ => (-1, String::new()),
        };
        return Ok(Response::Fault { code, message });
    }
    let mut params = p.params()?;
    p.close("methodResponse")?;
    if params.is_empty() {
        return Err(malformed(0, "response without a value"));
    }
    Ok(Response::Ok(params.swap_remove(0)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_all_value_kinds() {
        let mut m = BTreeMap::new();
        m.insert("a<b".to_string(), Value::Double(1.5));
        m.insert("n".to_string(), Value::Nil);
        let v = Value::Array(vec![
            Value::Int(-3),
            Value::Int(1 << 40),
            Value::Bool(true),
            Value::str("x & <y> \"z\"\nline"),
            Value::Struct(m),
            Value::Array(vec![]),
            Value::Base64("aGk=".into()),
        ]);
        let call = decode_call(&encode_call("m", std::slice::from_ref(&v))).unwrap();
        assert_eq!(call.method, "m");
        assert_eq!(call.params, vec![v.clone()]);
        assert_eq!(
            decode_response(&encode_response(&Response::Ok(v.clone()))).unwrap(),
            Response::Ok(v)
        );
    }

    #[test]
    fn decodes_python_style_untyped_strings_and_faults() {
        let src = "<?xml version='1.0'?>\n<methodCall>\n<methodName>getParam</methodName>\n<params>\n<param>\n<value><string>/rosparam-1</string></value>\n</param>\n<param>\n<value>/a/b</value>\n</param>\n<param><value><int>7</int></value></param>\n<param><value/></param>\n</params>\n</methodCall>\n";
        let c = decode_call(src).unwrap();
        assert_eq!(
            c.params,
            vec![
                Value::str("/rosparam-1"),
                Value::str("/a/b"),
                Value::Int(7),
                Value::str("")
            ]
        );
        let f = "<?xml version='1.0'?><methodResponse><fault><value><struct><member><name>faultCode</name><value><int>1</int></value></member><member><name>faultString</name><value><string>boom &amp; bust</string></value></member></struct></value></fault></methodResponse>";
        assert_eq!(
            decode_response(f).unwrap(),
            Response::Fault {
                code: 1,
                message: "boom & bust".into()
            }
        );
    }

    #[test]
    fn whitespace_inside_strings_is_kept_and_garbage_rejected() {
        let src = "<methodCall><methodName>x</methodName><params><param><value><string>  a  </string></value></param></params></methodCall>";
        assert_eq!(decode_call(src).unwrap().params, vec![Value::str("  a  ")]);
        assert!(decode_call("<methodCall><methodName>x</methodName><params><param><value><i4>z</i4></value></param></params></methodCall>").is_err());
        assert!(decode_call("<foo/>").is_err());
    }

    mod props {
        use proptest::prelude::*;

        use super::*;

        fn value() -> impl Strategy<Value = Value> {
            let leaf = prop_oneof![
                any::<i64>().prop_map(Value::Int),
                any::<bool>().prop_map(Value::Bool),
                any::<String>().prop_map(Value::Str),
                (-1e300f64..1e300).prop_map(Value::Double),
                "[0-9T:]{0,17}".prop_map(Value::DateTime),
                "[A-Za-z0-9+/=]{0,24}".prop_map(Value::Base64),
                Just(Value::Nil),
            ];
            leaf.prop_recursive(6, 48, 6, |inner| {
                prop_oneof![
                    prop::collection::vec(inner.clone(), 0..6).prop_map(Value::Array),
                    prop::collection::btree_map(any::<String>(), inner, 0..6)
                        .prop_map(Value::Struct),
                ]
            })
        }

        fn nested(depth: usize) -> String {
            let mut s = String::from("<methodCall><methodName>m</methodName><params><param>");
            s.push_str(&"<value><array><data>".repeat(depth));
            s.push_str(&"</data></array></value>".repeat(depth));
            s.push_str("</param></params></methodCall>");
            s
        }

        proptest! {
            #![proptest_config(ProptestConfig::with_cases(128))]

            #[test]
            fn calls_and_responses_round_trip(method in "[A-Za-z_.]{1,20}", params in prop::collection::vec(value(), 0..4)) {
                let call = decode_call(&encode_call(&method, &params)).unwrap();
                prop_assert_eq!(call, MethodCall { method, params: params.clone() });
                let v = Value::Array(params);
                let r = decode_response(&encode_response(&Response::Ok(v.clone()))).unwrap();
                prop_assert_eq!(r, Response::Ok(v));
            }

            #[test]
            fn any_text_decodes_or_errs_without_panicking(text in any::<String>(), tags in prop::collection::vec("</?(value|array|data|struct|member|name|string|i4|params|param|methodCall|methodName)/?>", 0..40)) {
                let _ = decode_call(&text);
                let _ = decode_response(&text);
                let soup: String = tags.concat();
                let _ = decode_call(&soup);
                let _ = decode_response(&format!("<methodResponse>{soup}"));
            }

            #[test]
            fn nesting_is_refused_exactly_past_the_limit(depth in 1usize..20_000) {
                // methodCall, params, param, then three elements a level.
                let elements = 3 + 3 * depth;
                match decode_call(&nested(depth)) {
                    Ok(c) => {
                        prop_assert!(elements <= MAX_XML_DEPTH);
                        prop_assert_eq!(c.params[0].depth(), depth);
                    }
                    Err(e) => {
                        prop_assert!(elements > MAX_XML_DEPTH);
                        prop_assert!(e.to_string().contains("nested deeper than"), "{}", e);
                    }
                }
            }
        }

        #[test]
        fn documents_with_too_many_tags_are_refused() {
            let flat = |n: usize| {
                format!(
                    "<methodCall><methodName>m</methodName><params><param><value><array><data>{}</data></array></value></param></params></methodCall>",
                    "<value/>".repeat(n)
                )
            };
            // Ten tags around the values.
            assert!(decode_call(&flat(MAX_XML_TOKENS - 100)).is_ok());
            let err = decode_call(&flat(MAX_XML_TOKENS)).unwrap_err();
            assert!(
                err.to_string().contains("more than 500000 tags and texts"),
                "{err}"
            );
        }

        #[test]
        fn the_deepest_allowed_document_decodes() {
            let depth = (MAX_XML_DEPTH - 3) / 3;
            assert_eq!(
                decode_call(&nested(depth)).unwrap().params[0].depth(),
                depth
            );
            assert!(decode_call(&nested(depth + 1)).is_err());
            assert!(decode_call(&nested(200_000)).is_err());
        }
    }
}
