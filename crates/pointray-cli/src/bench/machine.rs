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
/// process with its children that have ended (the Embree bench it runs).
#[derive(Clone, Copy)]
pub struct LoadSample {
    at: Instant,
    busy_ticks: Option<u64>,
    own_ticks: Option<u64>,
}

/// Linux's clock tick for `/proc` (USER_HZ), 100 on every architecture it runs on.
const TICKS_PER_SECOND: f64 = 100.0;

/// Busy ticks of all processors from `/proc/stat`: user, nice, system, irq, softirq and steal
/// (time the hypervisor gave to another machine is time this one could not use either).
fn busy_ticks(proc_stat: &str) -> Option<u64> {
    // cpu  user nice system idle iowait irq softirq steal guest guest_nice
    let f: Vec<u64> = proc_stat.lines().next()?.split_whitespace().skip(1).filter_map(|v| v.parse().ok()).collect();
    (f.len() >= 8).then(|| f[0] + f[1] + f[2] + f[5] + f[6] + f[7])
}

/// A process's ticks from its `/proc/PID/stat`: user and system time, its own and that of its
/// children it has waited for.
fn process_ticks(pid_stat: &str) -> Option<u64> {
    // The command name may hold spaces and parentheses: fields are counted after the last ')'.
    let f: Vec<&str> = pid_stat[pid_stat.rfind(')')? + 1..].split_whitespace().collect();
    // state ppid pgrp session tty tpgid flags minflt cminflt majflt cmajflt utime stime cutime cstime
    (11..=14).map(|i| f.get(i)?.parse::<u64>().ok()).sum()
}

impl LoadSample {
    pub fn now() -> Self {
        let read = |path: &str| std::fs::read_to_string(path).ok();
        Self {
            at: Instant::now(),
            busy_ticks: read("/proc/stat").as_deref().and_then(busy_ticks),
            own_ticks: read("/proc/self/stat").as_deref().and_then(process_ticks),
        }
    }

    /// Cores that other processes kept busy on average since `self`.
    pub fn other_cores_since(&self) -> Option<f64> {
        let now = Self::now();
        let seconds = now.at.duration_since(self.at).as_secs_f64();
        let busy = now.busy_ticks?.checked_sub(self.busy_ticks?)?;
        let own = now.own_ticks?.checked_sub(self.own_ticks?)?;
        (seconds > 0.0).then(|| busy.saturating_sub(own) as f64 / TICKS_PER_SECOND / seconds)
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
    fn proc_stat_busy_time_leaves_out_idle_and_iowait() {
        let stat = "cpu  100 2 30 5000 40 6 7 8 0 0\ncpu0 50 1 15 2500 20 3 3 4 0 0\n";
        assert_eq!(busy_ticks(stat), Some(100 + 2 + 30 + 6 + 7 + 8));
        assert_eq!(busy_ticks("cpu 1 2\n"), None);
    }

    #[test]
    fn process_time_counts_itself_and_its_waited_children() {
        // A command name with a space and a parenthesis; utime 11, stime 12, cutime 13, cstime 14.
        let stat = "4242 (a (b) c) R 1 4242 4242 0 -1 4194560 300 0 0 0 11 12 13 14 20 0 3 0 100 0";
        assert_eq!(process_ticks(stat), Some(11 + 12 + 13 + 14));
        assert_eq!(process_ticks("4242 (short) R 1"), None);
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn load_is_measured_on_linux() {
        let start = LoadSample::now();
        std::thread::sleep(std::time::Duration::from_millis(20));
        assert!(start.other_cores_since().is_some_and(|cores| cores >= 0.0));
    }
}
