//! The Helm chart and Grafana dashboard stay true to the code: every metric
//! the dashboard queries is one the binaries register, every `.Values` path a
//! template reads exists in values.yaml, and the chart's YAML files parse.

use std::path::{Path, PathBuf};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn rust_sources(dir: &Path, out: &mut String) {
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let p = e.path();
        if p.is_dir() && !p.ends_with("target") {
            rust_sources(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push_str(&std::fs::read_to_string(&p).unwrap());
        }
    }
}

/// Every `configbot_*` identifier in `text`.
fn metric_names(text: &str) -> Vec<String> {
    let re = regex::Regex::new(r"configbot_[a-z_]+").unwrap();
    let mut v: Vec<String> = re.find_iter(text).map(|m| m.as_str().to_owned()).collect();
    v.sort();
    v.dedup();
    v
}

#[test]
fn the_dashboard_queries_only_registered_metrics() {
    let text =
        std::fs::read_to_string(repo().join("charts/configbot/dashboards/configbot.json")).unwrap();
    let dash: serde_json::Value = serde_json::from_str(&text).unwrap();
    let exprs: Vec<String> = dash["panels"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|p| p["targets"].as_array().unwrap().iter())
        .map(|t| t["expr"].as_str().unwrap().to_owned())
        .collect();
    assert!(exprs.len() >= 10);
    let mut code = String::new();
    rust_sources(&repo().join("controller/src"), &mut code);
    rust_sources(&repo().join("agents"), &mut code);
    let names = metric_names(&exprs.join("\n"));
    assert!(names.len() >= 15, "{names:?}");
    for n in names {
        assert!(
            code.contains(&format!("\"{n}\"")),
            "the dashboard queries {n}, which no binary registers"
        );
    }
}

fn values_path_exists(values: &serde_json::Value, path: &str) -> bool {
    path.split('.').try_fold(values, |v, k| v.get(k)).is_some()
}

#[test]
fn templates_read_only_values_that_exist() {
    let chart = repo().join("charts/configbot");
    let values: serde_json::Value =
        serde_saphyr::from_str(&std::fs::read_to_string(chart.join("values.yaml")).unwrap())
            .unwrap();
    let meta: serde_json::Value =
        serde_saphyr::from_str(&std::fs::read_to_string(chart.join("Chart.yaml")).unwrap())
            .unwrap();
    assert_eq!(meta["name"], "configbot");
    let re = regex::Regex::new(r"\.Values\.([A-Za-z0-9_.]+)").unwrap();
    let mut seen = 0;
    for e in std::fs::read_dir(chart.join("templates"))
        .unwrap()
        .flatten()
    {
        let text = std::fs::read_to_string(e.path()).unwrap();
        for c in re.captures_iter(&text) {
            seen += 1;
            assert!(
                values_path_exists(&values, &c[1]),
                "{} reads .Values.{}, missing from values.yaml",
                e.path().display(),
                &c[1]
            );
        }
    }
    assert!(seen >= 10);
    // The CRDs the chart installs are the generated ones (checked by manifests' schema test).
    for kind in configbot_manifests::Kind::ALL {
        assert!(
            chart
                .join("crds")
                .join(configbot_manifests::schema::crd_file_name(kind))
                .exists()
        );
    }
}
