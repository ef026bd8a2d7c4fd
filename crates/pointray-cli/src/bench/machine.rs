//! What a benchmark records about the machine: its processor, cores and memory, the date, and
//! how busy other processes kept the processors while it measured (Linux `/proc`; elsewhere
//! unknown).

use std::time::{Instant, SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Machine {
    pub cpu: Option<String>,
    pub cores: usize,
    pub memory_bytes: Option<u64>,
    /// UTC, `YYYY-MM-DD HH:MM`.
    pub date: String,
    pub os: String,
}

impl Machine {
    pub fn describe() -> Self {
        let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
        let cpu = cpuinfo
            .lines()
            .find(|l| l.starts_with("model name"))
            .and_then(|l| l.split_once(':'))
            .map(|(_, name)| name.trim().to_string());
        let meminfo = std::fs::read_to_string("/proc/meminfo").unwrap_or_default();
        let memory_bytes = meminfo
            .lines()
            .find_map(|l| l.strip_prefix("MemTotal:"))
            .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
            .map(|kib| kib * 1024);
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        let now = SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_secs());
        Self { cpu, cores, memory_bytes, date: utc_minutes(now), os: std::env::consts::OS.into() }
    }
}

/// `seconds` since 1970 as `YYYY-MM-DD HH:MM` (UTC), by the proleptic Gregorian calendar.
fn utc_minutes(seconds: u64) -> String {
    let days = (seconds / 86_400) as i64;
    let minute_of_day = seconds % 86_400 / 60;
    // Days to civil date (Hinnant's algorithm), eras of 400 years from 0000-03-01.
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!("{year:04}-{month:02}-{day:02} {:02}:{:02}", minute_of_day / 60, minute_of_day % 60)
}

/// Processor time spent so far, in clock ticks: by everything (busy, not idle), and by this
/// process.
#[derive(Clone, Copy)]
pub struct LoadSample {
    at: Instant,
    busy_ticks: Option<u64>,
    own_ticks: Option<u64>,
}

/// Linux's clock tick for `/proc` (USER_HZ), 100 on every architecture it runs on.
const TICKS_PER_SECOND: f64 = 100.0;

impl LoadSample {
    pub fn now() -> Self {
        let busy_ticks = std::fs::read_to_string("/proc/stat").ok().and_then(|s| {
            // cpu  user nice system idle iowait irq softirq steal guest guest_nice
            let f: Vec<u64> = s.lines().next()?.split_whitespace().skip(1).filter_map(|v| v.parse().ok()).collect();
            (f.len() >= 8).then(|| f[0] + f[1] + f[2] + f[5] + f[6] + f[7])
        });
        let own_ticks = std::fs::read_to_string("/proc/self/stat").ok().and_then(|s| {
            // The command name may hold spaces: fields are counted after its closing parenthesis.
            let rest = &s[s.rfind(')')? + 1..];
            let f: Vec<&str> = rest.split_whitespace().collect();
            Some(f.get(11)?.parse::<u64>().ok()? + f.get(12)?.parse::<u64>().ok()?)
        });
        Self { at: Instant::now(), busy_ticks, own_ticks }
    }

    /// Cores that other processes kept busy on average since `self`.
    pub fn other_cores_since(&self) -> Option<f64> {
        let now = Self::now();
        let seconds = now.at.duration_since(self.at).as_secs_f64();
        let busy = now.busy_ticks?.checked_sub(self.busy_ticks?)?;
        let own = now.own_ticks?.checked_sub(self.own_ticks?)?;
        (seconds > 0.0).then(|| (busy.saturating_sub(own) as f64 / TICKS_PER_SECOND / seconds).max(0.0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dates_are_civil_utc() {
        assert_eq!(utc_minutes(0), "1970-01-01 00:00");
        // 2000-02-29 12:34 (a leap day of a century divisible by 400).
        assert_eq!(utc_minutes(951_827_640), "2000-02-29 12:34");
        assert_eq!(utc_minutes(1_795_000_000), "2026-11-18 11:06");
    }

    #[test]
    fn this_process_busy_is_not_counted_as_other_load() {
        let start = LoadSample::now();
        // Half a second of this thread's work.
        let until = Instant::now() + std::time::Duration::from_millis(500);
        let mut x = 0u64;
        while Instant::now() < until {
            x = std::hint::black_box(x.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1));
        }
        if let Some(other) = start.other_cores_since() {
            // Whatever else runs, our own core is not in it; a 2-core machine can show at most
            // about one other busy core (tick rounding aside).
            let cores = std::thread::available_parallelism().map_or(1, |n| n.get()) as f64;
            assert!((0.0..=cores - 0.5).contains(&other), "other processes: {other} cores");
        }
    }
}
