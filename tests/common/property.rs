//! How the GPU-vs-CPU property tests draw their cases.
//!
//! Every run draws fresh random cases (no persisted seeds: that is how a rare disagreement is
//! found), `STREAMPF_PROPTEST_CASES=N` runs N cases of each test instead of its default (the
//! long run in docs/FUZZING.md), and a failure prints the failing case in the form the test's
//! check takes, so that it can be pinned as a regression test beside it.

use proptest::strategy::Strategy;
use proptest::test_runner::{Config, TestCaseError, TestError, TestRunner};

/// The variable that sets how many cases every property test draws.
pub const CASES_ENV: &str = "STREAMPF_PROPTEST_CASES";

/// `default` cases, or the number `STREAMPF_PROPTEST_CASES` gives.
pub fn cases(default: u32) -> u32 {
    match std::env::var(CASES_ENV) {
        Ok(text) => text
            .parse()
            .unwrap_or_else(|_| panic!("{CASES_ENV}={text:?} is not a number of cases")),
        Err(_) => default,
    }
}

/// A proptest configuration of `default` cases (see [`cases`]), with nothing persisted.
pub fn config(default: u32) -> Config {
    Config {
        cases: cases(default),
        failure_persistence: None,
        ..Config::default()
    }
}

/// Runs `check` over `strategy`'s cases; a failure panics with the case to pin.
pub fn check_cases<S>(
    name: &str,
    default_cases: u32,
    strategy: S,
    check: impl Fn(S::Value) -> Result<(), TestCaseError>,
) where
    S: Strategy,
    S::Value: std::fmt::Debug,
{
    let mut runner = TestRunner::new(config(default_cases));
    match runner.run(&strategy, check) {
        Ok(()) => {}
        Err(TestError::Fail(why, case)) => {
            panic!("{name} failed: {why}\n  the case (pin it as a regression test): {case:?}")
        }
        Err(TestError::Abort(why)) => panic!("{name} aborted: {why}"),
    }
}

/// Panics with a failed run's case, in the form to pin (`runner.run(..).unwrap_or_else(report)`).
pub fn report<T: std::fmt::Debug>(error: TestError<T>) {
    match error {
        TestError::Fail(why, case) => {
            panic!("failed: {why}\n  the case (pin it as a regression test): {case:?}")
        }
        TestError::Abort(why) => panic!("aborted: {why}"),
    }
}
