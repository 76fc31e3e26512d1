//! ConfigBot's typed API: the `RobotStack` and `PerformanceSpec` manifests.
