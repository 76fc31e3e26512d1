//! The registry of kinds: names, plurals and short names used by the API paths,
//! the CLI and the schemas.

/// A ConfigBot resource kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Kind {
    RobotStack,
    PerformanceSpec,
    ConfigProfile,
}

impl Kind {
    /// Every kind, in apply order (stacks before the specs that name them).
    pub const ALL: [Kind; 3] = [Kind::RobotStack, Kind::PerformanceSpec, Kind::ConfigProfile];

    /// The `kind` field value.
    pub fn name(self) -> &'static str {
        match self {
            Kind::RobotStack => "RobotStack",
            Kind::PerformanceSpec => "PerformanceSpec",
            Kind::ConfigProfile => "ConfigProfile",
        }
    }

    /// The plural used in API paths (`robotstacks`).
    pub fn plural(self) -> &'static str {
        match self {
            Kind::RobotStack => "robotstacks",
            Kind::PerformanceSpec => "performancespecs",
            Kind::ConfigProfile => "configprofiles",
        }
    }

    pub fn singular(self) -> &'static str {
        match self {
            Kind::RobotStack => "robotstack",
            Kind::PerformanceSpec => "performancespec",
            Kind::ConfigProfile => "configprofile",
        }
    }

    pub fn short_names(self) -> &'static [&'static str] {
        match self {
            Kind::RobotStack => &["rs"],
            Kind::PerformanceSpec => &["pspec", "ps"],
            Kind::ConfigProfile => &["cprof"],
        }
    }

    /// Columns of `get` tables (kubectl and `configbot get`): (name, type, JSON path, wide only).
    pub fn printer_columns(self) -> &'static [PrinterColumn] {
        const STACK: &[PrinterColumn] = &[
            PrinterColumn::new("Phase", "string", ".status.phase", false),
            PrinterColumn::new("Apps", "integer", ".status.apps", false),
            PrinterColumn::new("Nodes", "integer", ".status.nodes", false),
            PrinterColumn::new("Model", "string", ".spec.robot.model", true),
        ];
        const SPEC: &[PrinterColumn] = &[
            PrinterColumn::new("Stack", "string", ".spec.stackRef.name", false),
            PrinterColumn::new("Phase", "string", ".status.phase", false),
            PrinterColumn::new("Satisfaction", "number", ".status.satisfaction", false),
            PrinterColumn::new("Trials", "integer", ".status.trials", true),
        ];
        const PROFILE: &[PrinterColumn] = &[
            PrinterColumn::new("Model", "string", ".spec.context.robotModel", false),
            PrinterColumn::new("Spec", "string", ".spec.specName", false),
            PrinterColumn::new("Satisfaction", "number", ".spec.satisfaction", false),
            PrinterColumn::new("Objective", "number", ".spec.objective", true),
        ];
        match self {
            Kind::RobotStack => STACK,
            Kind::PerformanceSpec => SPEC,
            Kind::ConfigProfile => PROFILE,
        }
    }

    /// Find a kind by its name, plural, singular or short name, any case.
    pub fn lookup(word: &str) -> Option<Kind> {
        let w = word.to_ascii_lowercase();
        Kind::ALL.into_iter().find(|k| {
            k.name().eq_ignore_ascii_case(&w)
                || k.plural() == w
                || k.singular() == w
                || k.short_names().contains(&w.as_str())
        })
    }

    /// Find a kind by its plural (API path segment).
    pub fn from_plural(plural: &str) -> Option<Kind> {
        Kind::ALL.into_iter().find(|k| k.plural() == plural)
    }

    /// Find a kind by its exact `kind` field.
    pub fn from_name(name: &str) -> Option<Kind> {
        Kind::ALL.into_iter().find(|k| k.name() == name)
    }
}

/// One column of a kind's table view.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PrinterColumn {
    pub name: &'static str,
    /// OpenAPI type: `string`, `integer`, `number`.
    pub type_: &'static str,
    /// Simple JSON path, e.g. `.status.phase`.
    pub json_path: &'static str,
    /// Shown only with `-o wide`.
    pub wide: bool,
}

impl PrinterColumn {
    const fn new(
        name: &'static str,
        type_: &'static str,
        json_path: &'static str,
        wide: bool,
    ) -> Self {
        PrinterColumn {
            name,
            type_,
            json_path,
            wide,
        }
    }

    /// The column's value in `obj`, if present.
    pub fn value<'a>(&self, obj: &'a serde_json::Value) -> Option<&'a serde_json::Value> {
        self.json_path
            .trim_start_matches('.')
            .split('.')
            .try_fold(obj, |v, key| v.get(key))
            .filter(|v| !v.is_null())
    }
}

impl std::fmt::Display for Kind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lookup_accepts_every_spelling() {
        for w in [
            "rs",
            "RobotStack",
            "robotstacks",
            "robotstack",
            "ROBOTSTACK",
        ] {
            assert_eq!(Kind::lookup(w), Some(Kind::RobotStack), "{w}");
        }
        for w in ["pspec", "performancespecs", "PerformanceSpec"] {
            assert_eq!(Kind::lookup(w), Some(Kind::PerformanceSpec), "{w}");
        }
        for w in ["cprof", "configprofiles", "ConfigProfile"] {
            assert_eq!(Kind::lookup(w), Some(Kind::ConfigProfile), "{w}");
        }
        assert_eq!(Kind::lookup("pods"), None);
    }
}
