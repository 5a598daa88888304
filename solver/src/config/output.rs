//! `[output]`: where the series goes, how often, which point arrays and how they are stored.

use super::values::Precision;
use super::Scenario;
use serde::de::Error;
use serde::{Deserialize, Deserializer, Serialize};
use std::path::PathBuf;

/// A point array eprop can write.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Field {
    Displacement,
    Velocity,
    Potential,
    Energy,
}

impl Field {
    /// Every field, in the order the series stores them.
    pub const ALL: [Field; 4] = [Field::Displacement, Field::Velocity, Field::Potential, Field::Energy];

    pub fn name(self) -> &'static str {
        match self {
            Field::Displacement => "displacement",
            Field::Velocity => "velocity",
            Field::Potential => "potential",
            Field::Energy => "energy",
        }
    }

    /// Values per node.
    pub fn components(self) -> usize {
        match self {
            Field::Energy => 1,
            _ => 3,
        }
    }
}

#[derive(Deserialize, Debug, Clone)]
#[serde(deny_unknown_fields)]
pub struct OutputSec {
    pub file: Option<String>,
    /// Every how many steps a step is written (absent: 1, or in `eprop serve`'s real-time
    /// mode about `REALTIME_RATE` a second of simulated time, `Output::every_for_realtime`).
    #[serde(default, deserialize_with = "at_least_one")]
    pub every: Option<u64>,
    /// Point arrays written every output step.
    #[serde(default = "all_fields", deserialize_with = "fields")]
    pub fields: Vec<Field>,
    /// float64 is needed for an exact restart.
    #[serde(default)]
    pub precision: Precision,
    /// gzip (deflate) level of the point arrays, 0 (off) to 9.
    #[serde(default, deserialize_with = "gzip_level")]
    pub compression: u8,
    /// Replace an existing series in `file` (as `--overwrite`).
    #[serde(default)]
    pub overwrite: bool,
    /// Seconds of wall time between flushes that complete the written steps in the file
    /// (0: every output step).
    #[serde(default = "one_second", deserialize_with = "seconds")]
    pub flush: f64,
}

fn one_second() -> f64 {
    1.0
}

fn seconds<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    match f64::deserialize(d)? {
        s if s.is_finite() && s >= 0.0 => Ok(s),
        _ => Err(D::Error::custom(
            "must be a number of seconds, 0 or more; fix: 0 completes every output step in the file, the default 1 at most once a second",
        )),
    }
}

fn all_fields() -> Vec<Field> {
    Field::ALL.to_vec()
}

fn at_least_one<'de, D: Deserializer<'de>>(d: D) -> Result<Option<u64>, D::Error> {
    match u64::deserialize(d)? {
        0 => Err(D::Error::custom("must be at least 1")),
        n => Ok(Some(n)),
    }
}

/// Output steps per second of simulated time that `eprop serve`'s real-time mode writes when
/// the scenario names no `[output] every` (the physics thread writes the series itself).
pub(crate) const REALTIME_RATE: f64 = 30.0;

fn gzip_level<'de, D: Deserializer<'de>>(d: D) -> Result<u8, D::Error> {
    match u8::deserialize(d) {
        Ok(l) if l <= 9 => Ok(l),
        _ => Err(D::Error::custom("must be a gzip level from 0 (off) to 9")),
    }
}

/// A list of distinct field names.
fn fields<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<Field>, D::Error> {
    let names: Vec<String> = Vec::deserialize(d)?;
    let all: Vec<&str> = Field::ALL.iter().map(|f| f.name()).collect();
    if names.is_empty() {
        return Err(D::Error::custom(format!("is empty; fix: list some of {all:?}")));
    }
    let mut out = Vec::with_capacity(names.len());
    for name in &names {
        let Some(f) = Field::ALL.into_iter().find(|f| f.name() == name) else {
            return Err(D::Error::custom(format!(
                "`{name}` is not a field; fix: choose from {all:?}"
            )));
        };
        if out.contains(&f) {
            return Err(D::Error::custom(format!("`{name}` is listed twice")));
        }
        out.push(f);
    }
    Ok(out)
}

/// `[output]` resolved.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Output {
    #[serde(with = "crate::config::wire::path")]
    pub file: PathBuf,
    pub every: u64,
    /// Whether the scenario named `every`.
    pub every_given: bool,
    pub fields: Vec<Field>,
    pub precision: Precision,
    pub compression: u8,
    /// An existing series in `file` may be replaced.
    pub overwrite: bool,
    /// Seconds between the flushes that make written steps complete in the file.
    pub flush: f64,
}

impl Output {
    /// In the real-time mode of `eprop serve` with a step dt: every how many steps to write
    /// when the scenario names no `every` (about `REALTIME_RATE` output steps a second).
    pub fn every_for_realtime(&mut self, dt: f64) {
        if !self.every_given && dt > 0.0 {
            self.every = (1.0 / (REALTIME_RATE * dt)).round().clamp(1.0, 1e9) as u64;
        }
    }

    /// The fields to write, in the series' order.
    pub fn fields(&self) -> Vec<Field> {
        Field::ALL.into_iter().filter(|f| self.fields.contains(f)).collect()
    }
}

/// The output file: the scenario's, relative to the scenario file, or `<stem>.h5` beside it.
pub fn file_of(sc: &Scenario) -> PathBuf {
    let base = sc.path.parent().unwrap_or(std::path::Path::new("."));
    match &sc.file.output.file {
        Some(f) => base.join(f),
        None => base.join(format!(
            "{}.h5",
            sc.path.file_stem().and_then(|s| s.to_str()).unwrap_or("out")
        )),
    }
}

/// `[output]` resolved.
pub fn resolve(sc: &Scenario) -> Output {
    let o = &sc.file.output;
    Output {
        file: file_of(sc),
        every: o.every.unwrap_or(1),
        every_given: o.every.is_some(),
        fields: o.fields.clone(),
        precision: o.precision,
        compression: o.compression,
        overwrite: o.overwrite,
        flush: o.flush,
    }
}

#[cfg(test)]
mod tests {
    use super::super::Scenario;
    use super::*;

    fn output(keys: &str) -> Result<Output, String> {
        let text = format!("[mesh]\nfile = \"m.msh\"\n[time]\nsteps = 1\n[output]\n{keys}\n");
        let sc = Scenario::parse(std::path::Path::new("dir/run.toml"), text).map_err(|e| e.to_string())?;
        Ok(resolve(&sc))
    }

    #[test]
    fn defaults_and_choices() {
        let o = output("").unwrap();
        assert_eq!(o.file, PathBuf::from("dir/run.h5"));
        assert_eq!((o.every, o.precision, o.compression), (1, Precision::Float64, 0));
        assert_eq!(o.fields, Field::ALL);
        assert_eq!(o.flush, 1.0);
        assert_eq!(output("flush = 0").unwrap().flush, 0.0);
        let o = output("file = \"x/y.h5\"\nfields = [\"energy\", \"displacement\"]\nprecision = \"float32\"").unwrap();
        assert_eq!(o.file, PathBuf::from("dir/x/y.h5"));
        assert_eq!(o.fields(), [Field::Displacement, Field::Energy]);
        assert_eq!(o.precision, Precision::Float32);
    }

    #[test]
    fn each_bad_key_is_named_at_its_line() {
        for (keys, want) in [
            ("every = 0", "[output] every: must be at least 1"),
            ("fields = []", "[output] fields: is empty; fix: list some of"),
            (
                "fields = [\"strain\"]",
                "`strain` is not a field; fix: choose from [\"displacement\"",
            ),
            ("fields = [\"energy\", \"energy\"]", "`energy` is listed twice"),
            (
                "precision = \"float16\"",
                "[output] precision: `float16` is not one of the accepted values; fix: use \"float64\" or \"float32\"",
            ),
            ("compression = 12", "[output] compression: must be a gzip level"),
            ("flush = -1", "[output] flush: must be a number of seconds"),
        ] {
            let e = output(keys).unwrap_err();
            assert!(e.starts_with("dir/run.toml:6:"), "{keys}: {e}");
            assert!(e.contains(want) && e.contains("fix:"), "{keys}: {e}");
        }
    }
}
