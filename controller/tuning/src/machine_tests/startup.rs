//! The start-up wait: no baseline and no verdict before the stack's
//! declared nodes have registered and the metrics' topics flow, or the
//! start-up timeout passed (then an event names what never came up).

use configbot_manifests::{Phase, Reason};

use super::*;

/// The graph without `absent`'s node and the topics it publishes.
fn graph_without(absent: &str) -> Graph {
    let mut g = graph();
    g.nodes.remove(absent);
    g.topics.retain(|_, t| !t.publishers.contains(absent));
    g
}

fn observed_graph(g: Graph) -> Input {
    Input::Observed {
        graph: g,
        context: ctx(),
        known: None,
    }
}

/// Feeds the run the IO its effects ask for, the robot being `robot(t_ms)`
/// (graph, cmd values, det) at time t, until it leaves start-up; returns the
/// run, every event and the time it left.
fn run_start_up(
    env: &Env<'_>,
    robot: impl Fn(u64) -> (Graph, [f64; 1], f64),
) -> (Run, Vec<Reason>, Vec<String>, u64) {
    let mut run = Run::new(1, Trigger::SpecChanged);
    let (mut t, mut events, mut messages) = (0u64, Vec::new(), Vec::new());
    while name(&run.state) == "StartUp" {
        assert!(t < 600_000, "start-up never ended: {:?}", run.state);
        let (g, cmd, det) = robot(t);
        let input = match effect(&run, env) {
            Effect::Observe => observed_graph(g),
            Effect::Sleep(d) => {
                t += d.as_millis() as u64;
                Input::Slept
            }
            Effect::Measure(req) => {
                t += req.duration_ms;
                report(&cmd, det)
            }
            e => panic!("start-up asked for {e:?}"),
        };
        let (next, out) = step(run, input, env);
        run = next;
        for o in &out {
            if let Output::Event {
                reason, message, ..
            } = o
            {
                events.push(reason.clone());
                messages.push(message.clone());
            }
        }
    }
    (run, events, messages, t)
}

#[test]
fn a_stack_whose_nodes_take_10_s_to_register_gets_no_verdict_before_they_do() {
    let (st, sp) = (stack(), spec(2.0, 20));
    let env = env(&st, &sp);
    // The detector registers at 10 s and publishes from 12 s; cmd flows from the start.
    let (run, events, _, t) = run_start_up(&env, |t| {
        let g = if t < 10_000 {
            graph_without("/detector")
        } else {
            graph()
        };
        (g, [40.0], if t < 12_000 { 0.0 } else { 4.0 })
    });
    assert!(
        t >= 12_000,
        "left start-up at {t} ms, before the detector published"
    );
    assert_eq!(events, vec![Reason::StackUp]);
    assert_eq!(name(&run.state), "Observe");
    assert!(run.baseline.is_none() && run.trials.is_empty() && run.reason.is_none());
    // Then the run observes the full graph and measures its baseline.
    let (run, _) = step(run, observed(false), &env);
    assert_eq!(name(&run.state), "Baseline");
    assert_eq!(run.phase(), Phase::Baseline);
}

#[test]
fn a_node_that_never_registers_is_named_when_the_start_up_times_out() {
    let (st, mut sp) = (stack(), spec(2.0, 20));
    sp.spec.tuning.startup_timeout_seconds = 30.0;
    let env = env(&st, &sp);
    let (run, events, messages, t) =
        run_start_up(&env, |_| (graph_without("/detector"), [40.0], 0.0));
    assert!((30_000..=32_000).contains(&t), "{t}");
    assert_eq!(events, vec![Reason::StartupTimeout]);
    assert!(
        messages[0].contains("never registered: /detector")
            && messages[0].contains("no messages on the topics of det"),
        "{}",
        messages[0]
    );
    assert_eq!(name(&run.state), "Observe", "the run goes on");
}

#[test]
fn a_silent_non_core_topic_delays_the_run_by_the_grace_only() {
    let (st, sp) = (stack(), spec(2.0, 20));
    let env = env(&st, &sp);
    // Every node is there; the default config starves the detector for good.
    let (_, events, _, t) = run_start_up(&env, |_| (graph(), [40.0], 0.0));
    assert!(
        (crate::startup::NON_CORE_GRACE_MS..=crate::startup::NON_CORE_GRACE_MS + 2_000)
            .contains(&t),
        "{t}"
    );
    assert_eq!(events, vec![Reason::StackUp]);
}
