//! The config library's store side: a context's `ConfigProfile` looked up
//! among the stored ones, and a profile saved. What an entry is, its context
//! and its name are the pure rules of `configbot_tuning::library`.

use configbot_manifests::{ConfigProfile, Kind, ProfileContext};
use configbot_tuning::library::find;

use crate::store::{Store, StoreError};

/// Look the context up in the store.
pub fn lookup(
    store: &Store,
    namespace: &str,
    spec_name: &str,
    ctx: &ProfileContext,
) -> Result<Option<ConfigProfile>, StoreError> {
    let (all, _) = store.list(Kind::ConfigProfile, Some(namespace))?;
    Ok(find(&all, spec_name, ctx))
}

/// Store (create or replace) an entry.
pub fn save(store: &Store, p: &ConfigProfile) -> Result<(), StoreError> {
    let v = serde_json::to_value(p).map_err(|e| StoreError::Corrupt(e.to_string()))?;
    store.put(Kind::ConfigProfile, v, false)?;
    Ok(())
}
