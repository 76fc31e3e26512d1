//! Runs the ROS 1 data plane standalone: master + parameter server with
//! persistence, adaptors and graph monitor. Used by tests (kill -9/restart)
//! and for trying the agent's master by hand.
//!
//! Usage: configbot-ros1-master --uri http://localhost:PORT/ --db PATH
//!        [--adapt TOPIC=SUBSCRIBER@RATE|none]... [--refresh-secs N]

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, bail};
use configbot_dataplane::{AdaptorSetting, DataPlane, EdgeId};
use configbot_ros1::{Ros1Config, Ros1DataPlane};

fn parse_adapt(s: &str) -> anyhow::Result<(EdgeId, AdaptorSetting)> {
    let (edge, rate) = s
        .rsplit_once('@')
        .context("--adapt wants TOPIC=SUBSCRIBER@RATE")?;
    let (topic, sub) = edge
        .split_once('=')
        .context("--adapt wants TOPIC=SUBSCRIBER@RATE")?;
    let rate_hz = if rate == "none" {
        None
    } else {
        Some(rate.parse().context("bad rate")?)
    };
    Ok((
        EdgeId {
            topic: topic.into(),
            subscriber: sub.into(),
        },
        AdaptorSetting { rate_hz },
    ))
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    let _ = tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .try_init();
    let mut cfg = Ros1Config::default();
    let mut db = PathBuf::from("configbot-ros1.db");
    let mut adapt = Vec::new();
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut val = || args.next().with_context(|| format!("{a} needs a value"));
        match a.as_str() {
            "--uri" => cfg.master_uri = val()?,
            "--db" => db = PathBuf::from(val()?),
            "--adapt" => adapt.push(parse_adapt(&val()?)?),
            "--refresh-secs" => cfg.refresh_period = Duration::from_secs_f64(val()?.parse()?),
            "--adaptor-tcpros-port" => cfg.adaptor_tcpros_port = val()?.parse()?,
            "--adaptor-xmlrpc-port" => cfg.adaptor_xmlrpc_port = val()?.parse()?,
            other => bail!("unknown argument {other}"),
        }
    }
    let registry = prometheus::Registry::new();
    let dp = Ros1DataPlane::start(cfg, &db, &registry).await?;
    for (e, s) in adapt {
        dp.set_adaptor(&e, s)?;
    }
    println!(
        "configbot-ros1-master listening on {} (adaptor {})",
        dp.master_uri(),
        dp.adaptor_uri()
    );
    tokio::signal::ctrl_c().await?;
    Ok(())
}
