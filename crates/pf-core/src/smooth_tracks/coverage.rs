//! How often smoothed (or filtered) intervals hold the truth.

use crate::smooth::Summary;

/// How often the truth lay within the smoothed 95 % interval, per value (angles wrapped), and
/// the count of rows compared.
#[derive(Default)]
pub struct Coverage {
    /// Per value, the rows whose interval held the truth.
    pub within: Vec<usize>,
    /// The rows compared.
    pub rows: usize,
}

impl Coverage {
    /// Adds one row against its true values.
    pub fn add(&mut self, values: &[Summary], truth: &[f32], angular: &[bool]) {
        if self.within.len() != values.len() {
            self.within = vec![0; values.len()];
        }
        for (d, (s, &t)) in values.iter().zip(truth).enumerate() {
            let offset = |x: f32| {
                let e = t - x;
                if angular.get(d).copied().unwrap_or(false) {
                    crate::batch::wrap_angle_floor(e)
                } else {
                    e
                }
            };
            // The truth from the mean, within the interval's reach on each side.
            let from_mean = offset(s.mean);
            if from_mean >= s.lower - s.mean && from_mean <= s.upper - s.mean {
                self.within[d] += 1;
            }
        }
        self.rows += 1;
    }

    /// Each value's share within its interval, in percent.
    pub fn percent(&self) -> Vec<f64> {
        (self.within.iter())
            .map(|&w| 100.0 * w as f64 / self.rows.max(1) as f64)
            .collect()
    }
}
