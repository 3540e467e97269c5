//! How many GPUs a frame's work pays for. Splitting a frame over GPUs divides its work but not
//! the fixed cost each GPU pays per step (one dispatch after another for every stage and
//! annealing layer, a submission and its wait): below some work per GPU the split runs slower
//! than one GPU (four faces over two H200 ran at 0.8× one GPU's rate). Each tracker states its
//! work per frame in its own unit and how much of it one GPU must get for a split to pay.

/// The number of GPUs, of `available`, that `work` (per frame) pays for at `work_per_gpu` each:
/// at least one (when any is available), at most `available`. Work that is not a finite,
/// non-negative number, or a threshold that is not positive, gives one GPU.
pub fn gpus_for_work(work: f64, work_per_gpu: f64, available: usize) -> usize {
    if available == 0 {
        return 0;
    }
    if !(work.is_finite() && work >= 0.0 && work_per_gpu > 0.0 && work_per_gpu.is_finite()) {
        return 1;
    }
    let paid = (work / work_per_gpu).floor();
    if paid >= available as f64 {
        available
    } else {
        (paid as usize).max(1)
    }
}

#[cfg(test)]
mod tests {
    use super::gpus_for_work;

    #[test]
    fn a_gpu_per_share_of_work_within_what_is_there() {
        assert_eq!(gpus_for_work(10.0, 4.0, 0), 0);
        assert_eq!(gpus_for_work(0.0, 4.0, 4), 1);
        assert_eq!(gpus_for_work(3.9, 4.0, 4), 1);
        assert_eq!(gpus_for_work(8.0, 4.0, 4), 2);
        assert_eq!(gpus_for_work(11.9, 4.0, 4), 2);
        assert_eq!(gpus_for_work(1e30, 4.0, 4), 4);
        assert_eq!(gpus_for_work(f64::NAN, 4.0, 4), 1);
        assert_eq!(gpus_for_work(f64::INFINITY, 4.0, 4), 1);
        assert_eq!(gpus_for_work(10.0, 0.0, 4), 1);
        assert_eq!(gpus_for_work(-1.0, 4.0, 4), 1);
        // Never more than there are, never fewer than one.
        for work in [0.5, 3.0, 17.0, 1e6] {
            for available in 1..6 {
                let n = gpus_for_work(work, 2.0, available);
                assert!((1..=available).contains(&n));
                assert!(n == 1 || work / n as f64 >= 2.0);
            }
        }
    }
}
