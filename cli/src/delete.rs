//! `configbot delete`: objects named on the command line, every object of a
//! kind matching a label selector (`-l`), or the objects of manifest files
//! (`-f`, specs before the stacks they refer to). `--dry-run` asks the server
//! to check each delete without doing it.

use std::process::ExitCode;

use clap::Args;
use configbot_manifests::Kind;
use hyper::Method;

use super::get::kind;
use crate::client::{Client, ClientError, path};

#[derive(Debug, Args)]
#[command(group = clap::ArgGroup::new("what").required(true).multiple(true).args(["kind", "files"]))]
pub struct DeleteArgs {
    /// Kind: robotstack (rs), performancespec (pspec), configprofile (cprof).
    kind: Option<String>,
    /// Object names (with KIND).
    names: Vec<String>,
    /// Delete the objects these manifest files or folders describe.
    #[arg(short = 'f', long = "filename", conflicts_with_all = ["kind", "selector"])]
    files: Vec<String>,
    /// With KIND: delete every object matching this label selector, e.g. fleet=lab.
    #[arg(short = 'l', long, conflicts_with = "names")]
    selector: Option<String>,
    #[arg(short = 'n', long, default_value = "default")]
    namespace: String,
    /// Let the server check each delete without doing it.
    #[arg(long)]
    dry_run: bool,
    /// An object that does not exist is not an error.
    #[arg(long)]
    ignore_not_found: bool,
}

/// The objects to delete, in order: (kind, namespace, name).
async fn targets(client: &Client, a: &DeleteArgs) -> anyhow::Result<Vec<(Kind, String, String)>> {
    if !a.files.is_empty() {
        let loaded =
            super::apply::load_all(&a.files, "delete").map_err(|e| anyhow::anyhow!("{e}"))?;
        let mut t: Vec<_> = loaded
            .iter()
            .map(|l| {
                let m = l.manifest.metadata();
                (l.manifest.kind(), m.namespace().to_string(), m.name.clone())
            })
            .collect();
        // Apply creates stacks first; delete takes what refers to them first.
        t.sort_by_key(|(k, _, _)| std::cmp::Reverse(*k));
        return Ok(t);
    }
    let word = a.kind.as_deref().unwrap_or_default();
    let kind = kind(word)?;
    if let Some(sel) = &a.selector {
        let list = client
            .get(&format!(
                "{}?labelSelector={}",
                path(kind, Some(&a.namespace), None),
                encode_query(sel)
            ))
            .await?;
        return Ok(list["items"]
            .as_array()
            .into_iter()
            .flatten()
            .map(|o| {
                let (ns, name) = configbot_controller::store::key_of(o);
                (kind, ns, name)
            })
            .collect());
    }
    anyhow::ensure!(
        !a.names.is_empty(),
        "name the {} to delete, or select them with -l SELECTOR",
        kind.plural()
    );
    Ok(a.names
        .iter()
        .map(|n| (kind, a.namespace.clone(), n.clone()))
        .collect())
}

/// Percent-encode a query value (selectors contain `=`, `,`, `!` and spaces).
pub(super) fn encode_query(s: &str) -> String {
    s.bytes()
        .map(|b| match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'-' | b'_' | b'.' | b'~' => {
                (b as char).to_string()
            }
            _ => format!("%{b:02X}"),
        })
        .collect()
}

pub async fn run(client: &Client, a: &DeleteArgs) -> anyhow::Result<ExitCode> {
    let targets = targets(client, a).await?;
    if targets.is_empty() {
        eprintln!("No resources found in {} namespace.", a.namespace);
        return Ok(ExitCode::SUCCESS);
    }
    let (q, suffix) = if a.dry_run {
        ("?dryRun=All", " (server dry run)")
    } else {
        ("", "")
    };
    let mut failed = false;
    for (kind, ns, name) in targets {
        let res = client
            .send(
                Method::DELETE,
                &format!("{}{q}", path(kind, Some(&ns), Some(&name))),
                None,
                "application/json",
            )
            .await;
        match res {
            Ok(_) => println!(
                "{}.{}/{name} deleted{suffix}",
                kind.singular(),
                configbot_manifests::GROUP
            ),
            Err(ClientError::Api { code: 404, .. }) if a.ignore_not_found => {}
            Err(e) => {
                eprintln!("error: {} {ns}/{name}: {e}", kind.singular());
                failed = true;
            }
        }
    }
    Ok(if failed {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn selectors_are_encoded_for_the_query() {
        assert_eq!(
            encode_query("fleet=lab,tier!=x"),
            "fleet%3Dlab%2Ctier%21%3Dx"
        );
        assert_eq!(encode_query("env in (a, b)"), "env%20in%20%28a%2C%20b%29");
    }
}
