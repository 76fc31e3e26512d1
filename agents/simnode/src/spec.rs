//! Parsing of the command-line specs (pure): periodic publishers
//! `TOPIC:HZ:BYTES` and callbacks `IN->OUT:cost-ms=C[,bytes=B]`, plus ROS
//! name resolution (relative names resolve in the root namespace).

use std::str::FromStr;

/// Errors of parsing a spec or a name.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SpecError {
    #[error("bad publisher spec {0:?}: want TOPIC:HZ:BYTES, e.g. /scan:40:4096")]
    PublishShape(String),
    #[error(
        "bad callback spec {0:?}: want IN->OUT:cost-ms=C[,bytes=B], e.g. /scan->/cmd_vel:cost-ms=9"
    )]
    CallbackShape(String),
    #[error("bad number {value:?} for {what} in {spec:?}")]
    Number {
        spec: String,
        what: &'static str,
        value: String,
    },
    #[error("unknown callback option {option:?} in {spec:?} (known: cost-ms, bytes)")]
    Option { spec: String, option: String },
    #[error("bad ROS name {0:?}: use letters, digits, '_' and '/'")]
    Name(String),
}

/// Smallest data array a simnode sends: the 16-byte seq + stamp header.
pub const MIN_BYTES: usize = 16;

/// A periodic publisher: `--publish TOPIC:HZ:BYTES`.
#[derive(Debug, Clone, PartialEq)]
pub struct PublishSpec {
    pub topic: String,
    pub hz: f64,
    /// Size of the message's data array (at least [`MIN_BYTES`]).
    pub bytes: usize,
}

/// A callback: `--on IN->OUT:cost-ms=C[,bytes=B]`.
#[derive(Debug, Clone, PartialEq)]
pub struct CallbackSpec {
    pub input: String,
    pub output: String,
    /// CPU milliseconds of work per incoming message.
    pub cost_ms: f64,
    /// Data size of the output; `None` = the input message's data size.
    pub bytes: Option<usize>,
}

/// Resolves a ROS graph name in the root namespace: `scan` → `/scan`.
pub fn resolve(name: &str) -> Result<String, SpecError> {
    let n = name.trim();
    let ok = !n.is_empty()
        && n != "/"
        && n.chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '/')
        && !n.contains("//")
        && !n.ends_with('/');
    if !ok {
        return Err(SpecError::Name(name.to_string()));
    }
    Ok(if n.starts_with('/') {
        n.to_string()
    } else {
        format!("/{n}")
    })
}

fn number<T: FromStr>(spec: &str, what: &'static str, value: &str) -> Result<T, SpecError> {
    value.trim().parse().map_err(|_| SpecError::Number {
        spec: spec.into(),
        what,
        value: value.into(),
    })
}

impl FromStr for PublishSpec {
    type Err = SpecError;
    fn from_str(s: &str) -> Result<Self, SpecError> {
        let mut parts = s.rsplitn(3, ':');
        let (Some(bytes), Some(hz), Some(topic)) = (parts.next(), parts.next(), parts.next())
        else {
            return Err(SpecError::PublishShape(s.into()));
        };
        let hz: f64 = number(s, "HZ", hz)?;
        if !(hz.is_finite() && hz > 0.0) {
            return Err(SpecError::Number {
                spec: s.into(),
                what: "HZ (must be > 0)",
                value: hz.to_string(),
            });
        }
        let bytes: usize = number(s, "BYTES", bytes)?;
        Ok(PublishSpec {
            topic: resolve(topic)?,
            hz,
            bytes: bytes.max(MIN_BYTES),
        })
    }
}

impl FromStr for CallbackSpec {
    type Err = SpecError;
    fn from_str(s: &str) -> Result<Self, SpecError> {
        let (edge, opts) = s.split_once(':').unwrap_or((s, ""));
        let (input, output) = edge
            .split_once("->")
            .ok_or_else(|| SpecError::CallbackShape(s.into()))?;
        let mut spec = CallbackSpec {
            input: resolve(input)?,
            output: resolve(output)?,
            cost_ms: 0.0,
            bytes: None,
        };
        for opt in opts.split(',').map(str::trim).filter(|o| !o.is_empty()) {
            let (k, v) = opt.split_once('=').ok_or_else(|| SpecError::Option {
                spec: s.into(),
                option: opt.into(),
            })?;
            match k.trim() {
                "cost-ms" => {
                    let c: f64 = number(s, "cost-ms", v)?;
                    if !(c.is_finite() && c >= 0.0) {
                        return Err(SpecError::Number {
                            spec: s.into(),
                            what: "cost-ms (must be >= 0)",
                            value: v.into(),
                        });
                    }
                    spec.cost_ms = c;
                }
                "bytes" => spec.bytes = Some(number::<usize>(s, "bytes", v)?.max(MIN_BYTES)),
                other => {
                    return Err(SpecError::Option {
                        spec: s.into(),
                        option: other.into(),
                    });
                }
            }
        }
        Ok(spec)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_publishers() {
        let p: PublishSpec = "/scan:40:4096".parse().unwrap();
        assert_eq!(
            p,
            PublishSpec {
                topic: "/scan".into(),
                hz: 40.0,
                bytes: 4096
            }
        );
        let p: PublishSpec = "image:2.5:4".parse().unwrap();
        assert_eq!(
            (p.topic.as_str(), p.hz, p.bytes),
            ("/image", 2.5, MIN_BYTES)
        );
        for bad in [
            "/scan:40",
            "/scan:0:10",
            "/scan:x:10",
            "/scan:4:-1",
            ":4:10",
            "a b:1:1",
        ] {
            assert!(bad.parse::<PublishSpec>().is_err(), "{bad}");
        }
    }

    #[test]
    fn parses_callbacks() {
        let c: CallbackSpec = "/scan->/cmd_vel:cost-ms=9".parse().unwrap();
        assert_eq!(
            c,
            CallbackSpec {
                input: "/scan".into(),
                output: "/cmd_vel".into(),
                cost_ms: 9.0,
                bytes: None
            }
        );
        let c: CallbackSpec = "image->/det:cost-ms=1.5, bytes=64".parse().unwrap();
        assert_eq!(
            (c.input.as_str(), c.cost_ms, c.bytes),
            ("/image", 1.5, Some(64))
        );
        let c: CallbackSpec = "/a->/b".parse().unwrap();
        assert_eq!(c.cost_ms, 0.0);
        let e = "/a->/b:cost=3".parse::<CallbackSpec>().unwrap_err();
        assert!(e.to_string().contains("cost"), "{e}");
        for bad in [
            "/a/b:cost-ms=1",
            "/a->:cost-ms=1",
            "/a->/b:cost-ms=-1",
            "/a->/b:cost-ms",
        ] {
            assert!(bad.parse::<CallbackSpec>().is_err(), "{bad}");
        }
    }

    #[test]
    fn resolves_names() {
        assert_eq!(resolve("lidar").unwrap(), "/lidar");
        assert_eq!(resolve("/ns/x").unwrap(), "/ns/x");
        for bad in ["", "/", "a//b", "a/", "a-b"] {
            assert!(resolve(bad).is_err(), "{bad}");
        }
    }
}
