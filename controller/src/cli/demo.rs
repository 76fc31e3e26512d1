//! `configbot demo`: start a private control plane with embedded defaults,
//! apply the example stacks shipped in the binary, wait for the reconcilers,
//! and show the result as `get` and `describe` would.

use std::process::ExitCode;
use std::time::Duration;

use clap::Args;
use crate::client::{Client, Endpoint, path};
use crate::server::{Server, ServerConfig};
use configbot_manifests::Kind;

/// The example stacks, embedded so the demo runs from any directory.
const EXAMPLES: [(&str, &str); 3] = [
    (
        "basic-nav.yaml",
        include_str!("../../../manifests/examples/basic-nav.yaml"),
    ),
    (
        "intermed-nav.yaml",
        include_str!("../../../manifests/examples/intermed-nav.yaml"),
    ),
    (
        "terrain-nav.yaml",
        include_str!("../../../manifests/examples/terrain-nav.yaml"),
    ),
];

#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Keep the demo's control plane running afterwards (until Ctrl-C).
    #[arg(long)]
    keep: bool,
}

pub async fn run(a: &DemoArgs) -> anyhow::Result<ExitCode> {
    let dir = std::env::temp_dir().join(format!("configbot-demo-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let cfg = ServerConfig {
        db: dir.join("configbot.db"),
        socket: dir.join("configbot.sock"),
        tcp: None,
    };
    println!(
        "==> starting a control plane (database {}, socket {})",
        cfg.db.display(),
        cfg.socket.display()
    );
    let server = Server::start(&cfg).await?;
    let client = Client::new(Endpoint::Unix(cfg.socket.clone()));
    println!("==> applying the example stacks");
    let mut loaded = Vec::new();
    for (name, text) in EXAMPLES {
        loaded.extend(configbot_manifests::load(name, text)?);
    }
    loaded.sort_by_key(|l| l.manifest.kind());
    for l in &loaded {
        let obj = l.manifest.to_json();
        let r = super::apply::apply_one(&client, &obj, l.manifest.kind(), false).await?;
        println!(
            "{}.{}/{} {}",
            l.manifest.kind().singular(),
            configbot_manifests::GROUP,
            l.manifest.metadata().name,
            r.word()
        );
    }
    // Wait until every object's status reflects its current generation.
    let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
    loop {
        let mut done = true;
        for kind in Kind::ALL {
            let list = client.get(&path(kind, Some("default"), None)).await?;
            for o in list["items"].as_array().into_iter().flatten() {
                done &= o["status"]["observedGeneration"] == o["metadata"]["generation"];
            }
        }
        if done || tokio::time::Instant::now() > deadline {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let server_arg = format!("unix://{}", cfg.socket.display());
    for kind in Kind::ALL {
        println!("\n==> configbot get {}", kind.short_names()[0]);
        let list = client.get(&path(kind, Some("default"), None)).await?;
        let items = list["items"].as_array().cloned().unwrap_or_default();
        let now = time::OffsetDateTime::now_utc();
        let rows: Vec<Vec<String>> = items
            .iter()
            .map(|o| crate::table::row(kind, o, false, false, now))
            .collect();
        print!(
            "{}",
            crate::table::render(
                &crate::table::headers(kind, false, false),
                &rows
            )
        );
    }
    println!("\n==> configbot describe pspec basic-nav");
    super::get::describe(
        &client,
        &super::get::DescribeArgs::for_demo("pspec", "basic-nav"),
    )
    .await?;
    println!("\nTuning live stacks needs the node agent (coming with the agent and tuning loop).");
    if a.keep {
        println!(
            "\nThe control plane keeps running: configbot --server {server_arg} get rs   (Ctrl-C to stop)"
        );
        let _ = tokio::signal::ctrl_c().await;
    }
    server.stop();
    let _ = std::fs::remove_dir_all(&dir);
    Ok(ExitCode::SUCCESS)
}
