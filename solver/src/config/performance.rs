//! `[performance]`: how the propagation is computed and how a run is split among processes,
//! never what it computes (every setting gives the same bits, except `simd`, which changes the
//! rounding). Rank 0 reads it with the scenario; it reaches every process with its part.

use serde::de::{self, Deserializer, Visitor};
use serde::{Deserialize, Serialize};
use std::fmt;

/// Substeps per fused sweep of the explicit Euler stepper (`Propagation::substeps`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Fuse {
    /// One process: chosen by timing the first sweeps; several: one substep per sweep.
    #[default]
    Auto,
    /// d substeps per sweep (1: none), on any number of processes.
    Fixed(usize),
}

/// The most substeps per fused sweep.
pub const MAX_FUSE: usize = 16;

impl std::str::FromStr for Fuse {
    type Err = String;
    fn from_str(s: &str) -> Result<Fuse, String> {
        if s == "auto" {
            return Ok(Fuse::Auto);
        }
        match s.parse::<i64>() {
            Ok(d) => Fuse::fixed(d),
            Err(_) => Err(format!(
                "`{s}` is not a fusion depth; fix: \"auto\" or a whole number from 1 to {MAX_FUSE}"
            )),
        }
    }
}

impl Fuse {
    fn fixed(d: i64) -> Result<Fuse, String> {
        if (1..=MAX_FUSE as i64).contains(&d) {
            Ok(Fuse::Fixed(d as usize))
        } else {
            Err(format!(
                "{d} substeps per sweep is out of range; fix: \"auto\" or a whole number from 1 to {MAX_FUSE}"
            ))
        }
    }
}

/// `fuse` as written: "auto" or a whole number (the scenario's form; `Fuse` itself travels to
/// other processes in its derived form).
fn fuse_value<'de, D: Deserializer<'de>>(d: D) -> Result<Fuse, D::Error> {
    struct V;
    impl Visitor<'_> for V {
        type Value = Fuse;
        fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
            write!(f, "\"auto\" or a whole number from 1 to {MAX_FUSE}")
        }
        fn visit_i64<E: de::Error>(self, v: i64) -> Result<Fuse, E> {
            Fuse::fixed(v).map_err(E::custom)
        }
        fn visit_u64<E: de::Error>(self, v: u64) -> Result<Fuse, E> {
            Fuse::fixed(v.min(i64::MAX as u64) as i64).map_err(E::custom)
        }
        fn visit_str<E: de::Error>(self, v: &str) -> Result<Fuse, E> {
            v.parse().map_err(E::custom)
        }
    }
    d.deserialize_any(V)
}

/// Who splits the node graph of a run on several processes (one process never splits).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Partitioner {
    /// METIS k-way on rank 0 (the default).
    #[default]
    Metis,
    /// PT-Scotch through its ParMETIS V3 layer, every process on a slab of the graph; METIS
    /// where the build has no PT-Scotch or PT-Scotch fails.
    Ptscotch,
}

/// `[performance]` as written (every key has a default).
#[derive(Deserialize, Debug, Clone, Copy, PartialEq, Eq)]
#[serde(deny_unknown_fields)]
pub struct PerformanceSec {
    /// Substeps per fused sweep: "auto" (the default) or 1 to 16.
    #[serde(default, deserialize_with = "fuse_value")]
    pub fuse: Fuse,
    #[serde(default = "yes")]
    pub simd: bool,
    /// "metis" (the default) or "ptscotch".
    #[serde(default)]
    pub partitioner: Partitioner,
}

impl Default for PerformanceSec {
    fn default() -> Self {
        let Performance {
            fuse,
            simd,
            partitioner,
        } = Performance::default();
        PerformanceSec {
            fuse,
            simd,
            partitioner,
        }
    }
}

impl PerformanceSec {
    pub fn resolve(&self) -> Performance {
        Performance {
            fuse: self.fuse,
            simd: self.simd,
            partitioner: self.partitioner,
        }
    }
}

/// `[performance]`, resolved: how the propagation is computed.
#[derive(Deserialize, Serialize, Debug, Clone, Copy, PartialEq, Eq)]
pub struct Performance {
    /// Substeps per fused sweep.
    pub fuse: Fuse,
    /// The AVX2+FMA kernel of the compact step where the CPU has it (the default); false: the
    /// portable kernel (for comparisons; other rounding).
    pub simd: bool,
    /// Who splits the node graph on several processes.
    pub partitioner: Partitioner,
}

fn yes() -> bool {
    true
}

impl Default for Performance {
    fn default() -> Self {
        Performance {
            fuse: Fuse::Auto,
            simd: true,
            partitioner: Partitioner::Metis,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::Scenario;
    use super::*;

    fn perf(keys: &str) -> Result<Performance, String> {
        let text = format!("[mesh]\nfile = \"m.msh\"\n[time]\nsteps = 1\n[performance]\n{keys}\n");
        let sc = Scenario::parse(std::path::Path::new("p.toml"), text).map_err(|e| format!("{e:#}"))?;
        Ok(sc.file.performance.resolve())
    }

    #[test]
    fn performance_keys_are_checked() {
        assert_eq!(perf("").unwrap(), Performance::default());
        assert_eq!(
            perf("fuse = 4\nsimd = false").unwrap(),
            Performance {
                fuse: Fuse::Fixed(4),
                simd: false,
                partitioner: Partitioner::Metis,
            }
        );
        assert_eq!(
            perf("partitioner = \"ptscotch\"").unwrap().partitioner,
            Partitioner::Ptscotch
        );
        assert_eq!(perf("fuse = \"auto\"").unwrap().fuse, Fuse::Auto);
        for bad in [
            "fuse = 0",
            "fuse = 17",
            "fuse = \"four\"",
            "fuse = 2.5",
            "simd = 1",
            "prefetch = 8",
            "partitioner = \"parmetis\"",
        ] {
            let e = perf(bad).unwrap_err();
            assert!(e.contains("p.toml:6"), "{bad}: {e}");
            assert!(e.contains("performance"), "{bad}: {e}");
        }
        assert!(perf("fuse = 0").unwrap_err().contains("fix:"));
        assert_eq!("8".parse::<Fuse>(), Ok(Fuse::Fixed(8)));
        assert!("-1".parse::<Fuse>().is_err());
    }
}
