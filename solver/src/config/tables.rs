//! Values in time: the CSV tables a scenario names (a load's force history `t, fx, fy, fz`,
//! a tool's path `t, x, y, z`) and the piecewise-linear `History` they become. A live
//! session's samples (`serve`) grow a `History` of the same kind, so a trajectory sent over
//! the socket and the same trajectory in a table give the same values bit for bit.

use anyhow::{anyhow, Result};
use eprop_io::read_input_file;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Samples `[t, a, b, c]` with strictly increasing, finite times and finite values, read as a
/// function of time: linear between samples, constant before the first and after the last.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct History {
    rows: Vec<[f64; 4]>,
}

impl History {
    /// A history with no sample yet (a live input before its first sample).
    pub fn empty() -> History {
        History::default()
    }

    /// Appends a sample; its time must come after the last one and every value be finite.
    pub fn push(&mut self, row: [f64; 4]) -> Result<(), String> {
        if let Some(bad) = row.iter().find(|x| !x.is_finite()) {
            return Err(format!("{} is not a finite number", crate::diagnostics::short(*bad)));
        }
        if let Some(last) = self.rows.last() {
            if !(row[0] > last[0]) {
                return Err(format!(
                    "time {} does not come after the previous time {}",
                    crate::diagnostics::short(row[0]),
                    crate::diagnostics::short(last[0])
                ));
            }
        }
        self.rows.push(row);
        Ok(())
    }

    pub fn rows(&self) -> &[[f64; 4]] {
        &self.rows
    }

    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// Time of the last sample.
    pub fn last_time(&self) -> Option<f64> {
        self.rows.last().map(|r| r[0])
    }

    /// The value at time t (zero when there is no sample). Between two samples it is
    /// `v0 + (t - t0) / (t1 - t0) (v1 - v0)` with t0 the last sample time at or before t, so a
    /// sample's own time gives its values exactly, and the value at t depends only on the two
    /// samples around t (not on samples before or after them).
    pub fn at(&self, t: f64) -> [f64; 3] {
        let r = &self.rows;
        let j = r.partition_point(|row| row[0] <= t);
        if r.is_empty() {
            return [0.0; 3];
        }
        if j == 0 {
            return [r[0][1], r[0][2], r[0][3]];
        }
        if j == r.len() {
            let l = r[j - 1];
            return [l[1], l[2], l[3]];
        }
        let (p, q) = (r[j - 1], r[j]);
        let a = (t - p[0]) / (q[0] - p[0]);
        [
            p[1] + a * (q[1] - p[1]),
            p[2] + a * (q[2] - p[2]),
            p[3] + a * (q[3] - p[3]),
        ]
    }

    /// Drops the samples no value at or after time t needs (all but the last one at or
    /// before t); `at(s)` for s >= t is unchanged.
    pub fn forget_before(&mut self, t: f64) {
        let j = self.rows.partition_point(|row| row[0] <= t);
        if j > 1 {
            self.rows.drain(..j - 1);
        }
    }
}

/// A bound on the magnitude of a table's values (not its times), beyond which what they feed
/// overflows: `why` says what, `fix` what to do.
#[derive(Clone, Copy, Debug)]
pub struct Bound {
    pub limit: f64,
    pub why: &'static str,
    pub fix: &'static str,
}

/// Parses a CSV table of four columns (`columns` names them for messages): one row per line,
/// values separated by commas, an optional header line first, blank lines and lines starting
/// with `#` ignored. Times must increase strictly and every value be finite. Errors name the
/// file (`name`), the line and row, and the fix.
pub fn parse_table(name: &str, bytes: &[u8], role: &str, columns: [&str; 4]) -> Result<History> {
    parse_bounded(name, bytes, role, columns, None)
}

/// `parse_table`, with the values (not the times) within `bound`.
pub(crate) fn parse_bounded(
    name: &str,
    bytes: &[u8],
    role: &str,
    columns: [&str; 4],
    bound: Option<Bound>,
) -> Result<History> {
    let cols = columns.join(", ");
    let text = std::str::from_utf8(bytes).map_err(|e| {
        anyhow!(
            "{name}: the {role} is not UTF-8 text (byte {}); fix: save it as a plain CSV file with columns {cols}",
            e.valid_up_to()
        )
    })?;
    let mut h = History::empty();
    let mut row = 0usize;
    let mut seen_line = false;
    for (k, raw) in text.split('\n').enumerate() {
        let line_no = k + 1;
        let line = raw.trim_end_matches('\r').trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let first = !seen_line;
        seen_line = true;
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        let numbers: Vec<Option<f64>> = fields.iter().map(|f| f.parse::<f64>().ok()).collect();
        let spaced = line.split_whitespace().filter(|w| w.parse::<f64>().is_ok()).count() == 4;
        if first && numbers.iter().all(|x| x.is_none()) && !spaced {
            // a header line: no field is a number
            if fields.len() != 4 {
                return Err(anyhow!(
                    "{name}:{line_no}: the header of the {role} has {} column(s); fix: the columns are {cols}",
                    fields.len()
                ));
            }
            continue;
        }
        row += 1;
        let at = format!("{name}:{line_no}: row {row} of the {role}");
        if fields.len() != 4 {
            let hint = if fields.len() == 1 && line.split_whitespace().count() == 4 {
                " separated by commas"
            } else {
                ""
            };
            return Err(anyhow!(
                "{at}: {} value(s) where 4 are expected; fix: give each row {cols}{hint}",
                fields.len()
            ));
        }
        let mut values = [0.0; 4];
        for (c, (f, x)) in fields.iter().zip(&numbers).enumerate() {
            match x {
                Some(v) if v.is_finite() => match bound {
                    Some(b) if c > 0 && !(v.abs() <= b.limit) => {
                        return Err(anyhow!(
                            "{at}: {} = {} is beyond +-{}, {}; fix: {}",
                            columns[c],
                            crate::diagnostics::short(*v),
                            crate::diagnostics::short(b.limit),
                            b.why,
                            b.fix
                        ))
                    }
                    _ => values[c] = *v,
                },
                Some(v) => {
                    return Err(anyhow!(
                        "{at}: {} = {v} is not finite; fix: give a finite number",
                        columns[c]
                    ))
                }
                None => {
                    return Err(anyhow!(
                        "{at}: {} = `{f}` is not a number; fix: write a decimal number (a header is allowed on the first line only)",
                        columns[c]
                    ))
                }
            }
        }
        if let Some(prev) = h.last_time() {
            if !(values[0] > prev) {
                return Err(anyhow!(
                    "{at}: time {} does not come after the previous row's time {}; fix: times must increase strictly (sort the rows, drop repeated times)",
                    crate::diagnostics::short(values[0]),
                    crate::diagnostics::short(prev)
                ));
            }
        }
        h.rows.push(values);
    }
    if h.is_empty() {
        return Err(anyhow!(
            "{name}: the {role} has no rows; fix: give at least one row of {cols}"
        ));
    }
    Ok(h)
}

/// Reads a table file (a regular file only, `eprop_io::read_input_file`) and parses it.
pub(crate) fn read_table(path: &Path, role: &str, columns: [&str; 4]) -> Result<History> {
    read_bounded(path, role, columns, None)
}

/// `read_table`, with the values (not the times) within `bound`.
pub(crate) fn read_bounded(path: &Path, role: &str, columns: [&str; 4], bound: Option<Bound>) -> Result<History> {
    let bytes = read_input_file(path, "table")?;
    parse_bounded(&path.display().to_string(), &bytes, role, columns, bound)
}

#[cfg(test)]
mod tests {
    use super::*;

    const FORCE: [&str; 4] = ["t", "fx", "fy", "fz"];

    fn table(text: &str) -> Result<History, String> {
        parse_table("f.csv", text.as_bytes(), "force table", FORCE).map_err(|e| e.to_string())
    }

    #[test]
    fn a_history_is_linear_between_samples_and_constant_beyond() {
        let h = table("t, fx, fy, fz\n0, 0, 0, 0\n1, 2, -2, 4\n# a comment\n\n3, 2, 0, 0\n").unwrap();
        assert_eq!(h.rows().len(), 3);
        assert_eq!(h.at(-5.0), [0.0, 0.0, 0.0]);
        assert_eq!(h.at(0.5), [1.0, -1.0, 2.0]);
        assert_eq!(h.at(1.0), [2.0, -2.0, 4.0]);
        assert_eq!(h.at(2.0), [2.0, -1.0, 2.0]);
        assert_eq!(h.at(30.0), [2.0, 0.0, 0.0]);
        assert_eq!(History::empty().at(1.0), [0.0; 3]);
        // the value at a sample's own time is the sample, whatever the neighbours
        let h = table("0.1, 0.3, 0.7, 1e-3\n0.30000000000000004, 0.9, 0.2, 5\n1,0,0,0").unwrap();
        assert_eq!(h.at(0.30000000000000004), [0.9, 0.2, 5.0]);
    }

    #[test]
    fn forgetting_old_samples_keeps_every_later_value() {
        let rows: Vec<[f64; 4]> = (0..50)
            .map(|k| {
                let t = k as f64 * 0.37;
                [t, t.sin(), (3.0 * t).cos(), t * t]
            })
            .collect();
        let mut full = History::empty();
        for r in &rows {
            full.push(*r).unwrap();
        }
        let mut trimmed = full.clone();
        trimmed.forget_before(7.0);
        assert!(trimmed.rows().len() < 33 && trimmed.rows()[0][0] <= 7.0);
        for k in 0..200 {
            let t = 7.0 + k as f64 * 0.0731;
            assert_eq!(trimmed.at(t), full.at(t), "t = {t}");
        }
        // a live history that grows sample by sample agrees with the whole table wherever
        // a sample at or beyond t has arrived
        let mut live = History::empty();
        for r in &rows {
            live.push(*r).unwrap();
            let t = r[0] - 0.2;
            assert_eq!(live.at(t), full.at(t));
        }
    }

    #[test]
    fn samples_must_move_forward_in_time_and_be_finite() {
        let mut h = History::empty();
        h.push([0.0, 1.0, 2.0, 3.0]).unwrap();
        assert!(h
            .push([0.0, 1.0, 2.0, 3.0])
            .unwrap_err()
            .contains("does not come after"));
        assert!(h.push([-1.0, 1.0, 2.0, 3.0]).is_err());
        assert!(h.push([1.0, f64::NAN, 2.0, 3.0]).unwrap_err().contains("finite"));
        assert!(h.push([f64::INFINITY, 0.0, 0.0, 0.0]).is_err());
        h.push([1.0, 0.0, 0.0, 0.0]).unwrap();
        assert_eq!(h.last_time(), Some(1.0));
    }

    #[test]
    fn each_bad_table_is_named_with_its_row_and_fix() {
        for (text, want) in [
            ("", "f.csv: the force table has no rows; fix:"),
            ("t,fx,fy,fz\n# nothing\n", "has no rows"),
            ("0,0,0,0\n1,0,0\n", "f.csv:2: row 2 of the force table: 3 value(s) where 4 are expected; fix:"),
            ("0 0 0 0\n", "f.csv:1: row 1 of the force table: 1 value(s) where 4 are expected; fix: give each row t, fx, fy, fz separated by commas"),
            ("0,0,0,0\n0,1,1,1\n", "f.csv:2: row 2 of the force table: time 0 does not come after the previous row's time 0; fix: times must increase strictly"),
            ("1,0,0,0\n0.5,1,1,1\n", "time 0.5 does not come after"),
            ("0,0,nan,0\n", "f.csv:1: row 1 of the force table: fy = NaN is not finite; fix:"),
            ("0,0,0,inf\n", "fz = inf is not finite"),
            ("t,fx,fy,fz\n0,0,0,0\nt,fx,fy,fz\n", "f.csv:3: row 2 of the force table: t = `t` is not a number; fix: write a decimal number (a header is allowed on the first line only)"),
            ("0,0,0,1e999\n", "not finite"),
            ("0,0,0,0x10\n", "fz = `0x10` is not a number"),
            ("time,force\n0,1,2,3\n", "f.csv:1: the header of the force table has 2 column(s); fix: the columns are t, fx, fy, fz"),
        ] {
            let e = table(text).unwrap_err();
            assert!(e.contains(want), "{text:?}: {e}");
            assert!(e.contains("fix:"), "{text:?}: {e}");
        }
        let e = parse_table("f.csv", b"0,0,0,\xff\n", "force table", FORCE)
            .unwrap_err()
            .to_string();
        assert!(e.contains("not UTF-8") && e.contains("fix:"), "{e}");
        // CRLF line ends and spaces are fine
        assert_eq!(table("t,fx,fy,fz\r\n0, 1 ,2,3\r\n").unwrap().at(0.0), [1.0, 2.0, 3.0]);
    }

    #[test]
    fn only_regular_files_are_read() {
        let d = tempfile::tempdir().unwrap();
        let err = |p: &Path| format!("{:#}", read_table(p, "force table", FORCE).unwrap_err());
        let e = err(d.path());
        assert!(
            e.contains("is a directory, not a regular file") && e.contains("fix:"),
            "{e}"
        );
        let e = err(&d.path().join("none.csv"));
        assert!(e.contains("none.csv: no such table file") && e.contains("fix:"), "{e}");
        assert!(err(Path::new("/dev/null")).contains("character device"));
        // a named pipe would block a plain read (made by a call, not a `mkfifo` child: a
        // fork in this multithreaded test process would inherit other tests' open HDF5 files
        // and hold their locks while it runs)
        let fifo = d.path().join("pipe.csv");
        let c = std::ffi::CString::new(fifo.as_os_str().as_encoded_bytes()).unwrap();
        // SAFETY: a valid NUL-terminated path
        if unsafe { libc::mkfifo(c.as_ptr(), 0o600) } == 0 {
            let e = err(&fifo);
            assert!(e.contains("FIFO") && e.contains("not a regular file"), "{e}");
        }
        let f = d.path().join("ok.csv");
        std::fs::write(&f, "0,1,2,3\n").unwrap();
        assert_eq!(read_table(&f, "force table", FORCE).unwrap().at(9.0), [1.0, 2.0, 3.0]);
    }
}
