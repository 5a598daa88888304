//! Measurements of a process for the logs, the summary and the benchmarks: resident memory
//! and the median and spread of timings and counts.

/// Logs (at -vv) the resident and peak memory of this process after a setup phase.
pub(crate) fn log_memory(phase: &str) {
    if tracing::enabled!(tracing::Level::DEBUG) {
        let now = status_kb("VmRSS:") * 1024;
        tracing::debug!(
            "memory after {phase}: {:.1} MiB resident, peak {:.1} MiB",
            now as f64 / 1048576.0,
            peak_rss() as f64 / 1048576.0
        );
    }
}

/// Peak resident memory of this process so far, in bytes (Linux; 0 elsewhere).
pub fn peak_rss() -> u64 {
    status_kb("VmHWM:") * 1024
}

/// A `kB` line of /proc/self/status (0 when there is none).
fn status_kb(key: &str) -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with(key))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|v| v.parse::<u64>().ok())
        })
        .unwrap_or(0)
}

/// The median of a list (the upper one of an even count; 0 when empty).
pub fn median(v: &[f64]) -> f64 {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(0.0)
}

/// Min, median (as `median`) and max of a list (zeros when empty).
pub fn spread(v: &[u32]) -> [u32; 3] {
    let mut v = v.to_vec();
    v.sort_unstable();
    match (v.first(), v.last()) {
        (Some(&lo), Some(&hi)) => [lo, v[v.len() / 2], hi],
        _ => [0; 3],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn medians_and_spreads() {
        assert_eq!(median(&[]), 0.0);
        assert_eq!(median(&[3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&[4.0, 1.0, 3.0, 2.0]), 3.0);
        assert_eq!(spread(&[]), [0; 3]);
        assert_eq!(spread(&[5, 1, 9, 2]), [1, 5, 9]);
    }

    #[test]
    fn this_process_has_a_resident_peak() {
        let v = vec![1u8; 1 << 20];
        std::hint::black_box(&v);
        assert!(peak_rss() >= 1 << 20);
        assert!(status_kb("VmRSS:") > 0);
        assert_eq!(status_kb("NoSuchKey:"), 0);
    }
}

/// A number's text without the sign of a zero ("-0.000" reads "0.000").
fn unsigned_zero(s: String) -> String {
    match s.strip_prefix('-') {
        Some(rest) if rest.chars().all(|c| c == '0' || c == '.') => rest.to_string(),
        _ => s,
    }
}

/// A box's corners as `(x, y, z) .. (x, y, z)`, every coordinate with the decimals that give
/// its largest about four significant digits (a mesh in metres from a file in mm reads
/// `(-0.001000, ...)`), in exponent form beyond `fixed`'s range.
pub fn span(lo: [f64; 3], hi: [f64; 3]) -> String {
    let big = lo.iter().chain(&hi).fold(0.0f64, |m, x| m.max(x.abs()));
    let text = |p: [f64; 3]| -> String {
        let one = |x: f64| {
            if big == 0.0 || !(1e-3..1e9).contains(&big) {
                fixed(x, 4)
            } else {
                let digits = (3 - big.log10().floor() as i64).clamp(0, 9) as usize;
                unsigned_zero(format!("{x:.digits$}"))
            }
        };
        format!("({}, {}, {})", one(p[0]), one(p[1]), one(p[2]))
    };
    format!("{} .. {}", text(lo), text(hi))
}

/// `x` with `digits` decimals where that reads well (1e-3 <= |x| < 1e9, and zero), in exponent
/// form otherwise (a time of 1e300 is not 300 digits, 1e-12 is not 0.000000); never `-0`.
pub fn fixed(x: f64, digits: usize) -> String {
    let a = x.abs();
    if a == 0.0 || (1e-3..1e9).contains(&a) {
        unsigned_zero(format!("{x:.digits$}"))
    } else if a.is_finite() {
        format!("{x:.digits$e}")
    } else {
        format!("{x}")
    }
}

/// A number as written in a scenario (the shortest form that reads back the same), in exponent
/// form when it is very large or very small (1e300, not 301 digits); never `-0`. `fixed` is
/// for computed values, `short` for the values a user wrote.
pub fn short(x: f64) -> String {
    if x == 0.0 {
        "0".into()
    } else if x.is_finite() && !(1e-4..1e6).contains(&x.abs()) {
        format!("{x:e}")
    } else {
        format!("{x}")
    }
}

/// `10^lg` in exponent form with two significant digits (an estimate held as its logarithm:
/// 10^600 is "1.0e600", a number no f64 holds).
pub(crate) fn power_of_ten(lg: f64) -> String {
    if !lg.is_finite() {
        return if lg > 0.0 { "inf".into() } else { "0".into() };
    }
    if lg.abs() > 1e15 {
        return format!("10^({lg:.1e})");
    }
    let e = lg.floor();
    let m = 10f64.powf(lg - e);
    let (m, e) = if m >= 9.95 { (1.0, e + 1.0) } else { (m, e) };
    format!("{m:.1}e{}", e as i64)
}

#[cfg(test)]
mod fixed_tests {
    use super::{fixed, power_of_ten, short};

    #[test]
    fn short_is_as_written_in_exponent_form_when_huge_or_tiny() {
        assert_eq!(short(0.05), "0.05");
        assert_eq!(short(100.0), "100");
        assert_eq!(short(-0.0), "0");
        assert_eq!(short(1e300), "1e300");
        assert_eq!(short(-1e-300), "-1e-300");
        assert_eq!(power_of_ten(299.46), "2.9e299");
        assert_eq!(power_of_ten(600.0), "1.0e600");
        assert_eq!(power_of_ten(-0.001), "1.0e0");
        assert_eq!(power_of_ten(-1.4e300), "10^(-1.4e300)");
    }

    #[test]
    fn fixed_where_it_reads_well_exponent_elsewhere_never_minus_zero() {
        assert_eq!(fixed(100.0, 6), "100.000000");
        assert_eq!(fixed(0.0, 3), "0.000");
        assert_eq!(fixed(-0.0, 3), "0.000");
        assert_eq!(fixed(-0.0002, 3), "-2.000e-4");
        assert_eq!(fixed(-0.00201, 2), "0.00");
        assert_eq!(fixed(1e300, 6), "1.000000e300");
        assert_eq!(fixed(-1.5e-12, 4), "-1.5000e-12");
        assert_eq!(fixed(f64::INFINITY, 4), "inf");
    }
}
