//! The project's rule for tests whose prerequisite (a tool, root, a cgroup
//! hierarchy) is missing: no test passes silently. Locally it skips with a
//! printed `SKIPPED: reason`; under CI (`CI=true`) or with
//! `CONFIGBOT_REQUIRE=1` the test fails instead.

/// Whether a missing prerequisite must fail the test: `CI=true` or
/// `CONFIGBOT_REQUIRE=1` in the environment.
pub fn required() -> bool {
    required_by(|k| std::env::var(k).ok())
}

fn required_by(var: impl Fn(&str) -> Option<String>) -> bool {
    var("CI").is_some_and(|v| v == "true") || var("CONFIGBOT_REQUIRE").is_some_and(|v| v == "1")
}

/// Says why a test cannot run on this machine and lets it pass, unless
/// [`required`]: then a missing prerequisite fails the test instead of
/// skipping it silently. The caller returns right after.
#[track_caller]
pub fn skip(why: &str) {
    assert!(
        !required(),
        "cannot run: {why} (CI=true or CONFIGBOT_REQUIRE=1 makes a skip a failure)"
    );
    eprintln!("SKIPPED: {why}");
}

/// `available`, having said why not ([`skip`], a failure when
/// [`required`]) when it is false: `if !require("...", ok) { return; }`.
#[track_caller]
pub fn require(why: &str, available: bool) -> bool {
    if !available {
        skip(why);
    }
    available
}

#[cfg(test)]
mod tests {
    use super::*;

    fn env<'a>(vars: &'a [(&'a str, &'a str)]) -> impl Fn(&str) -> Option<String> + 'a {
        move |k| {
            vars.iter()
                .find(|(n, _)| *n == k)
                .map(|(_, v)| v.to_string())
        }
    }

    #[test]
    fn ci_true_or_configbot_require_1_makes_prerequisites_required() {
        assert!(!required_by(env(&[])));
        assert!(required_by(env(&[("CI", "true")])));
        assert!(required_by(env(&[("CONFIGBOT_REQUIRE", "1")])));
        assert!(!required_by(env(&[
            ("CI", "1"),
            ("CONFIGBOT_REQUIRE", "yes")
        ])));
        assert!(!required_by(env(&[
            ("CI", "false"),
            ("CONFIGBOT_REQUIRE", "0")
        ])));
    }

    #[test]
    fn an_available_prerequisite_is_never_a_skip() {
        assert!(require("present", true));
    }

    /// Whichever way this test runs, a missing prerequisite does what the
    /// rule says: fails when required, else returns false.
    #[test]
    fn a_missing_prerequisite_fails_when_required_and_skips_otherwise() {
        let outcome = std::panic::catch_unwind(|| require("missing tool", false));
        if required() {
            let msg = outcome.unwrap_err();
            let msg = msg
                .downcast_ref::<String>()
                .expect("a formatted panic message");
            assert!(msg.contains("cannot run: missing tool"), "{msg}");
        } else {
            assert!(!outcome.unwrap());
        }
    }
}
