//! `configbot-agent`: the node agent daemon (see `configbot_agent::cli`).

use clap::Parser;

#[derive(Debug, Parser)]
#[command(name = "configbot-agent", about = "ConfigBot node agent")]
struct Cli {
    #[command(flatten)]
    args: configbot_agent::cli::AgentArgs,
}

#[tokio::main(flavor = "current_thread")]
async fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    configbot_agent::cli::init_logging();
    configbot_agent::cli::run(cli.args)
        .await
        .map_err(|e| anyhow::anyhow!(configbot_agent::agent::error_chain(&e)))
}
