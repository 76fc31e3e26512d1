//! `configbot apply` and the manifest loading shared with `validate`: read
//! files, folders (recursive) or standard input, validate everything first,
//! then create or update each object (stacks before specs), optionally prune.

use std::collections::BTreeSet;
use std::io::Read;
use std::path::Path;
use std::process::ExitCode;

use crate::client::{Client, ClientError, path};
use clap::Args;
use configbot_controller::api::selector::Selector;
use configbot_manifests::{Kind, Loaded, ManifestError, ManifestErrors};
use hyper::Method;

#[derive(Debug, Args)]
pub struct ApplyArgs {
    /// Files or folders (recursive); `-` for standard input.
    #[arg(short = 'f', long = "filename", required = true)]
    files: Vec<String>,
    /// Let the server validate without storing anything.
    #[arg(long)]
    dry_run: bool,
    /// Delete objects matching -l that are not in the applied files (GitOps).
    #[arg(long, requires = "selector")]
    prune: bool,
    /// Label selector for --prune, e.g. fleet=lab.
    #[arg(short = 'l', long)]
    selector: Option<String>,
}

fn collect(path: &Path, out: &mut Vec<std::path::PathBuf>) -> std::io::Result<()> {
    if path.is_dir() {
        let mut entries: Vec<_> = std::fs::read_dir(path)?.collect::<Result<_, _>>()?;
        entries.sort_by_key(|e| e.path());
        for e in entries {
            let p = e.path();
            if p.is_dir()
                || p.extension()
                    .is_some_and(|x| x == "yaml" || x == "yml" || x == "json")
            {
                collect(&p, out)?;
            }
        }
    } else {
        out.push(path.to_path_buf());
    }
    Ok(())
}

/// Load and validate every manifest named by `-f`; all errors at once. An
/// input with no objects at all is an error ("no objects passed to `verb`").
pub fn load_all(files: &[String], verb: &str) -> Result<Vec<Loaded>, ManifestErrors> {
    let mut loaded = Vec::new();
    let mut errors = Vec::new();
    let io_error = |source: &str, message: String| ManifestError {
        source: source.into(),
        document: None,
        path: String::new(),
        line: None,
        column: None,
        message,
    };
    let mut texts = Vec::new();
    for f in files {
        if f == "-" {
            let mut s = String::new();
            match std::io::stdin()
                .take(configbot_manifests::yaml::MAX_INPUT_BYTES as u64 + 1)
                .read_to_string(&mut s)
            {
                Ok(_) => texts.push(("-".to_string(), s)),
                Err(e) => errors.push(io_error("-", e.to_string())),
            }
            continue;
        }
        let mut paths = Vec::new();
        if let Err(e) = collect(Path::new(f), &mut paths) {
            errors.push(io_error(f, e.to_string()));
        }
        for p in paths {
            let name = p.display().to_string();
            match std::fs::metadata(&p) {
                Ok(m) if m.len() as usize > configbot_manifests::yaml::MAX_INPUT_BYTES => {
                    errors.push(io_error(
                        &name,
                        format!(
                            "file is {} bytes, more than the {} byte limit for manifests",
                            m.len(),
                            configbot_manifests::yaml::MAX_INPUT_BYTES
                        ),
                    ));
                    continue;
                }
                Err(e) => {
                    errors.push(io_error(&name, e.to_string()));
                    continue;
                }
                Ok(_) => {}
            }
            match std::fs::read_to_string(&p) {
                Ok(s) => texts.push((name, s)),
                Err(e) => errors.push(io_error(&name, e.to_string())),
            }
        }
    }
    for (name, text) in &texts {
        match configbot_manifests::load(name, text) {
            Ok(l) => loaded.extend(l),
            Err(e) => errors.extend(e.0),
        }
    }
    let mut seen = BTreeSet::new();
    for l in &loaded {
        let m = l.manifest.metadata();
        if !seen.insert((l.manifest.kind(), m.namespace().to_string(), m.name.clone())) {
            errors.push(ManifestError {
                source: l.source.clone(),
                document: Some(l.document),
                path: "metadata.name".into(),
                line: None,
                column: None,
                message: format!(
                    "{} {}/{} is given twice in this input",
                    l.manifest.kind(),
                    m.namespace(),
                    m.name
                ),
            });
        }
    }
    if errors.is_empty() && loaded.is_empty() {
        errors.push(io_error(
            &files.join(", "),
            format!("no objects passed to {verb}"),
        ));
    }
    if errors.is_empty() {
        Ok(loaded)
    } else {
        Err(ManifestErrors(errors))
    }
}

/// What happened to one object.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Applied {
    Created,
    Configured,
    Unchanged,
}

impl Applied {
    pub fn word(self) -> &'static str {
        match self {
            Applied::Created => "created",
            Applied::Configured => "configured",
            Applied::Unchanged => "unchanged",
        }
    }
}

/// Create or update one object; identical content is left alone.
pub async fn apply_one(
    client: &Client,
    obj: &serde_json::Value,
    kind: Kind,
    dry_run: bool,
) -> Result<Applied, ClientError> {
    let (ns, name) = configbot_controller::store::key_of(obj);
    // The field manager its writes are recorded under in managedFields.
    let q = if dry_run {
        "?fieldManager=configbot&dryRun=All"
    } else {
        "?fieldManager=configbot"
    };
    for _attempt in 0..3 {
        match client.get(&path(kind, Some(&ns), Some(&name))).await {
            Err(ClientError::Api { code: 404, .. }) => {
                client
                    .send(
                        Method::POST,
                        &format!("{}{q}", path(kind, Some(&ns), None)),
                        Some(obj),
                        "application/json",
                    )
                    .await?;
                return Ok(Applied::Created);
            }
            Err(e) => return Err(e),
            Ok(live) => {
                let same = live.get("spec") == obj.get("spec")
                    && live["metadata"]["labels"] == obj["metadata"]["labels"]
                    && live["metadata"]["annotations"] == obj["metadata"]["annotations"];
                if same {
                    return Ok(Applied::Unchanged);
                }
                let mut body = obj.clone();
                body["metadata"]["resourceVersion"] = live["metadata"]["resourceVersion"].clone();
                match client
                    .send(
                        Method::PUT,
                        &format!("{}{q}", path(kind, Some(&ns), Some(&name))),
                        Some(&body),
                        "application/json",
                    )
                    .await
                {
                    Ok(_) => return Ok(Applied::Configured),
                    Err(ClientError::Api { code: 409, .. }) => continue,
                    Err(e) => return Err(e),
                }
            }
        }
    }
    Err(ClientError::Http(format!(
        "{kind} {ns}/{name} kept changing while applying; try again"
    )))
}

pub async fn run(client: &Client, a: &ApplyArgs) -> anyhow::Result<ExitCode> {
    let mut loaded = match load_all(&a.files, "apply") {
        Ok(l) => l,
        Err(e) => {
            eprintln!("{e}");
            eprintln!("nothing was applied");
            return Ok(ExitCode::FAILURE);
        }
    };
    loaded.sort_by_key(|l| l.manifest.kind());
    let suffix = if a.dry_run { " (dry run)" } else { "" };
    let mut failed = false;
    let mut applied = BTreeSet::new();
    for l in &loaded {
        let kind = l.manifest.kind();
        let m = l.manifest.metadata();
        applied.insert((kind, m.namespace().to_string(), m.name.clone()));
        let mut obj = l.value.clone();
        obj["metadata"]["namespace"] = m.namespace().into();
        match apply_one(client, &obj, kind, a.dry_run).await {
            Ok(r) => println!(
                "{}.{}/{} {}{suffix}",
                kind.singular(),
                configbot_manifests::GROUP,
                m.name,
                r.word()
            ),
            Err(e) => {
                eprintln!(
                    "error: {}: document {}: {} {:?}: {e}",
                    l.source, l.document, kind, m.name
                );
                failed = true;
            }
        }
    }
    if a.prune && !failed {
        let sel =
            Selector::parse(a.selector.as_deref().unwrap_or("")).map_err(anyhow::Error::msg)?;
        for kind in Kind::ALL.into_iter().rev() {
            let list = client.get(&path(kind, None, None)).await?;
            for item in list["items"].as_array().into_iter().flatten() {
                let (ns, name) = configbot_controller::store::key_of(item);
                if sel.matches_object(item) && !applied.contains(&(kind, ns.clone(), name.clone()))
                {
                    if !a.dry_run {
                        client
                            .send(
                                Method::DELETE,
                                &path(kind, Some(&ns), Some(&name)),
                                None,
                                "application/json",
                            )
                            .await?;
                    }
                    println!(
                        "{}.{}/{name} pruned{suffix}",
                        kind.singular(),
                        configbot_manifests::GROUP
                    );
                }
            }
        }
    }
    Ok(if failed {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    })
}
