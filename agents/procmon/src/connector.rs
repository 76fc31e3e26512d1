//! placeholder
use crate::{MonitorConfig, ProcEvent, Shared, Started};
use std::sync::Arc;
use tokio::sync::mpsc;

/// Errors.
#[derive(Debug, thiserror::Error)]
pub enum ConnectorError {
    #[error("not implemented")]
    NotImplemented,
}

pub(crate) async fn start(
    _c: &MonitorConfig,
    _tx: mpsc::Sender<ProcEvent>,
    _s: Arc<Shared>,
) -> Result<Started, ConnectorError> {
    Err(ConnectorError::NotImplemented)
}
