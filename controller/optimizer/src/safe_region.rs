//! Safe exploration's geometric guard (see [`crate::optimizer`]): proposals stay
//! near trials that measured safe, and close enough that the steepest slope seen
//! cannot cross the floor.

/// Safety factor on the steepest slope seen (safe mode).
pub(crate) const SLOPE_FACTOR: f64 = 3.0;

/// Safe mode's second guard besides the models' confidence bounds: a config
/// must lie within `reach` (L∞, unit cube) of a trial that measured safe and,
/// for every constraint, close enough to some such trial that even the
/// steepest slope seen so far (tripled) could not take it below the floor.
#[derive(Debug, Default)]
pub(crate) struct SafeRegion {
    pub active: bool,
    pub reach: f64,
    /// Safe trials (unit cube) with each constraint's margin above its floor.
    pub points: Vec<(Vec<f64>, Vec<f64>)>,
    pub slopes: Vec<f64>,
}

impl SafeRegion {
    /// L∞ radius around safe trial `p` that the slopes and `reach` allow.
    pub fn radius(&self, p: &[f64]) -> f64 {
        let margins = self
            .points
            .iter()
            .find(|(q, _)| q.as_slice() == p)
            .map(|(_, m)| m.as_slice());
        let mut r = self.reach;
        if let Some(m) = margins {
            for (mj, &l) in m.iter().zip(&self.slopes) {
                if l > 0.0 {
                    r = r.min(mj / l);
                }
            }
        }
        r.max(0.0)
    }

    pub fn allows(&self, u: &[f64]) -> bool {
        if !self.active {
            return true;
        }
        let dist = |p: &[f64]| {
            p.iter()
                .zip(u)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max)
        };
        let near = self
            .points
            .iter()
            .any(|(p, _)| dist(p) <= self.reach + 1e-12);
        near && self
            .slopes
            .iter()
            .enumerate()
            .all(|(j, &l)| self.points.iter().any(|(p, m)| m[j] >= l * dist(p)))
    }
}
