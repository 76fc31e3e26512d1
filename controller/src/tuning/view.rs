//! `configbot get trials SPEC` (pure): a PerformanceSpec's tuning run as a
//! progress line, its knobs, and one row per measured config (baseline and
//! trials) with satisfaction, objective, feasibility, every metric and the
//! config; `*` marks the applied best.

use configbot_manifests::performance_spec::TrialStatus;
use configbot_manifests::{PerformanceSpecStatus, ResourceConfig};
use serde_json::Value;

use crate::table;

fn num(v: Option<f64>, digits: usize) -> String {
    v.map_or("-".to_string(), |x| format!("{x:.digits$}"))
}

fn pct(v: Option<f64>) -> String {
    v.map_or("-".to_string(), |x| format!("{:.1}%", x * 100.0))
}

/// One-line summary of a config: `/node=0.5cpu /topic>/sub=4Hz weight(/a,/b)=1000`.
pub fn config_text(c: &ResourceConfig) -> String {
    let mut parts: Vec<String> = c
        .cpu
        .iter()
        .map(|(n, v)| format!("{n}={v:.3}cpu"))
        .collect();
    parts.extend(
        c.adaptors
            .iter()
            .map(|a| format!("{}>{}={:.2}Hz", a.topic, a.subscriber, a.rate_hz)),
    );
    // Nodes of one weight together: `weight(/a,/b)=1000`.
    let mut by_weight: std::collections::BTreeMap<u32, Vec<&str>> = Default::default();
    for (n, w) in &c.cpu_weight {
        by_weight.entry(*w).or_default().push(n);
    }
    parts.extend(
        by_weight
            .iter()
            .map(|(w, nodes)| format!("weight({})={w}", nodes.join(","))),
    );
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

/// The whole view of one PerformanceSpec object; fails when its status does
/// not decode.
pub fn trials_view(obj: &Value) -> Result<String, serde_json::Error> {
    let st: PerformanceSpecStatus = configbot_manifests::decode_status(obj)?;
    let name = obj["metadata"]["name"].as_str().unwrap_or("?");
    let metrics: Vec<String> = obj["spec"]["metrics"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|m| m["name"].as_str().map(str::to_string))
        .collect();
    Ok(view(name, &metrics, &st))
}

fn view(name: &str, metrics: &[String], st: &PerformanceSpecStatus) -> String {
    let (done, total) = (st.trials, st.max_trials.unwrap_or(0));
    let mut out = format!(
        "{name}: {}  trials {done}/{total} {}  satisfaction {}\n",
        st.phase,
        bar(done.into(), total.into(), 20),
        pct(st.satisfaction)
    );
    if let Some(c) = &st.context {
        out.push_str(&format!("context: {c}\n"));
    }
    let knobs: Vec<String> = st
        .knobs
        .iter()
        .map(|k| match k.pinned_at {
            Some(p) => format!("{} = {p:.2} (pinned: feeds no metric)", k.name),
            None => format!("{} [{:.2}, {:.2}]", k.name, k.min, k.max),
        })
        .collect();
    if !knobs.is_empty() {
        out.push_str(&format!("knobs: {}\n", knobs.join(", ")));
    }
    let mut headers: Vec<String> = ["TRIAL", "SATISFACTION", "OBJECTIVE", "FEASIBLE"]
        .map(String::from)
        .to_vec();
    headers.extend(metrics.iter().map(|m| m.to_uppercase()));
    headers.push("CONFIG".into());
    let row = |label: String, t: &TrialStatus| {
        let failed = st.rejected_trials.contains(&t.index);
        let mut r = vec![
            label,
            pct(Some(t.satisfaction)),
            num(t.objective, 3),
            match (t.feasible, t.censored) {
                (_, true) => "no (stopped early)".into(),
                (true, _) if failed => "yes, failed verification".into(),
                (true, _) => "yes".into(),
                _ => "no".into(),
            },
        ];
        r.extend(metrics.iter().map(|m| num(t.values.get(m).copied(), 2)));
        r.push(config_text(&t.config));
        r
    };
    let mut rows = Vec::new();
    if let Some(b) = &st.baseline {
        rows.push(row("baseline".into(), b));
    }
    for t in &st.trial_history {
        let mark = if st.best_trial == Some(t.index) {
            "*"
        } else {
            ""
        };
        rows.push(row(format!("{}{mark}", t.index), t));
    }
    if rows.is_empty() {
        out.push_str("no trials yet\n");
    } else {
        out.push_str(&table::render(&headers, &rows));
    }
    if let (Some(i), Some(f)) = (st.best_trial, st.best_trial_backoff) {
        out.push_str(&format!(
            "applied: trial {i} with its non-core knobs backed off (as safe as all at {:.0} %): {}\n",
            f * 100.0,
            config_text(&st.best_config.clone().unwrap_or_default())
        ));
    }
    if let Some(r) = &st.reason {
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
                    {"index": 0, "config": {"cpu": {"/det": 0.5}, "cpuWeight": {"/plan": 1000, "/lidar": 1000}}, "values": {"cmd-vel": 40.0, "det": 5.0},
                     "satisfaction": 1.0, "objective": 0.5, "feasible": true},
                    {"index": 1, "config": {"adaptors": [{"topic": "/image", "subscriber": "/det", "rateHz": 3.0}]},
                     "values": {"cmd-vel": 20.0}, "satisfaction": 0.0, "feasible": false, "censored": true}],
                "bestTrial": 0, "reason": "why"}
        });
        let v = trials_view(&obj).unwrap();
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
            lines[4].starts_with("0*")
                && lines[4].ends_with("/det=0.500cpu weight(/lidar,/plan)=1000"),
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
        let v = trials_view(&obj).unwrap();
        let rows: Vec<&str> = v.lines().filter(|l| l.starts_with(['0', '1'])).collect();
        assert!(!rows[0].contains("failed verification"), "{v}");
        assert!(rows[1].contains("yes, failed verification"), "{v}");
        assert!(
            v.contains(
                "applied: trial 1 with its non-core knobs backed off (as safe as all at 64 %): /det=1.200cpu"
            ),
            "{v}"
        );
    }
}
