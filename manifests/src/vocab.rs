//! The status vocabulary: the phases of a PerformanceSpec ([`Phase`]) and of a
//! RobotStack ([`StackPhase`]), and the reasons of conditions and events
//! ([`Reason`]). Each value is written as its name (`"Monitoring"`,
//! `"LibraryHit"`), exactly the strings these fields have always held.
//!
//! The JSON Schema lists the known values, so a cluster holding the CRDs
//! rejects a new write of an unknown one. Reading stays tolerant: a value this
//! version does not know (stored by another version, or written by another
//! client through the status subresource) decodes as `Other` and is written
//! back unchanged, so an old object never loses its status for one word.

use std::borrow::Cow;
use std::fmt;

use schemars::{JsonSchema, Schema, SchemaGenerator, json_schema};
use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// An enum of known names plus `Other(String)`, written as the name.
macro_rules! vocabulary {
    (
        $(#[$meta:meta])*
        pub enum $name:ident {
            $( $(#[$vmeta:meta])* $variant:ident, )+
        }
    ) => {
        $(#[$meta])*
        #[derive(Debug, Clone, PartialEq, Eq, Hash)]
        pub enum $name {
            $( $(#[$vmeta])* $variant, )+
            /// A value this version does not know, kept as written.
            Other(String),
        }

        impl $name {
            /// The name, as written in status and events.
            pub fn as_str(&self) -> &str {
                match self {
                    $( $name::$variant => stringify!($variant), )+
                    $name::Other(s) => s,
                }
            }

            /// The value named `s` (`Other` when the name is unknown).
            pub fn parse(s: &str) -> $name {
                match s {
                    $( stringify!($variant) => $name::$variant, )+
                    other => $name::Other(other.to_owned()),
                }
            }
        }

        impl fmt::Display for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.pad(self.as_str())
            }
        }

        impl Serialize for $name {
            fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                s.serialize_str(self.as_str())
            }
        }

        impl<'de> Deserialize<'de> for $name {
            fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                let s = Cow::<'de, str>::deserialize(d)?;
                Ok($name::parse(&s))
            }
        }

        impl JsonSchema for $name {
            fn schema_name() -> Cow<'static, str> {
                stringify!($name).into()
            }

            fn json_schema(_: &mut SchemaGenerator) -> Schema {
                json_schema!({
                    "type": "string",
                    "enum": [ $( stringify!($variant) ),+ ],
                })
            }
        }
    };
}

vocabulary! {
    /// Where a PerformanceSpec is: the reconciler's phases (`Pending`,
    /// `Accepted`, `Invalid`), then the tuning run's (the rest).
    #[derive(Default)]
    pub enum Phase {
        /// Not reconciled yet, or its RobotStack does not exist.
        #[default]
        Pending,
        /// Valid, with its stack found; no tuning run has reported yet.
        Accepted,
        /// Fails validation, or does not match its stack.
        Invalid,
        /// Waiting for the stack, reading the context, measuring the baseline.
        Baseline,
        /// Measuring trials.
        Tuning,
        /// Verifying the best trial's config.
        Satisfied,
        /// No config meets every core constraint; the safest one is applied.
        Unsat,
        /// A verified config is applied and monitored.
        Monitoring,
        /// A core constraint is violated while tuning is not allowed: non-core
        /// apps are stopped or frozen.
        Remediating,
    }
}

vocabulary! {
    /// Where a RobotStack is.
    #[derive(Default)]
    pub enum StackPhase {
        /// Not reconciled yet.
        #[default]
        Pending,
        /// Valid; the robot may run it.
        Accepted,
        /// Fails validation.
        Invalid,
    }
}

vocabulary! {
    /// Why a condition is what it is, or why an event was recorded.
    pub enum Reason {
        // The API server's events.
        /// An object was created.
        Created,
        /// An object was changed.
        Updated,
        /// An object was deleted.
        Deleted,
        // The reconciler's conditions and events.
        /// A RobotStack passed validation.
        Accepted,
        /// A PerformanceSpec passed validation against its stack.
        Valid,
        /// An object fails validation.
        Invalid,
        /// A PerformanceSpec's stack exists.
        StackFound,
        /// A PerformanceSpec's stack does not exist.
        StackNotFound,
        /// A PerformanceSpec does not match its stack.
        StackMismatch,
        /// No tuning run has measured the spec yet.
        NotMeasured,
        // The tuning run's conditions.
        /// A run is measuring (baseline, trials or verification).
        Tuning,
        /// The core constraints hold with the applied config.
        Satisfied,
        /// No config meets every core constraint.
        Unsat,
        /// Non-core apps are stopped or frozen until tuning is allowed.
        Remediating,
        /// The applied config was re-applied from the config library.
        LibraryConfig,
        // The tuning run's events: what starts or restarts a run.
        /// The spec was created or changed.
        SpecChanged,
        /// A core constraint was violated for the whole violation window.
        ConstraintViolated,
        /// The running apps or nodes (or the labels) changed.
        ContextChanged,
        /// A config from the library did not hold.
        LibraryConfigFailed,
        /// Tuning is allowed again after a remediation.
        TuningAllowed,
        // The tuning run's events: its steps.
        /// A persisted run resumed after a restart.
        Resumed,
        /// Every node the stack starts registered and its metrics flow.
        StackUp,
        /// The stack did not come up in time; the run goes on.
        StartupTimeout,
        /// A familiar context: its library config is re-applied.
        LibraryHit,
        /// The baseline was measured.
        Baseline,
        /// The knob space could not be built.
        KnobsInvalid,
        /// Safe exploration is off: no knob can starve a core service.
        SafeExplorationOff,
        /// The optimizer was warm-started from library trials.
        WarmStart,
        /// The baseline misses a core target: the restrictive corner first.
        FeasibilityFirst,
        /// The optimizer failed.
        OptimizerFailed,
        /// A trial was measured.
        Trial,
        /// A trial's config settled later than the minimum settle time.
        SettledLate,
        /// A trial is near a constraint's boundary, or a verification's
        /// margin is short of the bar: it is measured longer.
        NearBoundary,
        /// A trial among the best so far counted few messages on an
        /// objective: it is measured longer.
        FewMessages,
        /// A trial meets every target with every objective capped.
        ObjectivesCapped,
        /// A trial capped every objective but missed a core target: the
        /// initial design ends and the models choose the next trials.
        DesignEnded,
        /// The next trial is the balanced config, computed from what the
        /// trials measured the apps' costs at, not proposed by the models.
        Balancing,
        /// The optimizer's stopping rule ended the search.
        TuningStopped,
        /// A trial is verified with the input of non-core apps whose
        /// objectives measured more than counts cut down to what does.
        TrimmingSurplus,
        /// A config held its verification with its worst objectives below
        /// the others: it is verified again with the knobs that work only
        /// for them raised; or such a lift gave no more objective and the
        /// config it raised is applied again.
        LiftingObjectives,
        /// A config failed its verification.
        VerificationFailed,
        /// A verification missed in bursts: the core nodes are weighted
        /// from now on and the candidate is verified again; or a weighted
        /// config set aside (see `CoreUnweighted`) is verified again.
        CoreWeighted,
        /// A weighted verification held with less objective than a back-off
        /// of its trial promises: the weight is dropped and the back-off is
        /// verified unweighted; the weighted config is verified again when
        /// nothing better holds.
        CoreUnweighted,
        /// A rejected best trial is verified again with its knobs backed off.
        BackingOff,
        /// A held config tipped, or a measured trial promises more than a
        /// back-off; the next best trial is verified.
        VerifyingNextBest,
        /// A trial failed its verification with trials left in the budget:
        /// the search goes on, its models revised by what the verification
        /// measured.
        SearchingOn,
        /// The inputs of paused apps are being recorded.
        RecordingInputs,
        /// The inputs of paused apps cannot be recorded.
        NotRecording,
        /// Non-core apps were stopped or frozen.
        Remediated,
        /// Paused apps run again.
        RemediationUndone,
        /// A ConfigProfile was saved to the config library.
        ProfileSaved,
        /// A ConfigProfile could not be saved.
        ProfileSaveFailed,
        /// A step of the tuning run failed (it is retried).
        TuningError,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_are_written_as_their_names() {
        for (p, s) in [
            (Phase::Monitoring, "Monitoring"),
            (Phase::Pending, "Pending"),
        ] {
            assert_eq!(serde_json::to_value(&p).unwrap(), s);
            assert_eq!(serde_json::from_value::<Phase>(s.into()).unwrap(), p);
        }
        assert_eq!(Reason::LibraryHit.to_string(), "LibraryHit");
        assert_eq!(
            format!("{:<8}|", Phase::Unsat),
            "Unsat   |",
            "padded in tables"
        );
        assert_eq!(Reason::parse("StackNotFound"), Reason::StackNotFound);
        assert_eq!(StackPhase::default().as_str(), "Pending");
    }

    #[test]
    fn unknown_values_are_kept_as_written() {
        let p: Phase = serde_json::from_value("Relearning".into()).unwrap();
        assert_eq!(p, Phase::Other("Relearning".into()));
        assert_eq!(serde_json::to_value(&p).unwrap(), "Relearning");
        assert_eq!(Reason::parse("Applied").as_str(), "Applied");
    }

    #[test]
    fn the_schema_lists_the_known_values() {
        let s = schemars::schema_for!(StackPhase);
        assert_eq!(s.get("type").unwrap(), "string");
        assert_eq!(
            s.get("enum").unwrap(),
            &serde_json::json!(["Pending", "Accepted", "Invalid"])
        );
    }
}
