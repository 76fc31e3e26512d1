//! The configuration space: knobs with bounds, linear/log scale and optional
//! steps, and the map between real knob units and the unit cube the models see.

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// How a knob's values are spread between its bounds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Scale {
    /// Equal distances in the unit cube are equal differences.
    Linear,
    /// Equal distances in the unit cube are equal ratios (bounds must be > 0).
    Log,
}

/// One tunable value, e.g. a node's CPU quota (cores) or an adaptor's rate (Hz).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Knob {
    pub name: String,
    pub lower: f64,
    pub upper: f64,
    pub scale: Scale,
    /// Values are snapped to `lower + k * step` (integers: `Some(1.0)`).
    pub step: Option<f64>,
}

impl Knob {
    /// A continuous linear knob.
    pub fn linear(name: &str, lower: f64, upper: f64) -> Self {
        Self {
            name: name.to_owned(),
            lower,
            upper,
            scale: Scale::Linear,
            step: None,
        }
    }

    /// A continuous log-scale knob.
    pub fn log(name: &str, lower: f64, upper: f64) -> Self {
        Self {
            name: name.to_owned(),
            lower,
            upper,
            scale: Scale::Log,
            step: None,
        }
    }

    /// The same knob restricted to multiples of `step` above `lower`.
    pub fn with_step(mut self, step: f64) -> Self {
        self.step = Some(step);
        self
    }

    fn validate(&self) -> Result<()> {
        let err = |reason: String| {
            Err(Error::Knob {
                name: self.name.clone(),
                reason,
            })
        };
        if !(self.lower.is_finite() && self.upper.is_finite() && self.lower < self.upper) {
            return err(format!(
                "bounds [{}, {}] must be finite with lower < upper",
                self.lower, self.upper
            ));
        }
        if self.scale == Scale::Log && self.lower <= 0.0 {
            return err(format!("log scale needs lower > 0, got {}", self.lower));
        }
        if let Some(step) = self.step
            && !(step.is_finite() && step > 0.0 && step <= self.upper - self.lower)
        {
            return err(format!("step {step} must be > 0 and at most the range"));
        }
        Ok(())
    }

    /// Real units to `[0, 1]` (clamped).
    pub fn to_unit(&self, v: f64) -> f64 {
        let u = match self.scale {
            Scale::Linear => (v - self.lower) / (self.upper - self.lower),
            Scale::Log => {
                (v.max(f64::MIN_POSITIVE).ln() - self.lower.ln())
                    / (self.upper.ln() - self.lower.ln())
            }
        };
        u.clamp(0.0, 1.0)
    }

    /// `[0, 1]` to real units, snapped to the step grid when there is one.
    pub fn from_unit(&self, u: f64) -> f64 {
        let u = u.clamp(0.0, 1.0);
        let v = match self.scale {
            Scale::Linear => self.lower + u * (self.upper - self.lower),
            Scale::Log => (self.lower.ln() + u * (self.upper.ln() - self.lower.ln())).exp(),
        };
        self.snap(v)
    }

    /// Clamp into bounds and snap to the step grid.
    pub fn snap(&self, v: f64) -> f64 {
        let v = v.clamp(self.lower, self.upper);
        match self.step {
            None => v,
            Some(step) => {
                let max_k = ((self.upper - self.lower) / step + 1e-9).floor();
                let k = ((v - self.lower) / step).round().clamp(0.0, max_k);
                self.lower + k * step
            }
        }
    }
}

/// An ordered set of knobs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Space {
    knobs: Vec<Knob>,
}

impl Space {
    /// Validates bounds, scales, steps and name uniqueness.
    pub fn new(knobs: Vec<Knob>) -> Result<Self> {
        if knobs.is_empty() {
            return Err(Error::Problem("the space has no knobs".into()));
        }
        for (i, k) in knobs.iter().enumerate() {
            k.validate()?;
            if knobs[..i].iter().any(|o| o.name == k.name) {
                return Err(Error::Knob {
                    name: k.name.clone(),
                    reason: "duplicate name".into(),
                });
            }
        }
        Ok(Self { knobs })
    }

    pub fn knobs(&self) -> &[Knob] {
        &self.knobs
    }

    pub fn dim(&self) -> usize {
        self.knobs.len()
    }

    /// Checks a configuration has one finite value per knob.
    pub fn check(&self, x: &[f64]) -> Result<()> {
        if x.len() != self.dim() {
            return Err(Error::Observation(format!(
                "config has {} values, the space has {} knobs",
                x.len(),
                self.dim()
            )));
        }
        if let Some((k, v)) = self.knobs.iter().zip(x).find(|(_, v)| !v.is_finite()) {
            return Err(Error::Observation(format!(
                "knob {:?} has non-finite value {v}",
                k.name
            )));
        }
        Ok(())
    }

    pub fn to_unit(&self, x: &[f64]) -> Vec<f64> {
        self.knobs
            .iter()
            .zip(x)
            .map(|(k, &v)| k.to_unit(v))
            .collect()
    }

    pub fn from_unit(&self, u: &[f64]) -> Vec<f64> {
        self.knobs
            .iter()
            .zip(u)
            .map(|(k, &v)| k.from_unit(v))
            .collect()
    }

    /// The unit-cube point of the config a unit point actually maps to (after snapping).
    pub fn snap_unit(&self, u: &[f64]) -> Vec<f64> {
        self.to_unit(&self.from_unit(u))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unit_round_trip_linear_log_and_steps() {
        let s = Space::new(vec![
            Knob::linear("quota", 0.1, 2.0),
            Knob::log("rate", 1.0, 100.0),
            Knob::linear("threads", 1.0, 8.0).with_step(1.0),
        ])
        .unwrap();
        let x = s.from_unit(&[0.5, 0.5, 0.5]);
        assert!((x[0] - 1.05).abs() < 1e-12);
        assert!(
            (x[1] - 10.0).abs() < 1e-9,
            "log midpoint is the geometric mean"
        );
        assert_eq!(x[2], 5.0); // 1 + 3.5 rounds to 5 (4.5 rounds half away from zero)
        let u = s.to_unit(&x);
        assert!((u[0] - 0.5).abs() < 1e-12 && (u[1] - 0.5).abs() < 1e-12);
        assert_eq!(s.from_unit(&[0.0, 1.0, 1.0]), vec![0.1, 100.0, 8.0]);
    }

    #[test]
    fn invalid_knobs_are_rejected_with_their_name() {
        let e = Space::new(vec![Knob::log("rate", 0.0, 1.0)]).unwrap_err();
        assert!(e.to_string().contains("rate"), "{e}");
        assert!(Space::new(vec![Knob::linear("a", 1.0, 1.0)]).is_err());
        assert!(
            Space::new(vec![
                Knob::linear("a", 0.0, 1.0),
                Knob::linear("a", 0.0, 2.0)
            ])
            .is_err()
        );
        assert!(Space::new(vec![Knob::linear("a", 0.0, 1.0).with_step(0.0)]).is_err());
    }
}
