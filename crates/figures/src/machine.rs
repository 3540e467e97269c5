//! Where a run happened: the host, the GPU adapter, the commit and the mode. Every CSV row, plot
//! and report names them.

use pf_gpu::AdapterSummary;

/// The run's provenance.
#[derive(Debug, Clone)]
pub struct Machine {
    /// The CPU model and core count, e.g. "Intel(R) Xeon(R) Platinum 8480+, 16 cores".
    pub host: String,
    /// The adapter the GPU series ran on; `None` when the run had no GPU (quick mode only).
    pub adapter: Option<AdapterSummary>,
    /// The commit the binary was built from (`+changes` when the tree had uncommitted changes).
    pub commit: String,
    /// The run's date (UTC, YYYY-MM-DD).
    pub date: String,
    pub quick: bool,
}

impl Machine {
    pub fn detect(adapter: Option<AdapterSummary>, quick: bool) -> Self {
        Self {
            host: host_description(),
            adapter,
            commit: env!("STREAMPF_FIGURES_COMMIT").to_string(),
            date: today(),
            quick,
        }
    }

    pub fn mode(&self) -> &'static str {
        if self.quick { "quick" } else { "full" }
    }

    pub fn adapter_name(&self) -> String {
        match &self.adapter {
            Some(a) => format!("{} ({}, {})", a.name, a.device_type, a.backend),
            None => "no GPU".to_string(),
        }
    }

    pub fn driver(&self) -> String {
        match &self.adapter {
            Some(a) if a.driver_info.is_empty() => a.driver.clone(),
            Some(a) => format!("{} {}", a.driver, a.driver_info),
            None => String::new(),
        }
    }

    /// The line stamped on every plot and table.
    pub fn stamp(&self) -> String {
        let mode = if self.quick {
            "QUICK MODE (small sizes, not the papers' figures) · "
        } else {
            ""
        };
        format!(
            "{mode}GPU: {} · host: {} · commit {} · {}",
            self.adapter_name(),
            self.host,
            self.commit,
            self.date
        )
    }
}

fn host_description() -> String {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let model = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|text| {
            text.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split_once(':'))
                .map(|(_, v)| v.trim().to_string())
        })
        .unwrap_or_else(|| std::env::consts::ARCH.to_string());
    format!("{model}, {cores} cores")
}

/// Today's date in UTC from the system clock (days since 1970 to a civil date).
fn today() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let (y, m, d) = civil_from_days((secs / 86_400) as i64);
    format!("{y:04}-{m:02}-{d:02}")
}

/// Howard Hinnant's days-to-civil algorithm (proleptic Gregorian calendar).
fn civil_from_days(days: i64) -> (i64, u32, u32) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    let y = yoe + era * 400 + i64::from(m <= 2);
    (y, m, d)
}

#[cfg(test)]
mod tests {
    use super::civil_from_days;

    #[test]
    fn civil_dates() {
        assert_eq!(civil_from_days(0), (1970, 1, 1));
        assert_eq!(civil_from_days(19_782), (2024, 2, 29));
        assert_eq!(civil_from_days(20_415), (2025, 11, 23));
    }
}
