//! Values checked while the scenario is parsed, each by its type: numbers in range, points,
//! boxes, spheres, half-spaces, ramps and the choices spelled as strings. A bad value fails
//! the parse at its own line and column (see `Scenario::parse`).

use crate::diagnostics::short;
use serde::{Deserialize, Deserializer, Serialize};

/// Poisson's ratio nu: 0 <= nu < 0.5 (0.5, incompressible, has no finite bulk modulus).
#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(try_from = "f64")]
pub struct Poisson(pub f64);

impl TryFrom<f64> for Poisson {
    type Error = String;
    fn try_from(x: f64) -> Result<Self, String> {
        if (0.0..0.5).contains(&x) {
            Ok(Poisson(x))
        } else {
            Err(format!(
                "{} is not a Poisson's ratio; fix: 0 <= poisson < 0.5 (0.45 for soft tissue, 0.49 nearly incompressible)",
                short(x)
            ))
        }
    }
}

/// The default Poisson's ratio of soft tissue (`[tissue] poisson`).
pub(crate) const POISSON: f64 = 0.45;

pub(crate) fn poisson<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Poisson::deserialize(d).map(|x| x.0)
}

/// `[tissue] poisson`'s default, for serde.
pub(crate) fn poisson_default() -> f64 {
    POISSON
}

/// A finite number > 0.
#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(try_from = "f64")]
pub struct Positive(pub f64);

impl TryFrom<f64> for Positive {
    type Error = String;
    fn try_from(x: f64) -> Result<Self, String> {
        if x > 0.0 && x.is_finite() {
            Ok(Positive(x))
        } else {
            Err(format!("{} must be a positive number", short(x)))
        }
    }
}

/// A finite number >= 0.
#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(try_from = "f64")]
pub struct NonNegative(pub f64);

impl TryFrom<f64> for NonNegative {
    type Error = String;
    fn try_from(x: f64) -> Result<Self, String> {
        if x >= 0.0 && x.is_finite() {
            Ok(NonNegative(x))
        } else {
            Err(format!("{} must be zero or positive", short(x)))
        }
    }
}

/// A finite number.
#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(try_from = "f64")]
pub struct Finite(pub f64);

impl TryFrom<f64> for Finite {
    type Error = String;
    fn try_from(x: f64) -> Result<Self, String> {
        if x.is_finite() {
            Ok(Finite(x))
        } else {
            Err(format!("{} must be a finite number", short(x)))
        }
    }
}

// `deserialize_with` forms of the checked numbers, for plain `f64` fields.
pub fn positive<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Positive::deserialize(d).map(|x| x.0)
}
pub(crate) fn non_negative<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    NonNegative::deserialize(d).map(|x| x.0)
}
pub(crate) fn opt_positive<'de, D: Deserializer<'de>>(d: D) -> Result<Option<f64>, D::Error> {
    positive(d).map(Some)
}
// optional checked numbers of a section that is also sent to other processes (an Option
// on the wire, a present key in TOML)
pub(crate) fn opt_non_negative<'de, D: Deserializer<'de>>(d: D) -> Result<Option<f64>, D::Error> {
    Option::<NonNegative>::deserialize(d).map(|o| o.map(|x| x.0))
}
pub(crate) fn opt_finite<'de, D: Deserializer<'de>>(d: D) -> Result<Option<f64>, D::Error> {
    Option::<Finite>::deserialize(d).map(|o| o.map(|x| x.0))
}

/// A point (or vector) with finite coordinates.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(try_from = "[f64; 3]")]
pub struct Point(pub [f64; 3]);

impl TryFrom<[f64; 3]> for Point {
    type Error = String;
    fn try_from(p: [f64; 3]) -> Result<Self, String> {
        if finite3(&p) {
            Ok(Point(p))
        } else {
            Err("has a non-finite component".into())
        }
    }
}

pub(crate) fn finite3(v: &[f64; 3]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// An axis-aligned box `[[xmin, ymin, zmin], [xmax, ymax, zmax]]`.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(try_from = "[[f64; 3]; 2]")]
pub struct Aabb {
    pub min: [f64; 3],
    pub max: [f64; 3],
}

impl TryFrom<[[f64; 3]; 2]> for Aabb {
    type Error = String;
    fn try_from([min, max]: [[f64; 3]; 2]) -> Result<Self, String> {
        if !finite3(&min) || !finite3(&max) || (0..3).any(|d| min[d] > max[d]) {
            return Err("must be [[xmin, ymin, zmin], [xmax, ymax, zmax]] with min <= max".into());
        }
        Ok(Aabb { min, max })
    }
}

/// A ball `{ center = [x, y, z], radius = R }` (a sphere selector, a contact patch).
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(try_from = "BallKeys")]
pub struct Ball {
    pub center: [f64; 3],
    pub radius: f64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BallKeys {
    center: [f64; 3],
    radius: f64,
}

impl TryFrom<BallKeys> for Ball {
    type Error = String;
    fn try_from(b: BallKeys) -> Result<Self, String> {
        if !(finite3(&b.center) && b.radius > 0.0 && b.radius.is_finite()) {
            return Err("needs a finite center and a positive radius".into());
        }
        Ok(Ball {
            center: b.center,
            radius: b.radius,
        })
    }
}

/// A half-space `{ point = [x, y, z], normal = [nx, ny, nz] }`: the side the normal points to.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(try_from = "HalfSpaceKeys")]
pub struct HalfSpace {
    pub point: [f64; 3],
    pub normal: [f64; 3],
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HalfSpaceKeys {
    point: [f64; 3],
    normal: [f64; 3],
}

impl TryFrom<HalfSpaceKeys> for HalfSpace {
    type Error = String;
    fn try_from(h: HalfSpaceKeys) -> Result<Self, String> {
        let n = eprop_io::geom::norm(h.normal);
        if !(finite3(&h.point) && n > 0.0 && n.is_finite()) {
            return Err("needs a finite point and a non-zero normal".into());
        }
        Ok(HalfSpace {
            point: h.point,
            normal: h.normal,
        })
    }
}

/// A piecewise-linear ramp `[[t0, s0], [t1, s1], ...]`: finite, times strictly increasing.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(try_from = "Vec<[f64; 2]>")]
pub struct Ramp(pub Vec<[f64; 2]>);

impl TryFrom<Vec<[f64; 2]>> for Ramp {
    type Error = String;
    fn try_from(r: Vec<[f64; 2]>) -> Result<Self, String> {
        if r.is_empty()
            || r.windows(2).any(|w| !(w[1][0] > w[0][0]))
            || r.iter().any(|p| !p[0].is_finite() || !p[1].is_finite())
        {
            return Err("must be [[t, scale], ...] with finite values and strictly increasing times".into());
        }
        Ok(Ramp(r))
    }
}

/// Storage precision of floating-point values: the compact operator's coefficients
/// (`[model] operator_precision`) or the output's point arrays (`[output] precision`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    #[default]
    Float64,
    Float32,
}

/// Every key of a section at its default (the section is absent from the file).
pub fn defaults<T: serde::de::DeserializeOwned>() -> T {
    toml::from_str("").expect("every key of an optional section has a default")
}

pub fn one() -> f64 {
    1.0
}

pub(crate) fn yes() -> bool {
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse<T: serde::de::DeserializeOwned>(v: &str) -> Result<T, String> {
        #[derive(Deserialize)]
        struct W<T> {
            v: T,
        }
        toml::from_str::<W<T>>(&format!("v = {v}"))
            .map(|w| w.v)
            .map_err(|e| e.message().to_string())
    }

    #[test]
    fn numbers_are_checked_by_their_type() {
        assert_eq!(parse::<Positive>("2").unwrap().0, 2.0);
        assert_eq!(parse::<Positive>("0.0").unwrap_err(), "0 must be a positive number");
        assert!(parse::<Positive>("nan").unwrap_err().contains("positive"));
        assert!(parse::<Positive>("inf").is_err());
        assert_eq!(parse::<NonNegative>("0.0").unwrap().0, 0.0);
        assert_eq!(parse::<NonNegative>("-1.0").unwrap_err(), "-1 must be zero or positive");
        assert_eq!(parse::<Finite>("-3.5").unwrap().0, -3.5);
        assert_eq!(parse::<Finite>("-inf").unwrap_err(), "-inf must be a finite number");
    }

    #[test]
    fn shapes_are_checked_by_their_type() {
        assert_eq!(parse::<Point>("[1, 2.5, 3]").unwrap(), Point([1.0, 2.5, 3.0]));
        assert!(parse::<Point>("[1, nan, 3]").unwrap_err().contains("non-finite"));
        let b = parse::<Aabb>("[[0, 0, 0], [1, 2, 3]]").unwrap();
        assert_eq!((b.min, b.max), ([0.0; 3], [1.0, 2.0, 3.0]));
        assert!(parse::<Aabb>("[[0, 3, 0], [1, 2, 3]]")
            .unwrap_err()
            .contains("min <= max"));
        assert!(parse::<Ball>("{ center = [0, 0, 0], radius = 1 }").is_ok());
        assert!(parse::<Ball>("{ center = [0, 0, 0], radius = 0 }")
            .unwrap_err()
            .contains("positive radius"));
        assert!(parse::<Ball>("{ center = [0, 0, 0], radius = 1, colour = 2 }")
            .unwrap_err()
            .contains("unknown field `colour`"));
        assert!(parse::<HalfSpace>("{ point = [0, 0, 0], normal = [0, 0, 0] }")
            .unwrap_err()
            .contains("non-zero normal"));
        assert_eq!(
            parse::<Ramp>("[[0, 0], [1, 1]]").unwrap(),
            Ramp(vec![[0.0, 0.0], [1.0, 1.0]])
        );
        for bad in ["[]", "[[1, 0], [1, 1]]", "[[0, 0], [1, inf]]"] {
            assert!(parse::<Ramp>(bad).unwrap_err().contains("increasing"), "{bad}");
        }
    }

    #[test]
    fn precisions_keep_their_spellings() {
        assert_eq!(parse::<Precision>("\"float32\"").unwrap(), Precision::Float32);
        assert_eq!(parse::<Precision>("\"float64\"").unwrap(), Precision::Float64);
        let e = parse::<Precision>("\"half\"").unwrap_err();
        assert!(
            e.contains("`half`") && e.contains("float64") && e.contains("float32"),
            "{e}"
        );
    }
}
