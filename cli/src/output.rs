//! `configbot get -o FORMAT`, pure: parsing the format (`wide`, `yaml`,
//! `json`, `name`, `jsonpath=TEMPLATE`, `custom-columns=SPEC`) and rendering
//! objects with it, kubectl's way. Templates are kubectl's JSONPath subset:
//! literal text, `{.a.b}`, `{.items[*].x}`, `{.a[0]}`, `{.a[-1]}`, `{.a.*}`,
//! `{..name}`, `{['k.e.y']}`, `{"\n"}` and `{range .items[*]}…{end}`.

use std::fmt;

use configbot_manifests::Kind;
use serde_json::{Value, json};

use configbot_controller::table;

/// An `-o` format.
#[derive(Debug, Clone, PartialEq)]
pub enum Output {
    Wide,
    Yaml,
    Json,
    Name,
    JsonPath(Template),
    /// `(header, template)` per column.
    CustomColumns(Vec<(String, Template)>),
}

/// Parse `-o` (clap's value parser).
pub fn parse_output(s: &str) -> Result<Output, String> {
    if let Some(t) = s.strip_prefix("jsonpath=") {
        return Template::parse(t)
            .map(Output::JsonPath)
            .map_err(String::from);
    }
    if let Some(spec) = s.strip_prefix("custom-columns=") {
        return spec
            .split(',')
            .map(|col| {
                let (header, path) = col.split_once(':').ok_or_else(|| {
                    format!(
                        "custom-columns: {col:?} is not HEADER:JSONPATH (e.g. NAME:.metadata.name)"
                    )
                })?;
                let path = if path.starts_with('{') {
                    path.to_string()
                } else {
                    format!("{{{path}}}")
                };
                let t = Template::parse(&path)
                    .map_err(|e| format!("custom-columns: column {header:?}: {e}"))?;
                Ok((header.to_string(), t))
            })
            .collect::<Result<_, String>>()
            .map(Output::CustomColumns);
    }
    match s {
        "wide" => Ok(Output::Wide),
        "yaml" => Ok(Output::Yaml),
        "json" => Ok(Output::Json),
        "name" => Ok(Output::Name),
        "jsonpath" | "custom-columns" => Err(format!("-o {s} needs a template: -o {s}=...")),
        other => Err(format!(
            "unknown output format {other:?}; use wide, yaml, json, name, jsonpath=TEMPLATE or custom-columns=SPEC"
        )),
    }
}

/// The JSON kubectl prints for a list: a `v1` `List` of the objects.
pub fn list_object(items: &[Value]) -> Value {
    json!({"apiVersion": "v1", "kind": "List", "metadata": {"resourceVersion": ""}, "items": items})
}

/// `kind.group/name`, as `-o name` prints it.
pub fn name_of(kind: Kind, obj: &Value) -> String {
    format!(
        "{}.{}/{}",
        kind.singular(),
        configbot_manifests::GROUP,
        obj["metadata"]["name"].as_str().unwrap_or("")
    )
}

/// The table `custom-columns` prints for `objs`, header first.
pub fn custom_columns(columns: &[(String, Template)], objs: &[Value], header: bool) -> String {
    let headers: Vec<String> = columns.iter().map(|(h, _)| h.clone()).collect();
    let rows: Vec<Vec<String>> = objs
        .iter()
        .map(|o| {
            columns
                .iter()
                .map(|(_, t)| {
                    let v = t.values(o);
                    if v.is_empty() {
                        "<none>".to_string()
                    } else {
                        v.iter().map(scalar).collect::<Vec<_>>().join(",")
                    }
                })
                .collect()
        })
        .collect();
    let text = table::render(&headers, &rows);
    if header {
        text
    } else {
        text.split_once('\n').map_or("", |(_, r)| r).to_string()
    }
}

/// A parsed JSONPath template.
#[derive(Debug, Clone, PartialEq)]
pub struct Template(Vec<Node>);

#[derive(Debug, Clone, PartialEq)]
enum Node {
    Text(String),
    Path(Vec<Step>),
    Range(Vec<Step>, Vec<Node>),
}

#[derive(Debug, Clone, PartialEq)]
enum Step {
    Field(String),
    Index(i64),
    All,
    Descend(String),
}

/// A template error with the byte offset it was found at.
#[derive(Debug, Clone, PartialEq)]
pub struct TemplateError {
    pub offset: usize,
    pub message: String,
}

impl fmt::Display for TemplateError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "jsonpath: at byte {}: {}", self.offset, self.message)
    }
}

impl From<TemplateError> for String {
    fn from(e: TemplateError) -> String {
        e.to_string()
    }
}

impl Template {
    pub fn parse(text: &str) -> Result<Template, TemplateError> {
        let mut stack: Vec<(Vec<Step>, Vec<Node>, usize)> = Vec::new();
        let mut nodes = Vec::new();
        let mut rest = text;
        let err = |at: &str, message: String| TemplateError {
            offset: text.len() - at.len(),
            message,
        };
        while !rest.is_empty() {
            let Some(open) = rest.find('{') else {
                nodes.push(Node::Text(rest.to_string()));
                break;
            };
            if open > 0 {
                nodes.push(Node::Text(rest[..open].to_string()));
            }
            let inner_start = &rest[open + 1..];
            let close = closing_brace(inner_start)
                .ok_or_else(|| err(&rest[open..], "unclosed '{'".into()))?;
            let inner = inner_start[..close].trim();
            let at = inner_start;
            rest = &inner_start[close + 1..];
            if inner == "end" {
                let (steps, outer, _) = stack
                    .pop()
                    .ok_or_else(|| err(at, "{end} without {range}".into()))?;
                let body = std::mem::replace(&mut nodes, outer);
                nodes.push(Node::Range(steps, body));
            } else if let Some(expr) = inner.strip_prefix("range ") {
                let steps = parse_path(expr.trim()).map_err(|m| err(at, m))?;
                stack.push((steps, std::mem::take(&mut nodes), text.len() - at.len()));
            } else if inner.starts_with('"') {
                nodes.push(Node::Text(parse_string(inner).map_err(|m| err(at, m))?));
            } else {
                nodes.push(Node::Path(parse_path(inner).map_err(|m| err(at, m))?));
            }
        }
        if let Some((_, _, offset)) = stack.pop() {
            return Err(TemplateError {
                offset,
                message: "{range} without {end}".into(),
            });
        }
        Ok(Template(nodes))
    }

    /// The template's output for `data`; missing keys print nothing.
    pub fn render(&self, data: &Value) -> String {
        let mut out = String::new();
        render_nodes(&self.0, data, &mut out);
        out
    }

    /// The values of a template that is one path (custom columns).
    fn values(&self, data: &Value) -> Vec<Value> {
        self.0
            .iter()
            .flat_map(|n| match n {
                Node::Path(steps) => eval(steps, data),
                Node::Text(t) => vec![Value::String(t.clone())],
                Node::Range(..) => Vec::new(),
            })
            .collect()
    }
}

/// Where the `}` closing a template action is, skipping quoted strings.
fn closing_brace(s: &str) -> Option<usize> {
    let mut quote = None;
    let mut escaped = false;
    for (i, c) in s.char_indices() {
        match (quote, c) {
            (Some(_), _) if escaped => escaped = false,
            (Some(_), '\\') => escaped = true,
            (Some(q), c) if c == q => quote = None,
            (Some(_), _) => {}
            (None, '"' | '\'') => quote = Some(c),
            (None, '}') => return Some(i),
            (None, _) => {}
        }
    }
    None
}

fn parse_string(s: &str) -> Result<String, String> {
    serde_json::from_str::<String>(s).map_err(|e| format!("bad string literal {s}: {e}"))
}

fn parse_path(expr: &str) -> Result<Vec<Step>, String> {
    let mut steps = Vec::new();
    let mut s = expr.strip_prefix('$').unwrap_or(expr);
    if s == "@" {
        return Ok(steps);
    }
    s = s.strip_prefix('@').unwrap_or(s);
    while !s.is_empty() {
        if let Some(r) = s.strip_prefix("..") {
            let end = r.find(['.', '[']).unwrap_or(r.len());
            if end == 0 {
                return Err(format!("{expr:?}: '..' needs a field name"));
            }
            steps.push(Step::Descend(r[..end].to_string()));
            s = &r[end..];
        } else if let Some(r) = s.strip_prefix('.') {
            let end = r.find(['.', '[']).unwrap_or(r.len());
            match &r[..end] {
                "" if r.is_empty() => {}
                "" => return Err(format!("{expr:?}: empty field name")),
                "*" => steps.push(Step::All),
                f => steps.push(Step::Field(f.to_string())),
            }
            s = &r[end..];
        } else if let Some(r) = s.strip_prefix('[') {
            let end = r
                .find(']')
                .ok_or_else(|| format!("{expr:?}: unclosed '['"))?;
            let inner = r[..end].trim();
            if inner == "*" {
                steps.push(Step::All);
            } else if let Some(q) = inner
                .strip_prefix('\'')
                .and_then(|i| i.strip_suffix('\''))
                .or_else(|| inner.strip_prefix('"').and_then(|i| i.strip_suffix('"')))
            {
                steps.push(Step::Field(q.to_string()));
            } else if let Ok(i) = inner.parse::<i64>() {
                steps.push(Step::Index(i));
            } else {
                return Err(format!(
                    "{expr:?}: [{inner}] is not supported; use [N], [-N], [*] or ['key']"
                ));
            }
            s = &r[end + 1..];
        } else {
            return Err(format!(
                "{expr:?}: expected '.', '..' or '[' at {s:?} (paths start with '.', e.g. .metadata.name)"
            ));
        }
    }
    Ok(steps)
}

fn eval(steps: &[Step], data: &Value) -> Vec<Value> {
    let mut cur = vec![data.clone()];
    for step in steps {
        cur = cur
            .iter()
            .flat_map(|v| match step {
                Step::Field(f) => v.get(f).cloned().into_iter().collect::<Vec<_>>(),
                Step::Index(i) => v
                    .as_array()
                    .and_then(|a| {
                        let i = if *i < 0 { a.len() as i64 + i } else { *i };
                        usize::try_from(i).ok().and_then(|i| a.get(i))
                    })
                    .cloned()
                    .into_iter()
                    .collect(),
                Step::All => match v {
                    Value::Array(a) => a.clone(),
                    Value::Object(m) => m.values().cloned().collect(),
                    _ => Vec::new(),
                },
                Step::Descend(f) => {
                    let mut found = Vec::new();
                    descend(v, f, &mut found);
                    found
                }
            })
            .collect();
    }
    cur
}

fn descend(v: &Value, field: &str, out: &mut Vec<Value>) {
    match v {
        Value::Object(m) => {
            if let Some(x) = m.get(field) {
                out.push(x.clone());
            }
            for c in m.values() {
                descend(c, field, out);
            }
        }
        Value::Array(a) => a.iter().for_each(|c| descend(c, field, out)),
        _ => {}
    }
}

/// How a value prints: strings bare, everything else as compact JSON.
fn scalar(v: &Value) -> String {
    match v {
        Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

fn render_nodes(nodes: &[Node], data: &Value, out: &mut String) {
    for n in nodes {
        match n {
            Node::Text(t) => out.push_str(t),
            Node::Path(steps) => {
                let vals: Vec<String> = eval(steps, data).iter().map(scalar).collect();
                out.push_str(&vals.join(" "));
            }
            Node::Range(steps, body) => {
                for item in eval(steps, data) {
                    render_nodes(body, &item, out);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn list() -> Value {
        list_object(&[
            json!({"metadata": {"name": "a", "labels": {"app.kubernetes.io/name": "x"}}, "spec": {"apps": [{"name": "nav"}, {"name": "obj"}]}, "status": {"phase": "Accepted"}}),
            json!({"metadata": {"name": "b"}, "spec": {"apps": [{"name": "arm"}]}}),
        ])
    }

    #[test]
    fn templates_render_like_kubectl() {
        let cases = [
            ("{.items[*].metadata.name}", "a b"),
            ("{.items[0].spec.apps[-1].name}", "obj"),
            (
                "{range .items[*]}{.metadata.name}:{.status.phase}{\"\\n\"}{end}",
                "a:Accepted\nb:\n",
            ),
            ("names: {..apps[*].name}", "names: nav obj arm"),
            ("{.items[0].metadata.labels['app.kubernetes.io/name']}", "x"),
            ("{.items[0].spec.apps[0]}", r#"{"name":"nav"}"#),
            ("{.items[5].metadata.name}{.missing}", ""),
            ("{.kind}", "List"),
            ("{$.kind}", "List"),
            ("{.items[1].metadata.*}", "b"),
        ];
        for (t, want) in cases {
            let tpl = Template::parse(t).unwrap_or_else(|e| panic!("{t}: {e}"));
            assert_eq!(tpl.render(&list()), want, "{t}");
        }
    }

    #[test]
    fn bad_templates_say_where() {
        for (t, offset, message) in [
            ("{.a", 0, "unclosed '{'"),
            ("x{range .items[*]}{.a}", 2, "{range} without {end}"),
            ("{.a}{end}", 5, "{end} without {range}"),
            ("{.items[?(@.x)]}", 1, "is not supported"),
            ("{metadata.name}", 1, "expected '.'"),
        ] {
            let e = Template::parse(t).unwrap_err();
            assert_eq!(e.offset, offset, "{t}: {e}");
            assert!(e.message.contains(message), "{t}: {e}");
        }
    }

    #[test]
    fn output_formats_parse() {
        assert_eq!(parse_output("name"), Ok(Output::Name));
        assert!(matches!(
            parse_output("jsonpath={.kind}"),
            Ok(Output::JsonPath(_))
        ));
        assert!(
            parse_output("jsonpath")
                .unwrap_err()
                .contains("needs a template")
        );
        assert!(
            parse_output("table")
                .unwrap_err()
                .contains("unknown output format")
        );
        assert!(
            parse_output("custom-columns=NAME")
                .unwrap_err()
                .contains("HEADER:JSONPATH")
        );
        let Ok(Output::CustomColumns(cols)) = parse_output(
            "custom-columns=NAME:.metadata.name,APPS:{.spec.apps[*].name},PHASE:.status.phase",
        ) else {
            panic!("custom-columns did not parse");
        };
        let items = list()["items"].as_array().unwrap().clone();
        assert_eq!(
            custom_columns(&cols, &items, true),
            "NAME   APPS      PHASE\na      nav,obj   Accepted\nb      arm       <none>\n"
        );
    }
}
