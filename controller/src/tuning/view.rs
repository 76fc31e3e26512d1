//! `configbot get trials SPEC` (pure): a PerformanceSpec's tuning run as a
//! progress line, its knobs, and one row per measured config (baseline and
//! trials) with satisfaction, objective, feasibility, every metric and the
//! config; `*` marks the applied best.

use serde_json::Value;

use crate::table;

fn num(v: &Value, digits: usize) -> String {
    v.as_f64()
        .map_or("-".to_string(), |x| format!("{x:.digits$}"))
}

fn pct(v: &Value) -> String {
    v.as_f64()
        .map_or("-".to_string(), |x| format!("{:.1}%", x * 100.0))
}

/// One-line summary of a config: `/node=0.5cpu /topic>/sub=4Hz`.
pub fn config_text(c: &Value) -> String {
    let mut parts: Vec<String> = c["cpu"]
        .as_object()
        .into_iter()
        .flatten()
        .map(|(n, v)| format!("{n}={}cpu", num(v, 3)))
        .collect();
    parts.extend(c["adaptors"].as_array().into_iter().flatten().map(|a| {
        format!(
            "{}>{}={}Hz",
            a["topic"].as_str().unwrap_or("?"),
            a["subscriber"].as_str().unwrap_or("?"),
            num(&a["rateHz"], 2)
        )
    }));
    if parts.is_empty() {
        "unlimited".into()
    } else {
        parts.join(" ")
    }
}

/// `[#####.....]` for `done` of `total`.
pub fn bar(done: u64, total: u64, width: usize) -> String {
    let filled = if total == 0 {
        0
    } else {
        ((done.min(total) as f64 / total as f64) * width as f64).round() as usize
    };
    format!("[{}{}]", "#".repeat(filled), ".".repeat(width - filled))
}

/// The whole view of one PerformanceSpec object.
pub fn trials_view(obj: &Value) -> String {
    let st = &obj["status"];
    let name = obj["metadata"]["name"].as_str().unwrap_or("?");
    let done = st["trials"].as_u64().unwrap_or(0);
    let total = st["maxTrials"].as_u64().unwrap_or(0);
    let mut out = format!(
        "{name}: {}  trials {done}/{total} {}  satisfaction {}\n",
        st["phase"].as_str().unwrap_or("Pending"),
        bar(done, total, 20),
        pct(&st["satisfaction"])
    );
    if let Some(c) = st["context"].as_str() {
        out.push_str(&format!("context: {c}\n"));
    }
    let knobs: Vec<String> = st["knobs"]
        .as_array()
        .into_iter()
        .flatten()
        .map(|k| {
            let name = k["name"].as_str().unwrap_or("?");
            if k["pinnedAt"].is_number() {
                format!(
                    "{name} = {} (pinned: feeds no metric)",
                    num(&k["pinnedAt"], 2)
                )
            } else {
                format!("{name} [{}, {}]", num(&k["min"], 2), num(&k["max"], 2))
            }
        })
        .collect();
    if !knobs.is_empty() {
        out.push_str(&format!("knobs: {}\n", knobs.join(", ")));
    }
    let metrics: Vec<String> = obj["spec"]["metrics"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|m| m["name"].as_str().map(str::to_string))
        .collect();
    let mut headers: Vec<String> = ["TRIAL", "SATISFACTION", "OBJECTIVE", "FEASIBLE"]
        .map(String::from)
        .to_vec();
    headers.extend(metrics.iter().map(|m| m.to_uppercase()));
    headers.push("CONFIG".into());
    let best = st["bestTrial"].as_u64();
    let rejected: Vec<u64> = st["rejectedTrials"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(Value::as_u64)
        .collect();
    let row = |label: String, t: &Value| {
        let failed = t["index"].as_u64().is_some_and(|i| rejected.contains(&i));
        let mut r = vec![
            label,
            pct(&t["satisfaction"]),
            num(&t["objective"], 3),
            match (t["feasible"].as_bool(), t["censored"].as_bool()) {
                (_, Some(true)) => "no (stopped early)".into(),
                (Some(true), _) if failed => "yes, failed verification".into(),
                (Some(true), _) => "yes".into(),
                _ => "no".into(),
            },
        ];
        r.extend(metrics.iter().map(|m| num(&t["values"][m], 2)));
        r.push(config_text(&t["config"]));
        r
    };
    let mut rows = Vec::new();
    if !st["baseline"].is_null() {
        rows.push(row("baseline".into(), &st["baseline"]));
    }
    for t in st["trialHistory"].as_array().into_iter().flatten() {
        let i = t["index"].as_u64().unwrap_or(0);
        let mark = if best == Some(i) { "*" } else { "" };
        rows.push(row(format!("{i}{mark}"), t));
    }
    if rows.is_empty() {
        out.push_str("no trials yet\n");
    } else {
        out.push_str(&table::render(&headers, &rows));
    }
    if let (Some(i), Some(f)) = (best, st["bestTrialBackoff"].as_f64()) {
        out.push_str(&format!(
            "applied: trial {i} with its non-core knobs backed off to {:.0} %: {}\n",
            f * 100.0,
            config_text(&st["bestConfig"])
        ));
    }
    if let Some(r) = st["reason"].as_str() {
        out.push_str(&format!("reason: {r}\n"));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn view_shows_progress_rows_best_and_reason() {
        let obj = json!({
            "metadata": {"name": "nav"},
            "spec": {"metrics": [{"name": "cmd-vel"}, {"name": "det"}]},
            "status": {"phase": "Tuning", "trials": 2, "maxTrials": 4, "satisfaction": 0.5,
                "knobs": [{"name": "cpu:/det", "min": 0.05, "max": 2.0},
                          {"name": "cpu:/debug", "min": 0.05, "max": 2.0, "pinnedAt": 0.05}],
                "baseline": {"index": 0, "config": {}, "values": {"cmd-vel": 18.8, "det": 20.0},
                             "satisfaction": 0.0, "objective": 1.0, "feasible": false},
                "trialHistory": [
                    {"index": 0, "config": {"cpu": {"/det": 0.5}}, "values": {"cmd-vel": 40.0, "det": 5.0},
                     "satisfaction": 1.0, "objective": 0.5, "feasible": true},
                    {"index": 1, "config": {"adaptors": [{"topic": "/image", "subscriber": "/det", "rateHz": 3.0}]},
                     "values": {"cmd-vel": 20.0}, "satisfaction": 0.0, "feasible": false, "censored": true}],
                "bestTrial": 0, "reason": "why"}
        });
        let v = trials_view(&obj);
        let lines: Vec<&str> = v.lines().collect();
        assert_eq!(
            lines[0],
            "nav: Tuning  trials 2/4 [##########..........]  satisfaction 50.0%"
        );
        assert_eq!(
            lines[1],
            "knobs: cpu:/det [0.05, 2.00], cpu:/debug = 0.05 (pinned: feeds no metric)"
        );
        assert!(lines[2].starts_with("TRIAL"), "{v}");
        assert!(lines[2].contains("CMD-VEL"), "{v}");
        assert!(lines[3].starts_with("baseline"), "{v}");
        assert!(
            lines[4].starts_with("0*") && lines[4].ends_with("/det=0.500cpu"),
            "{v}"
        );
        assert!(
            lines[5].contains("no (stopped early)") && lines[5].ends_with("/image>/det=3.00Hz"),
            "{v}"
        );
        assert_eq!(lines[6], "reason: why");
        assert_eq!(bar(0, 0, 4), "[....]");
        assert_eq!(bar(9, 4, 4), "[####]");
    }
    #[test]
    fn view_marks_trials_that_failed_verification_and_a_backed_off_best() {
        let trial = |i: u64, cpu: f64| {
            json!({"index": i, "config": {"cpu": {"/det": cpu}}, "values": {},
                   "satisfaction": 1.0, "objective": 0.5, "feasible": true})
        };
        let obj = json!({
            "metadata": {"name": "nav"},
            "spec": {"metrics": []},
            "status": {"phase": "Monitoring", "trials": 2, "maxTrials": 2,
                "trialHistory": [trial(0, 0.5), trial(1, 1.9)],
                "rejectedTrials": [1], "bestTrial": 1, "bestTrialBackoff": 0.64,
                "bestConfig": {"cpu": {"/det": 1.2}}}
        });
        let v = trials_view(&obj);
        let rows: Vec<&str> = v.lines().filter(|l| l.starts_with(['0', '1'])).collect();
        assert!(!rows[0].contains("failed verification"), "{v}");
        assert!(rows[1].contains("yes, failed verification"), "{v}");
        assert!(
            v.contains(
                "applied: trial 1 with its non-core knobs backed off to 64 %: /det=1.200cpu"
            ),
            "{v}"
        );
    }
}
