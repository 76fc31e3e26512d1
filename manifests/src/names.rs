//! Name rules: object names, app and metric names, ROS graph names and label
//! keys. A name that passes here is also safe as a cgroup path part.

/// An object name: DNS-1123 subdomain (lowercase alphanumerics, '-', '.'; ≤ 253).
pub fn check_object_name(name: &str) -> Result<(), String> {
    if name.is_empty() {
        return Err("must not be empty".into());
    }
    if name.len() > 253 {
        return Err(format!("is {} characters, more than 253", name.len()));
    }
    if name.split('.').any(|part| check_dns_label(part).is_err()) {
        return Err(format!(
            "{name:?} is not a valid name (lowercase letters, digits, '-' and '.'; each dot-separated part starts and ends with a letter or digit)"
        ));
    }
    Ok(())
}

/// A DNS-1123 label (lowercase alphanumerics and '-', ≤ 63, alphanumeric at both ends).
pub fn check_dns_label(name: &str) -> Result<(), String> {
    let ok_chars = name
        .bytes()
        .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'-');
    let ok_ends = name
        .bytes()
        .next()
        .is_some_and(|b| b.is_ascii_alphanumeric())
        && name
            .bytes()
            .last()
            .is_some_and(|b| b.is_ascii_alphanumeric());
    if name.is_empty() || name.len() > 63 || !ok_chars || !ok_ends {
        return Err(format!(
            "{name:?} is not a DNS label (1-63 lowercase letters, digits or '-', starting and ending with a letter or digit)"
        ));
    }
    Ok(())
}

/// An absolute ROS graph name such as `/nav/planner`: tokens of a letter followed
/// by letters, digits or '_', separated by single '/'.
pub fn check_ros_name(name: &str) -> Result<(), String> {
    let bad = || {
        format!(
            "{name:?} is not a valid absolute ROS name (like /nav/planner: '/'-separated tokens of a letter then letters, digits or '_')"
        )
    };
    let rest = name.strip_prefix('/').ok_or_else(bad)?;
    if rest.is_empty() || name.len() > 255 {
        return Err(bad());
    }
    for token in rest.split('/') {
        let mut chars = token.chars();
        let first_ok = chars.next().is_some_and(|c| c.is_ascii_alphabetic());
        if !first_ok || !chars.all(|c| c.is_ascii_alphanumeric() || c == '_') {
            return Err(bad());
        }
    }
    Ok(())
}

/// A label key (`[prefix/]name`) or value, Kubernetes rules.
pub fn check_label(key: &str, value: &str) -> Result<(), String> {
    let simple = |s: &str| {
        s.len() <= 63
            && s.bytes()
                .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'-' | b'_' | b'.'))
            && s.bytes().next().is_none_or(|b| b.is_ascii_alphanumeric())
            && s.bytes().last().is_none_or(|b| b.is_ascii_alphanumeric())
    };
    let name = match key.split_once('/') {
        Some((prefix, name)) => {
            check_object_name(prefix).map_err(|e| format!("label key prefix {e}"))?;
            name
        }
        None => key,
    };
    if name.is_empty() || !simple(name) {
        return Err(format!("{key:?} is not a valid label key"));
    }
    if !simple(value) {
        return Err(format!("{value:?} is not a valid label value"));
    }
    Ok(())
}

/// An environment variable name.
pub fn check_env_name(name: &str) -> Result<(), String> {
    let mut chars = name.chars();
    let ok = chars
        .next()
        .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_');
    if ok {
        Ok(())
    } else {
        Err(format!("{name:?} is not a valid environment variable name"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ros_names() {
        for ok in ["/a", "/nav/planner", "/cmd_vel", "/A1_b"] {
            assert!(check_ros_name(ok).is_ok(), "{ok}");
        }
        for bad in [
            "",
            "/",
            "nav",
            "/../x",
            "/a//b",
            "/a/",
            "/1a",
            "/a b",
            "/a\0",
            "/a/../../x",
            "/a.b",
        ] {
            assert!(check_ros_name(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn object_names() {
        for ok in ["basic-nav", "a", "a.b", "x1"] {
            assert!(check_object_name(ok).is_ok(), "{ok}");
        }
        for bad in ["", "../../x", "A", "-a", "a-", "a..b", "a/b", "a_b"] {
            assert!(check_object_name(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn labels() {
        assert!(check_label("robot", "spot").is_ok());
        assert!(check_label("configbot.dev/location", "lab-1").is_ok());
        assert!(check_label("", "x").is_err());
        assert!(check_label("a", "bad value").is_err());
        assert!(check_label("../x/y", "v").is_err());
    }
}
