//! Maps the `RobotStack` manifest (crate `configbot-manifests`) onto the
//! agent's plain [`StackSpec`]: app `core` becomes each node's `core`, `run`
//! and `match` carry over field by field (`match.cmdline` is the agent's
//! `cmdlineRegex`, `match.rosNode` its `rosNode`). Pure.

use std::path::PathBuf;

use configbot_cgroups::NodeName;
use configbot_manifests::RobotStack;
use configbot_manifests::robot_stack as m;

use crate::error::{Error, Result};
use crate::spec::{AppSpec, MatchSpec, NodeSource, NodeSpec, RestartPolicy, RunSpec, StackSpec};

impl StackSpec {
    /// The agent's view of a `RobotStack`; errors name the offending node.
    pub fn from_manifest(stack: &RobotStack) -> Result<Self> {
        let mut apps = Vec::with_capacity(stack.spec.apps.len());
        for app in &stack.spec.apps {
            let mut nodes = Vec::with_capacity(app.nodes.len());
            for n in &app.nodes {
                nodes.push(node(app, n)?);
            }
            apps.push(AppSpec {
                name: app.name.clone(),
                nodes,
                inputs: app
                    .inputs
                    .iter()
                    .filter(|_| !app.core)
                    .map(|i| configbot_api::graph::EdgeId {
                        topic: i.topic.clone(),
                        subscriber: i.node.clone(),
                    })
                    .collect(),
            });
        }
        let spec = StackSpec { apps };
        spec.validate().map_err(Error::InvalidStack)?;
        Ok(spec)
    }
}

fn node(app: &m::App, n: &m::Node) -> Result<NodeSpec> {
    let bad = |why: &str| Error::InvalidStack(format!("app {} node {}: {why}", app.name, n.name));
    let name = NodeName::new(&n.name).map_err(|e| bad(&e.to_string()))?;
    let source = match (&n.run, &n.match_) {
        (Some(r), None) => NodeSource::Run(RunSpec {
            command: r.command.clone(),
            args: r.args.clone(),
            env: r.env.clone(),
            working_dir: r.working_dir.as_ref().map(PathBuf::from),
            user: r.user.clone(),
            restart_policy: match r.restart_policy {
                m::RestartPolicy::Always => RestartPolicy::Always,
                m::RestartPolicy::OnFailure => RestartPolicy::OnFailure,
                m::RestartPolicy::Never => RestartPolicy::Never,
            },
        }),
        (None, Some(mm)) => NodeSource::Match(MatchSpec {
            process_name: mm.process_name.clone(),
            cmdline_regex: mm.cmdline.clone(),
            ros_node: mm.ros_node.clone(),
        }),
        _ => return Err(bad("needs exactly one of run and match")),
    };
    Ok(NodeSpec {
        name,
        core: app.core,
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const YAML: &str = r#"
apiVersion: configbot.dev/v1alpha1
kind: RobotStack
metadata: {name: bot}
spec:
  apps:
    - name: nav
      core: true
      nodes:
        - name: /talker
          run: {command: /usr/bin/python3, args: [t.py], env: {A: "1"}, workingDir: /tmp, restartPolicy: OnFailure}
    - name: det
      nodes:
        - name: /listener
          match: {rosNode: /listener}
        - name: /cam
          match: {cmdline: "cam.*node"}
"#;

    fn load() -> RobotStack {
        let docs = configbot_manifests::load("t.yaml", YAML).unwrap();
        match &docs[0].manifest {
            configbot_manifests::Manifest::RobotStack(s) => s.clone(),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn maps_apps_core_run_and_match() {
        let s = StackSpec::from_manifest(&load()).unwrap();
        let nodes: Vec<(&str, &NodeSpec)> = s.nodes().collect();
        assert_eq!(nodes.len(), 3);
        let (app, talker) = nodes[0];
        assert_eq!(
            (app, talker.name.as_str(), talker.core),
            ("nav", "/talker", true)
        );
        let NodeSource::Run(r) = &talker.source else {
            panic!("run expected")
        };
        assert_eq!(r.restart_policy, RestartPolicy::OnFailure);
        assert_eq!(r.working_dir.as_deref(), Some(std::path::Path::new("/tmp")));
        assert_eq!(r.env["A"], "1");
        let (_, listener) = nodes[1];
        assert!(!listener.core);
        assert_eq!(
            listener.source,
            NodeSource::Match(MatchSpec {
                ros_node: Some("/listener".into()),
                ..MatchSpec::default()
            })
        );
        let NodeSource::Match(cam) = &nodes[2].1.source else {
            panic!("match expected")
        };
        assert_eq!(cam.cmdline_regex.as_deref(), Some("cam.*node"));
    }

    #[test]
    fn bad_node_is_named() {
        let mut st = load();
        st.spec.apps[1].nodes[1].match_ = None;
        let e = StackSpec::from_manifest(&st).unwrap_err().to_string();
        assert!(e.contains("node /cam"), "{e}");
    }
}
