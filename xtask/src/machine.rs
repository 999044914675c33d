//! What a published figure is stamped with (CPU model, cores, load, date, build profile),
//! and the re-run in the release profile that benchmarks and the full stress grid need.
//!
//! `cargo xtask` is an alias for `cargo run -p xtask`, which builds the dev profile
//! (debug assertions on). Timings from that build would not be the library's, so
//! `bench` and `stress` (except their `--quick` smoke runs) start themselves again
//! with `cargo run --release` and pass on the exit code.

use serde::Serialize;
use std::process::{Command, ExitCode};
use std::time::{SystemTime, UNIX_EPOCH};

/// Set in the environment of the release re-run, so it never re-runs itself.
const RELEASE_RERUN_VAR: &str = "SINEW_XTASK_RELEASE_RERUN";

/// The machine and build a set of figures was measured on.
#[derive(Clone, Debug, Serialize)]
pub struct Machine {
    /// CPU model from `/proc/cpuinfo` ("unknown" where it cannot be read).
    pub cpu: String,
    /// Hardware threads available to this process.
    pub cores: usize,
    /// Operating system and architecture.
    pub os: String,
    /// The 1-minute load average when the run started (`None` where unknown): figures
    /// taken at a load near the core count are noisy.
    pub load_at_start: Option<f64>,
    /// UTC date of the run, `YYYY-MM-DD`.
    pub date: String,
    /// `release` or `dev` (debug assertions on: not for quoting).
    pub profile: &'static str,
}

impl Machine {
    /// Reads the machine now.
    pub fn read() -> Self {
        Self {
            cpu: cpu_model().unwrap_or_else(|| "unknown".into()),
            cores: std::thread::available_parallelism().map_or(1, |n| n.get()),
            os: format!("{} {}", std::env::consts::OS, std::env::consts::ARCH),
            load_at_start: load_average(),
            date: utc_date(SystemTime::now()),
            profile: if cfg!(debug_assertions) {
                "dev"
            } else {
                "release"
            },
        }
    }

    /// One line for reports: `AMD EPYC ..., 2 cores, linux x86_64, release, 2026-11-22, load 0.8`.
    pub fn describe(&self) -> String {
        format!(
            "{}, {} cores, {}, {} build, {}{}",
            self.cpu,
            self.cores,
            self.os,
            self.profile,
            self.date,
            self.load_at_start
                .map_or(String::new(), |l| format!(", load {l:.2} at start"))
        )
    }
}

fn cpu_model() -> Option<String> {
    let info = std::fs::read_to_string("/proc/cpuinfo").ok()?;
    info.lines()
        .find(|l| l.starts_with("model name"))
        .and_then(|l| l.split_once(':'))
        .map(|(_, v)| v.trim().to_string())
}

/// The 1-minute load average now (`None` where it cannot be read).
pub fn load_average() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/loadavg").ok()?;
    text.split_whitespace().next()?.parse().ok()
}

/// `YYYY-MM-DD` (UTC) of a time, by the civil-from-days conversion of the proleptic
/// Gregorian calendar (days counted from 1970-01-01; eras of 400 years = 146 097 days).
pub fn utc_date(time: SystemTime) -> String {
    let secs = time.duration_since(UNIX_EPOCH).map_or(0, |d| d.as_secs());
    let days = (secs / 86_400) as i64;
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1_460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!("{year:04}-{month:02}-{day:02}")
}

/// In a dev build (and not already a re-run), runs this same command again from a
/// release build and returns its exit code; `None` means "go on here" (this is already
/// a release build, or the re-run was turned off with `SINEW_XTASK_NO_RELEASE=1`).
pub fn rerun_in_release() -> Option<ExitCode> {
    if !cfg!(debug_assertions)
        || std::env::var_os(RELEASE_RERUN_VAR).is_some()
        || std::env::var_os("SINEW_XTASK_NO_RELEASE").is_some()
    {
        return None;
    }
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    eprintln!("note: timings need optimised code; building and running xtask in release");
    let status = Command::new(cargo)
        .current_dir(crate::project_root())
        .args(["run", "--release", "--quiet", "--package", "xtask", "--"])
        .args(std::env::args_os().skip(1))
        .env(RELEASE_RERUN_VAR, "1")
        .status();
    Some(match status {
        Ok(s) if s.success() => ExitCode::SUCCESS,
        Ok(s) => ExitCode::from(s.code().map_or(1, |c| c.clamp(1, 255) as u8)),
        Err(e) => {
            eprintln!("error: could not start `cargo run --release`: {e}");
            ExitCode::from(2)
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn utc_dates_match_known_days() {
        let at = |secs: u64| utc_date(UNIX_EPOCH + Duration::from_secs(secs));
        assert_eq!(at(0), "1970-01-01");
        // 2000-02-29 (a leap day in a year divisible by 400) and 2100-03-01 (2100 is
        // not a leap year, so the day before is 02-28).
        assert_eq!(at(951_782_400), "2000-02-29");
        assert_eq!(at(4_107_542_400), "2100-03-01");
        assert_eq!(at(4_107_542_400 - 86_400), "2100-02-28");
        assert_eq!(at(1_795_305_600), "2026-11-22");
    }
}
