//! `streampf devices`.

use anyhow::Context;

pub fn run() -> anyhow::Result<()> {
    let adapters = pf_gpu::list_adapters().context("listing GPU adapters")?;
    outln!("{} adapter(s):", adapters.len());
    for (i, a) in adapters.iter().enumerate() {
        let driver = match (a.driver.is_empty(), a.driver_info.is_empty()) {
            (true, _) => String::new(),
            (false, true) => format!(", driver {}", a.driver),
            (false, false) => format!(", driver {} ({})", a.driver, a.driver_info),
        };
        outln!(
            "  [{i}] {} — {}, {}{driver}",
            a.name,
            a.device_type,
            a.backend
        );
    }
    if adapters.iter().all(|a| a.is_software()) {
        outln!(
            "only software adapters: fine for tests, far too slow for real-time tracking on a large scale"
        );
    }
    Ok(())
}
