//! Remediation: which apps are paused and how, what is recorded, undoing it
//! on a spec change, and reading runs persisted by older versions.

use configbot_manifests::performance_spec::RemediationAction;

use super::*;
use crate::outcome;

#[test]
fn a_spec_change_while_remediating_resumes_the_paused_apps_first() {
    let mut old = with(State::Remediating {
        remedy: paused("obj"),
    });
    old.current = cfg();
    let new = Run::after_spec_change(old, 7);
    assert_eq!(new.generation, 7);
    assert_eq!(
        new.state,
        State::RemediateUndo {
            remedy: paused("obj"),
        }
    );
    assert_eq!(new.current, cfg());
    // Any other state starts over: waiting for the stack, then observing.
    let fresh = Run::after_spec_change(
        with(State::Observe {
            trigger: Trigger::SpecChanged,
            skip_library: false,
        }),
        8,
    );
    assert_eq!(name(&fresh.state), "StartUp");
}

#[test]
fn remediation_pauses_the_running_non_core_apps_as_the_spec_says() {
    let st = stack();
    let mut sp = spec(2.0, 5).spec;
    let remedy = |sp: &PerformanceSpecSpec, ctx: Option<&ProfileContext>| {
        let env = Env {
            stack: &st,
            spec: sp,
            namespace: "default",
            spec_name: "p",
            cpus: 2.0,
            tuning_allowed: false,
        };
        let mut out = Vec::new();
        let State::RemediatePause { remedy } = remediate(&env, ctx, &mut out) else {
            panic!("not pausing")
        };
        let Output::Event { message, .. } = &out[0] else {
            panic!()
        };
        (remedy, message.clone())
    };
    let (r, msg) = remedy(&sp, Some(&ctx()));
    assert_eq!(r, paused("det"));
    assert!(msg.contains("stopping det"), "{msg}");
    sp.remediation.action = RemediationAction::FreezeNonCore;
    sp.remediation.record_rosbag = true;
    let (r, msg) = remedy(&sp, Some(&ctx()));
    assert_eq!(
        r,
        Remedy {
            apps: vec!["det".into()],
            freeze: true,
            record: true
        }
    );
    assert!(msg.contains("freezing det"), "{msg}");
    // A non-core app that is not running is left alone; nothing paused, nothing recorded.
    let nav_only = ProfileContext {
        apps: vec!["nav".into()],
        ..ctx()
    };
    let (r, _) = remedy(&sp, Some(&nav_only));
    assert_eq!(
        r,
        Remedy {
            freeze: true,
            ..Remedy::default()
        }
    );
    sp.remediation.action = RemediationAction::None;
    assert!(remedy(&sp, Some(&ctx())).0.apps.is_empty());
}

#[test]
fn a_remediation_records_what_the_paused_apps_subscribe_to() {
    let mut g = graph();
    g.topics.insert(
        "/cmd_vel".into(),
        TopicInfo {
            name: "/cmd_vel".into(),
            msg_type: "m/M".into(),
            publishers: ["/planner".to_string()].into(),
            subscribers: ["/base".to_string(), "/camera".to_string()].into(),
        },
    );
    assert_eq!(
        outcome::paused_inputs(&stack(), &g, &["det".into()]),
        vec!["/cmd_vel".to_string(), "/image".to_string()]
    );
    assert!(outcome::paused_inputs(&stack(), &g, &["nav".into()]).is_empty());
    assert!(outcome::paused_inputs(&stack(), &g, &[]).is_empty());
}

#[test]
fn a_remediation_persisted_before_freezing_existed_still_reads() {
    let remedy = paused("det");
    for (tag, want) in [
        (
            "remediateStop",
            State::RemediatePause {
                remedy: remedy.clone(),
            },
        ),
        ("remediateUndo", State::RemediateUndo { remedy }),
    ] {
        let old: State =
            serde_json::from_value(serde_json::json!({"state": tag, "apps": ["det"]})).unwrap();
        assert_eq!(old, want, "{tag}");
    }
    // And today's form round-trips.
    let now = State::Remediating {
        remedy: Remedy {
            apps: vec!["det".into()],
            freeze: true,
            record: true,
        },
    };
    let back: State = serde_json::from_value(serde_json::to_value(&now).unwrap()).unwrap();
    assert_eq!(back, now);
}

#[test]
fn recording_names_are_unique_and_fit_a_file_name() {
    assert_eq!(outcome::recording_name("default", "nav"), "default.nav");
    assert_ne!(
        outcome::recording_name("a-b", "c"),
        outcome::recording_name("a", "b-c")
    );
    let long = "x".repeat(253);
    let (a, b) = (
        outcome::recording_name("default", &long),
        outcome::recording_name("default", &format!("{}y", &long[1..])),
    );
    assert!(a.len() <= 200 && b.len() <= 200, "{} {}", a.len(), b.len());
    assert_ne!(a, b);
}
