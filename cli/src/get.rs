//! `configbot get` and `describe`: kubectl-like views of objects.

use std::process::ExitCode;

use super::output::{self, Output};
use crate::client::{Client, path};
use clap::Args;
use configbot_controller::table;
use configbot_manifests::{Kind, PerformanceSpecStatus, RobotStackStatus, decode_status};
use serde_json::Value;

#[derive(Debug, Args)]
pub struct GetArgs {
    /// Kind: robotstack (rs), performancespec (pspec), configprofile (cprof),
    /// or `trials` with a PerformanceSpec name (its tuning run).
    kind: String,
    /// Object name; all objects when omitted.
    name: Option<String>,
    #[arg(short = 'n', long, default_value = "default")]
    namespace: String,
    /// Every namespace.
    #[arg(short = 'A', long)]
    all_namespaces: bool,
    /// Label selector, e.g. robot=spot.
    #[arg(short = 'l', long)]
    selector: Option<String>,
    /// Output format: wide, yaml, json, name, jsonpath=TEMPLATE or
    /// custom-columns=HEADER:PATH,... (kubectl's JSONPath, e.g. {.items[*].metadata.name}).
    #[arg(short = 'o', long, value_parser = output::parse_output)]
    output: Option<Output>,
    /// Keep watching and print every change.
    #[arg(short = 'w', long)]
    watch: bool,
}

#[derive(Debug, Args)]
pub struct DescribeArgs {
    kind: String,
    name: String,
    #[arg(short = 'n', long, default_value = "default")]
    namespace: String,
}

pub fn kind(word: &str) -> anyhow::Result<Kind> {
    Kind::lookup(word).ok_or_else(|| {
        anyhow::anyhow!("unknown kind {word:?}; use robotstack (rs), performancespec (pspec), configprofile (cprof) or trials")
    })
}

/// Print objects in the `-o` format. `as_list`: the objects are the answer
/// to a list (json, yaml and jsonpath see one `List`), not one object each.
fn print_objects(
    kind: Kind,
    objs: &[Value],
    output: Option<&Output>,
    with_ns: bool,
    header: bool,
    as_list: bool,
) -> anyhow::Result<()> {
    let list = as_list.then(|| output::list_object(objs));
    let each: Vec<&Value> = match &list {
        Some(l) => vec![l],
        None => objs.iter().collect(),
    };
    match output {
        Some(Output::Json) => {
            for o in each {
                println!("{}", serde_json::to_string_pretty(o)?);
            }
        }
        Some(Output::Yaml) => {
            for o in each {
                print!("{}", serde_saphyr::to_string(o)?);
            }
        }
        Some(Output::JsonPath(t)) => {
            for o in each {
                print!("{}", t.render(o));
            }
        }
        Some(Output::Name) => {
            for o in objs {
                println!("{}", output::name_of(kind, o));
            }
        }
        Some(Output::CustomColumns(cols)) => {
            print!("{}", output::custom_columns(cols, objs, header));
        }
        Some(Output::Wide) | None => {
            let wide = matches!(output, Some(Output::Wide));
            let now = time::OffsetDateTime::now_utc();
            let rows: Vec<Vec<String>> = objs
                .iter()
                .map(|o| table::row(kind, o, wide, with_ns, now))
                .collect();
            let text = table::render(&table::headers(kind, wide, with_ns), &rows);
            if header {
                print!("{text}");
            } else {
                print!("{}", text.split_once('\n').map_or("", |(_, r)| r));
            }
        }
    }
    Ok(())
}

pub async fn get(client: &Client, a: &GetArgs) -> anyhow::Result<ExitCode> {
    if matches!(a.kind.as_str(), "trials" | "trial") {
        return trials(client, a).await;
    }
    let kind = kind(&a.kind)?;
    let ns = (!a.all_namespaces).then_some(a.namespace.as_str());
    let mut query = Vec::new();
    if let Some(sel) = &a.selector {
        query.push(format!(
            "labelSelector={}",
            super::delete::encode_query(sel)
        ));
    }
    if let Some(n) = &a.name {
        query.push(format!("fieldSelector=metadata.name%3D{n}"));
    }
    let q = if query.is_empty() {
        String::new()
    } else {
        format!("?{}", query.join("&"))
    };
    let list = client.get(&format!("{}{q}", path(kind, ns, None))).await?;
    let items: Vec<Value> = list["items"].as_array().cloned().unwrap_or_default();
    if let (Some(n), true) = (&a.name, items.is_empty()) {
        anyhow::bail!(
            "{} {n:?} not found in namespace {:?}",
            kind.plural(),
            a.namespace
        );
    }
    let tabular = matches!(
        a.output,
        None | Some(Output::Wide | Output::CustomColumns(_))
    );
    if items.is_empty() && tabular {
        if !a.watch {
            eprintln!("No {} found.", kind.plural());
        }
    } else {
        let as_list = a.name.is_none();
        print_objects(
            kind,
            &items,
            a.output.as_ref(),
            a.all_namespaces,
            true,
            as_list,
        )?;
    }
    if a.watch {
        let mut rv = list["metadata"]["resourceVersion"]
            .as_str()
            .unwrap_or("0")
            .to_string();
        let sep = if q.is_empty() { "?" } else { "&" };
        let output = a.output.as_ref();
        let all = a.all_namespaces;
        loop {
            let wpath = format!(
                "{}{q}{sep}watch=true&resourceVersion={rv}",
                path(kind, ns, None)
            );
            let expired = watch_until_error(client, &wpath, |obj| {
                let _ = print_objects(kind, std::slice::from_ref(obj), output, all, false, false);
            })
            .await?;
            if !expired {
                break;
            }
            // Fell behind: list again (printing the current objects) and watch from there.
            let list = client.get(&format!("{}{q}", path(kind, ns, None))).await?;
            let items = list["items"].as_array().cloned().unwrap_or_default();
            print_objects(kind, &items, output, all, false, false)?;
            rv = list["metadata"]["resourceVersion"]
                .as_str()
                .unwrap_or("0")
                .to_string();
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// Hand each watched object to `on_object` until the stream ends (false) or
/// the server says the watch expired (true: the caller lists again). Any
/// other ERROR event is an error naming the server's message.
async fn watch_until_error(
    client: &Client,
    wpath: &str,
    mut on_object: impl FnMut(&Value),
) -> anyhow::Result<bool> {
    let mut error = None;
    client
        .watch(wpath, |ev| {
            if ev["type"] == "ERROR" {
                error = Some(ev["object"].clone());
                return false;
            }
            on_object(&ev["object"]);
            true
        })
        .await?;
    match error {
        None => Ok(false),
        Some(st) if st["code"] == 410 => {
            eprintln!(
                "configbot: {}",
                st["message"].as_str().unwrap_or("the watch expired")
            );
            Ok(true)
        }
        Some(st) => anyhow::bail!(
            "watch failed: {}",
            st["message"].as_str().unwrap_or("unknown error")
        ),
    }
}

/// `configbot get trials SPEC [-w]`: the tuning run of one PerformanceSpec;
/// with `-w` the view is redrawn on every change.
async fn trials(client: &Client, a: &GetArgs) -> anyhow::Result<ExitCode> {
    use configbot_controller::tuning::view::trials_view;
    let Some(name) = &a.name else {
        anyhow::bail!("usage: configbot get trials SPEC [-w] (SPEC is a PerformanceSpec name)");
    };
    let kind = Kind::PerformanceSpec;
    let obj = client
        .get(&path(kind, Some(&a.namespace), Some(name)))
        .await?;
    if matches!(a.output, Some(Output::Json)) {
        println!("{}", serde_json::to_string_pretty(&obj["status"])?);
        return Ok(ExitCode::SUCCESS);
    }
    print!("{}", trials_view(&obj)?);
    // While watching, a status that does not decode is shown, not fatal.
    let redraw = |o: &Value| {
        let view = trials_view(o).unwrap_or_else(|e| format!("unreadable status: {e}\n"));
        // Clear the screen and redraw (ANSI), like `watch`.
        print!("\x1b[2J\x1b[H{view}");
    };
    if a.watch {
        let mut obj = obj;
        loop {
            let rv = obj["metadata"]["resourceVersion"].as_str().unwrap_or("0");
            let wpath = format!(
                "{}?fieldSelector=metadata.name%3D{name}&watch=true&resourceVersion={rv}",
                path(kind, Some(&a.namespace), None)
            );
            let expired = watch_until_error(client, &wpath, redraw).await?;
            if !expired {
                break;
            }
            obj = client
                .get(&path(kind, Some(&a.namespace), Some(name)))
                .await?;
            redraw(&obj);
        }
    }
    Ok(ExitCode::SUCCESS)
}

pub async fn describe(client: &Client, a: &DescribeArgs) -> anyhow::Result<ExitCode> {
    let kind = kind(&a.kind)?;
    let obj = client
        .get(&path(kind, Some(&a.namespace), Some(&a.name)))
        .await?;
    let m = &obj["metadata"];
    let s = |v: &Value| {
        v.as_str()
            .map(str::to_string)
            .unwrap_or_else(|| v.to_string())
    };
    println!("Name:         {}", s(&m["name"]));
    println!("Namespace:    {}", s(&m["namespace"]));
    println!("Kind:         {}", kind.name());
    for (title, key) in [("Labels:", "labels"), ("Annotations:", "annotations")] {
        let entries: Vec<String> = m[key]
            .as_object()
            .map(|o| o.iter().map(|(k, v)| format!("{k}={}", s(v))).collect())
            .unwrap_or_default();
        println!(
            "{title:<13} {}",
            if entries.is_empty() {
                "<none>".into()
            } else {
                entries.join("\n              ")
            }
        );
    }
    println!("Generation:   {}", m["generation"]);
    println!("Created:      {}", s(&m["creationTimestamp"]));
    println!("Spec:");
    match kind {
        Kind::RobotStack => {
            for app in obj["spec"]["apps"].as_array().into_iter().flatten() {
                let nodes: Vec<String> = app["nodes"]
                    .as_array()
                    .into_iter()
                    .flatten()
                    .map(|n| s(&n["name"]))
                    .collect();
                let core = if app["core"].as_bool() == Some(true) {
                    "core"
                } else {
                    "non-core"
                };
                println!("  App {} ({core}): {}", s(&app["name"]), nodes.join(", "));
            }
        }
        Kind::PerformanceSpec => {
            println!("  Stack: {}", s(&obj["spec"]["stackRef"]["name"]));
            for metric in obj["spec"]["metrics"].as_array().into_iter().flatten() {
                let t = &metric["target"];
                let target = if t["atLeast"].is_number() {
                    format!(">= {}", t["atLeast"])
                } else {
                    format!("<= {}", t["atMost"])
                };
                let src = metric["source"]["topicRate"]["topic"]
                    .as_str()
                    .map(|t| format!("rate of {t}"))
                    .unwrap_or_else(|| {
                        format!("cpu of {}", s(&metric["source"]["cpuUsage"]["node"]))
                    });
                println!(
                    "  Metric {} (app {}): {src} {target}",
                    s(&metric["name"]),
                    s(&metric["app"])
                );
            }
        }
        Kind::ConfigProfile => {
            let c = &obj["spec"]["context"];
            println!("  Model: {}", s(&c["robotModel"]));
            println!("  Spec: {}", s(&obj["spec"]["specName"]));
            println!("  Context: apps {} nodes {}", c["apps"], c["nodes"]);
            println!("  Config: {}", obj["spec"]["config"]);
        }
    }
    let (phase, conditions) = match kind {
        Kind::RobotStack => {
            let st: RobotStackStatus = decode_status(&obj)?;
            (st.phase.to_string(), st.conditions)
        }
        Kind::PerformanceSpec => {
            let st: PerformanceSpecStatus = decode_status(&obj)?;
            (st.phase.to_string(), st.conditions)
        }
        Kind::ConfigProfile => (String::new(), Vec::new()),
    };
    println!("Status:");
    if obj["status"].is_null() {
        println!("  Phase: <none>");
    } else {
        println!("  Phase: {phase}");
    }
    println!("  Conditions:");
    println!(
        "    {:<15} {:<8} {:<16} Message",
        "Type", "Status", "Reason"
    );
    for c in &conditions {
        let status = format!("{:?}", c.status);
        println!(
            "    {:<15} {status:<8} {:<16} {}",
            c.type_, c.reason, c.message
        );
    }
    let events = client
        .get(&format!("/api/v1/namespaces/{}/events?fieldSelector=involvedObject.name%3D{},involvedObject.kind%3D{}", a.namespace, a.name, kind.name()))
        .await?;
    println!("Events:");
    let items = events["items"].as_array().cloned().unwrap_or_default();
    if items.is_empty() {
        println!("  <none>");
    }
    for e in items.iter().rev().take(15).rev() {
        println!(
            "  {:<8} {:<16} {}  {}",
            s(&e["type"]),
            s(&e["reason"]),
            s(&e["lastTimestamp"]),
            s(&e["message"])
        );
    }
    Ok(ExitCode::SUCCESS)
}
