//! Table views of objects: the columns of `configbot get` and of the
//! Kubernetes `Table` responses kubectl asks for, from one definition
//! (`Kind::printer_columns`).

use configbot_manifests::Kind;
use serde_json::Value;

/// Column headers for a kind.
pub fn headers(kind: Kind, wide: bool, with_namespace: bool) -> Vec<String> {
    let mut h = Vec::new();
    if with_namespace {
        h.push("NAMESPACE".into());
    }
    h.push("NAME".into());
    h.extend(
        kind.printer_columns()
            .iter()
            .filter(|c| wide || !c.wide)
            .map(|c| c.name.to_uppercase()),
    );
    h.push("AGE".into());
    h
}

/// One row of cells as text.
pub fn row(
    kind: Kind,
    obj: &Value,
    wide: bool,
    with_namespace: bool,
    now: time::OffsetDateTime,
) -> Vec<String> {
    let mut r = Vec::new();
    if with_namespace {
        r.push(
            obj["metadata"]["namespace"]
                .as_str()
                .unwrap_or("")
                .to_string(),
        );
    }
    r.push(obj["metadata"]["name"].as_str().unwrap_or("").to_string());
    for c in kind.printer_columns().iter().filter(|c| wide || !c.wide) {
        r.push(cell_text(c.json_path, c.value(obj)));
    }
    r.push(age(obj["metadata"]["creationTimestamp"].as_str(), now));
    r
}

fn cell_text(path: &str, v: Option<&Value>) -> String {
    match v {
        None => "<none>".into(),
        Some(Value::String(s)) => s.clone(),
        Some(Value::Number(n)) if path.ends_with("satisfaction") => {
            format!("{:.1}%", n.as_f64().unwrap_or(0.0) * 100.0)
        }
        Some(other) => other.to_string(),
    }
}

/// Kubernetes-style short age: `45s`, `12m`, `3h`, `2d`.
pub fn age(created: Option<&str>, now: time::OffsetDateTime) -> String {
    let Some(t) = created.and_then(|c| {
        time::OffsetDateTime::parse(c, &time::format_description::well_known::Rfc3339).ok()
    }) else {
        return "<unknown>".into();
    };
    let s = (now - t).whole_seconds().max(0);
    match s {
        0..120 => format!("{s}s"),
        120..7200 => format!("{}m", s / 60),
        7200..172_800 => format!("{}h", s / 3600),
        _ => format!("{}d", s / 86_400),
    }
}

/// Render rows as aligned text columns.
pub fn render(headers: &[String], rows: &[Vec<String>]) -> String {
    let mut widths: Vec<usize> = headers.iter().map(|h| h.chars().count()).collect();
    for r in rows {
        for (i, c) in r.iter().enumerate() {
            if let Some(w) = widths.get_mut(i) {
                *w = (*w).max(c.chars().count());
            }
        }
    }
    let line = |cells: &[String]| {
        let mut s = String::new();
        for (i, c) in cells.iter().enumerate() {
            if i + 1 == cells.len() {
                s.push_str(c);
            } else {
                s.push_str(&format!("{c:<w$}   ", w = widths[i]));
            }
        }
        s.trim_end().to_string()
    };
    let mut out = line(headers);
    for r in rows {
        out.push('\n');
        out.push_str(&line(r));
    }
    out.push('\n');
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn rows_follow_printer_columns() {
        let now = time::macros::datetime!(2026-01-01 0:10 UTC);
        let obj = json!({"metadata": {"name": "basic", "namespace": "default", "creationTimestamp": "2026-01-01T00:00:00Z"},
                         "spec": {"stackRef": {"name": "basic-nav"}}, "status": {"phase": "Satisfied", "satisfaction": 0.995}});
        assert_eq!(
            headers(Kind::PerformanceSpec, false, false),
            ["NAME", "STACK", "PHASE", "SATISFACTION", "AGE"]
        );
        assert_eq!(
            row(Kind::PerformanceSpec, &obj, false, false, now),
            ["basic", "basic-nav", "Satisfied", "99.5%", "10m"]
        );
        let text = render(
            &headers(Kind::PerformanceSpec, false, false),
            &[row(Kind::PerformanceSpec, &obj, false, false, now)],
        );
        assert_eq!(
            text,
            "NAME    STACK       PHASE       SATISFACTION   AGE\nbasic   basic-nav   Satisfied   99.5%          10m\n"
        );
    }
}
