//! Timing done the way a benchmark does it: warm-up runs that are thrown away, then repeats until
//! both a minimum count and a minimum time are reached (capped), and the median with the
//! interquartile range as the spread.

use std::time::{Duration, Instant};

use crate::record::Point;

/// How hard to time one point.
#[derive(Debug, Clone, Copy)]
pub struct TimingPlan {
    pub warm_up: usize,
    pub min_repeats: usize,
    pub max_repeats: usize,
    /// Keep repeating (up to `max_repeats`) until this much time was spent measuring.
    pub min_time: Duration,
}

impl TimingPlan {
    pub fn full() -> Self {
        Self {
            warm_up: 3,
            min_repeats: 10,
            max_repeats: 200,
            min_time: Duration::from_millis(500),
        }
    }

    pub fn quick() -> Self {
        Self {
            warm_up: 1,
            min_repeats: 3,
            max_repeats: 5,
            min_time: Duration::ZERO,
        }
    }

    /// For runs that take seconds each (one CPU thread at the largest sizes): fewer repeats.
    pub fn slow(self) -> Self {
        Self {
            warm_up: 1,
            min_repeats: self.min_repeats.min(5),
            max_repeats: self.min_repeats.min(5),
            min_time: Duration::ZERO,
        }
    }
}

/// Times `run` (which must include any device wait and readback), in seconds, and returns the
/// median and interquartile range at `x`. The first error stops the measurement.
pub fn measure<E>(
    plan: TimingPlan,
    x: f64,
    mut run: impl FnMut() -> Result<(), E>,
) -> Result<Point, E> {
    for _ in 0..plan.warm_up {
        run()?;
    }
    let mut times = Vec::with_capacity(plan.min_repeats);
    let started = Instant::now();
    while times.len() < plan.min_repeats
        || (times.len() < plan.max_repeats && started.elapsed() < plan.min_time)
    {
        let t = Instant::now();
        run()?;
        times.push(t.elapsed().as_secs_f64());
    }
    Ok(summarise(x, times))
}

/// Median and interquartile range of `values` (at least one).
pub fn summarise(x: f64, mut values: Vec<f64>) -> Point {
    values.sort_by(f64::total_cmp);
    let q = |f: f64| quantile(&values, f);
    Point {
        x,
        y: q(0.5),
        low: q(0.25),
        high: q(0.75),
        repeats: values.len(),
    }
}

/// Linear interpolation between closest ranks of sorted values.
fn quantile(sorted: &[f64], f: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let pos = f * (sorted.len() - 1) as f64;
    let lo = pos.floor() as usize;
    let hi = pos.ceil() as usize;
    sorted[lo] + (sorted[hi] - sorted[lo]) * (pos - lo as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_and_quartiles() {
        let p = summarise(1.0, vec![5.0, 1.0, 3.0, 2.0, 4.0]);
        assert_eq!((p.y, p.low, p.high, p.repeats), (3.0, 2.0, 4.0, 5));
        let p = summarise(1.0, vec![2.0, 1.0]);
        assert_eq!((p.y, p.low, p.high), (1.5, 1.25, 1.75));
    }

    #[test]
    fn warm_up_runs_are_not_counted_and_errors_stop() {
        let mut calls = 0;
        let plan = TimingPlan::quick();
        let p = measure::<()>(plan, 2.0, || {
            calls += 1;
            Ok(())
        })
        .unwrap();
        assert_eq!(p.repeats, plan.min_repeats);
        assert_eq!(calls, plan.warm_up + plan.min_repeats);
        let mut n = 0;
        let failed = measure(plan, 1.0, || {
            n += 1;
            if n == 2 { Err("device lost") } else { Ok(()) }
        });
        assert_eq!(failed, Err("device lost"));
    }
}
