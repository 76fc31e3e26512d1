//! Every `configbot simnode ...` command line in `manifests/examples/*.yaml`
//! parses with this crate's CLI and resolves into a node config whose node
//! name matches the manifest's node name.

use std::path::Path;

use clap::Parser;
use configbot_manifests::{Manifest, load};
use configbot_simnode::SimnodeArgs;

#[derive(Debug, Parser)]
struct Cli {
    #[command(flatten)]
    args: SimnodeArgs,
}

#[test]
fn example_stacks_simnode_command_lines_parse() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../manifests/examples");
    let mut checked = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "yaml") {
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap();
        for l in load(&path.display().to_string(), &text).unwrap() {
            let Manifest::RobotStack(stack) = l.manifest else {
                continue;
            };
            for node in stack.spec.apps.iter().flat_map(|a| &a.nodes) {
                let Some(run) = &node.run else { continue };
                if run.args.first().map(String::as_str) != Some("simnode") {
                    continue;
                }
                let argv = std::iter::once("configbot-simnode")
                    .chain(run.args[1..].iter().map(String::as_str));
                let cli = Cli::try_parse_from(argv)
                    .unwrap_or_else(|e| panic!("{}: node {}: {e}", path.display(), node.name));
                let cfg = cli.args.config().unwrap();
                assert_eq!(cfg.name, node.name, "{}", path.display());
                assert!(
                    !cfg.publish.is_empty() || !cfg.callbacks.is_empty(),
                    "{}: {} does nothing",
                    path.display(),
                    node.name
                );
                checked += 1;
            }
        }
    }
    assert!(checked >= 15, "only {checked} simnode command lines found");
}
