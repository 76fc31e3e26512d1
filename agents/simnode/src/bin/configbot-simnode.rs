//! Standalone simnode (`configbot-simnode ...`, the same arguments as
//! `configbot simnode ...`); used by the tests and by hand.

use clap::Parser;
use configbot_simnode::SimnodeArgs;

/// A configurable ROS 1 node modelling robot apps with real CPU work.
#[derive(Debug, Parser)]
#[command(name = "configbot-simnode", version)]
struct Cli {
    #[command(flatten)]
    args: SimnodeArgs,
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    rt.block_on(configbot_simnode::run(cli.args))?;
    Ok(())
}
