//! `[[tool]]`: a rigid indenter that follows a prescribed path (docs/tools.md). Its shape
//! (`sphere` with `radius`, or `punch`, a flat circular punch with `radius` and `normal`) and
//! its path (`start` and `velocity`, or a CSV `table` of `t, x, y, z`) are checked while
//! parsing; the table is read when the scenario is resolved.

use super::values::{opt_positive, positive, Point};
use super::Scenario;
use crate::config::tables::{read_bounded, Bound, History};
use anyhow::Result;
use eprop_io::geom::{norm, scale};
use serde::{Deserialize, Serialize};
use toml::Spanned;

/// The columns of a tool's path table.
pub const PATH_COLUMNS: [&str; 4] = ["t", "x", "y", "z"];

/// How a tool acts on the tissue (docs/tools.md).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ContactLaw {
    /// The tissue the tool touches is where the tool puts it; the potential there is the
    /// value that holds it (a Dirichlet condition), the force the model's reaction.
    #[default]
    Kinematic,
    /// An elastic foundation under the rest surface (the first tools' law): the pressure of
    /// the tool's overlap with the rest surface is the source and the force.
    Foundation,
}

/// How held tissue moves along a tool's face (kinematic law).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Grip {
    /// Frictionless: the tissue is pushed onto the surface along its normal and may slide.
    Slide,
    /// Sticky: the tissue on the face moves with the tool until the tool moves away from it.
    Stick,
}

/// The largest magnitude of a tool's coordinates, radius and velocity: the contact measures
/// distances as roots of sums of squares, which overflow beyond about 1e154, and a path
/// between two samples near f64's limit passes through infinity. 1e100 leaves room for both,
/// far outside any mesh (`mesh::EXTENT`).
pub const REACH: f64 = 1e100;

/// What a tool's coordinate beyond `REACH` is told.
pub const REACH_WHY: &str = "where the contact's distances overflow";
/// Its fix.
pub const REACH_FIX: &str = "give the tool's positions in the mesh's units, near the organ";

/// A tool's shape as the scenario spells it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ShapeName {
    Sphere,
    Punch,
}

/// A `[[tool]]` table as written.
#[derive(Deserialize, Debug, Clone)]
#[serde(deny_unknown_fields)]
pub struct ToolSec {
    pub shape: ShapeName,
    #[serde(deserialize_with = "positive")]
    pub radius: f64,
    /// The depth of the elastic foundation the contact pressure is measured against (a
    /// length; default: the radius).
    #[serde(default, deserialize_with = "opt_positive")]
    pub foundation: Option<f64>,
    /// The punch's pressing direction (from its face into the organ).
    pub normal: Option<Point>,
    pub start: Option<Point>,
    pub velocity: Option<Point>,
    pub table: Option<Spanned<String>>,
    /// Driven by the client of `eprop serve`.
    #[serde(default)]
    pub live: bool,
    /// The contact law (default: kinematic).
    #[serde(default)]
    pub law: ContactLaw,
    /// Slide or stick (kinematic law; default: a sphere slides, a punch sticks).
    pub contact: Option<Grip>,
}

/// The solid a tool is.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum Shape {
    /// A ball of this radius around the tool position.
    Sphere { radius: f64 },
    /// A flat circular punch: its face is the disc of this radius centred on the tool
    /// position, perpendicular to the unit `normal`, along which it presses; the solid is the
    /// half-infinite cylinder behind the face.
    Punch { radius: f64, normal: [f64; 3] },
}

impl Shape {
    pub fn radius(&self) -> f64 {
        match *self {
            Shape::Sphere { radius } | Shape::Punch { radius, .. } => radius,
        }
    }

    pub fn name(&self) -> &'static str {
        match self {
            Shape::Sphere { .. } => "sphere",
            Shape::Punch { .. } => "punch",
        }
    }
}

/// Where a tool is in time.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Trajectory {
    /// start + t velocity
    Linear { start: [f64; 3], velocity: [f64; 3] },
    /// Positions in time, linear between samples, held beyond the ends.
    Table(History),
}

impl Trajectory {
    pub fn at(&self, t: f64) -> [f64; 3] {
        match self {
            Trajectory::Linear { start, velocity } => [
                start[0] + t * velocity[0],
                start[1] + t * velocity[1],
                start[2] + t * velocity[2],
            ],
            Trajectory::Table(h) => h.at(t),
        }
    }
}

fn slide() -> Grip {
    Grip::Slide
}

/// A resolved tool.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Tool {
    pub shape: Shape,
    pub path: Trajectory,
    pub live: bool,
    #[serde(default)]
    pub law: ContactLaw,
    #[serde(default = "slide")]
    pub grip: Grip,
    /// The foundation depth h: a rest overlap delta gives the contact strain delta / h.
    pub foundation: f64,
}

/// `x`'s components within `REACH`, or the message about `key`.
fn within_reach(key: &str, x: Option<Point>) -> Result<(), String> {
    match x.and_then(|p| p.0.into_iter().find(|v| !(v.abs() <= REACH))) {
        Some(v) => Err(format!(
            "`{key}` has the component {}, beyond +-{}, {REACH_WHY}; fix: {REACH_FIX}",
            crate::diagnostics::short(v),
            crate::diagnostics::short(REACH)
        )),
        None => Ok(()),
    }
}

/// The combinations of keys a tool takes.
fn shape_and_path(t: &ToolSec) -> Result<(Shape, Option<Trajectory>), String> {
    within_reach("start", t.start)?;
    within_reach("velocity", t.velocity)?;
    for (key, v) in [("radius", Some(t.radius)), ("foundation", t.foundation)] {
        if v.is_some_and(|v| !(v <= REACH)) {
            return Err(format!(
                "`{key}` = {} is beyond {}, {REACH_WHY}; fix: give it in the mesh's units",
                crate::diagnostics::short(v.unwrap_or_default()),
                crate::diagnostics::short(REACH)
            ));
        }
    }
    let shape = match (t.shape, t.normal) {
        (ShapeName::Sphere, None) => Shape::Sphere { radius: t.radius },
        (ShapeName::Sphere, Some(_)) => {
            return Err("a sphere has no `normal`; fix: drop `normal` (only a punch has one)".into())
        }
        (ShapeName::Punch, None) => {
            return Err("a punch needs `normal = [nx, ny, nz]`, the direction it presses in; fix: add it".into())
        }
        (ShapeName::Punch, Some(n)) => {
            // scaled by its largest component first, so a normal of 1e300 is a direction, not inf
            let m = n.0.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            if !(m > 0.0) {
                return Err("`normal` must not be zero; fix: give the direction the punch presses in".into());
            }
            let d = scale(n.0, 1.0 / m);
            Shape::Punch {
                radius: t.radius,
                normal: scale(d, 1.0 / norm(d)),
            }
        }
    };
    let path = match (t.start, t.velocity, &t.table) {
        (Some(s), v, None) => Some(Trajectory::Linear {
            start: s.0,
            velocity: v.map_or([0.0; 3], |v| v.0),
        }),
        (None, None, Some(_)) => None,
        (None, Some(_), _) => {
            return Err("`velocity` moves the tool from `start`; fix: add `start = [x, y, z]`".into())
        }
        (Some(_), _, Some(_)) => {
            return Err("give the path once: `start` (and `velocity`) or `table`; fix: keep one".into())
        }
        (None, None, None) => {
            return Err(
                "the tool has no path; fix: give `start = [x, y, z]` (and `velocity = [vx, vy, vz]`) or `table = \"path.csv\"` (columns t, x, y, z)"
                    .into(),
            )
        }
    };
    Ok((shape, path))
}

/// Every tool, its table read relative to the scenario file.
pub fn resolve(sc: &Scenario, tools: &[Spanned<ToolSec>]) -> Result<Vec<Tool>> {
    let base = sc.path.parent().unwrap_or(std::path::Path::new("."));
    let mut out = Vec::with_capacity(tools.len());
    for (k, t) in tools.iter().enumerate() {
        let sec = t.get_ref();
        let (shape, path) = shape_and_path(sec).map_err(|e| sc.error_at(t.span(), "tool", "", e))?;
        let path = match (path, &sec.table) {
            (Some(p), _) => p,
            (None, Some(file)) => {
                let role = format!("path table of [[tool]] {}", k + 1);
                let bound = Bound {
                    limit: REACH,
                    why: REACH_WHY,
                    fix: REACH_FIX,
                };
                let h = read_bounded(&base.join(file.get_ref()), &role, PATH_COLUMNS, Some(bound))
                    .map_err(|e| sc.error_at(file.span(), "tool", "table", format!("{e:#}")))?;
                Trajectory::Table(h)
            }
            (None, None) => unreachable!("shape_and_path asks for a path"),
        };
        if sec.law == ContactLaw::Kinematic && sec.foundation.is_some() {
            return Err(sc.error_at(
                t.span(),
                "tool",
                "foundation",
                "`foundation` is the depth of the elastic-foundation law, which this tool does not use; fix: add `law = \"foundation\"`, or drop `foundation` (the kinematic law needs none)".to_string(),
            ));
        }
        if sec.law == ContactLaw::Foundation && sec.contact.is_some() {
            return Err(sc.error_at(
                t.span(),
                "tool",
                "contact",
                "`contact` (slide or stick) belongs to the kinematic law; fix: drop it, or drop `law = \"foundation\"`"
                    .to_string(),
            ));
        }
        let grip = sec.contact.unwrap_or(match shape {
            Shape::Sphere { .. } => Grip::Slide,
            Shape::Punch { .. } => Grip::Stick,
        });
        out.push(Tool {
            shape,
            path,
            live: sec.live,
            law: sec.law,
            grip,
            foundation: sec.foundation.unwrap_or(sec.radius),
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tools(keys: &str, files: &[(&str, &str)]) -> Result<Vec<Tool>, String> {
        let d = tempfile::tempdir().unwrap();
        for (name, text) in files {
            std::fs::write(d.path().join(name), text).unwrap();
        }
        let text = format!("[mesh]\nfile = \"m.msh\"\n[time]\nsteps = 1\n[[tool]]\n{keys}\n");
        let sc = Scenario::parse(&d.path().join("s.toml"), text).map_err(|e| e.to_string())?;
        resolve(&sc, &sc.file.tool).map_err(|e| format!("{e:#}"))
    }

    #[test]
    fn a_tool_is_a_shape_on_a_path() {
        let t = tools(
            "shape = \"sphere\"\nradius = 0.5\nstart = [0, 0, 2]\nvelocity = [0, 0, -1]",
            &[],
        )
        .unwrap();
        assert_eq!(t[0].shape, Shape::Sphere { radius: 0.5 });
        assert_eq!(t[0].path.at(0.25), [0.0, 0.0, 1.75]);
        assert!(!t[0].live);
        assert_eq!(t[0].foundation, 0.5, "the foundation defaults to the radius");
        let t = tools(
            "shape = \"punch\"\nradius = 0.2\nnormal = [0, 0, -2]\ntable = \"p.csv\"\nlive = true",
            &[("p.csv", "t,x,y,z\n0,0,0,1\n1,0,0,0\n")],
        )
        .unwrap();
        assert_eq!(
            t[0].shape,
            Shape::Punch {
                radius: 0.2,
                normal: [0.0, 0.0, -1.0]
            }
        );
        assert_eq!(t[0].path.at(0.5), [0.0, 0.0, 0.5]);
        assert!(t[0].live);
        let t = tools(
            "shape = \"sphere\"\nlaw = \"foundation\"\nradius = 0.5\nfoundation = 2\nstart = [0, 0, 2]",
            &[],
        )
        .unwrap();
        assert_eq!(t[0].foundation, 2.0);
        // a normal whose length overflows is still a direction
        let t = tools(
            "shape = \"punch\"\nradius = 0.2\nnormal = [1e300, 1e300, 0]\nstart = [0, 0, 1]",
            &[],
        )
        .unwrap();
        let Shape::Punch { normal, .. } = t[0].shape else {
            panic!()
        };
        assert!((normal[0] - 0.5f64.sqrt()).abs() < 1e-15 && normal[0] == normal[1] && normal[2] == 0.0);
        let t = tools("shape = \"sphere\"\nradius = 1\nstart = [1, 2, 3]", &[]).unwrap();
        assert_eq!(t[0].path.at(100.0), [1.0, 2.0, 3.0]);
    }

    #[test]
    fn each_bad_tool_is_named_with_its_fix() {
        for (keys, want) in [
            ("shape = \"cube\"\nradius = 1\nstart = [0, 0, 0]", "s.toml:6:9: [tool] shape: `cube` is not one of the accepted values; fix: use \"sphere\" or \"punch\""),
            ("shape = \"sphere\"\nradius = 0\nstart = [0, 0, 0]", "[tool] radius: 0 must be a positive number"),
            ("shape = \"sphere\"\nstart = [0, 0, 0]", "missing field `radius`"),
            ("shape = \"sphere\"\nradius = 1\nfoundation = -1\nstart = [0, 0, 0]", "[tool] foundation: -1 must be a positive number"),
            ("shape = \"sphere\"\nradius = 1\nstart = [0, 0, 0]\ncolour = 1", "unknown field `colour`"),
            ("shape = \"sphere\"\nradius = 1\nstart = [0, nan, 0]", "[tool] start: has a non-finite component"),
            ("shape = \"sphere\"\nradius = 1\nnormal = [0, 0, 1]\nstart = [0, 0, 0]", "s.toml:5: [tool]: a sphere has no `normal`; fix: drop `normal`"),
            ("shape = \"punch\"\nradius = 1\nstart = [0, 0, 0]", "a punch needs `normal = [nx, ny, nz]`"),
            ("shape = \"punch\"\nradius = 1\nnormal = [0, 0, 0]\nstart = [0, 0, 0]", "`normal` must not be zero"),
            ("shape = \"sphere\"\nradius = 1", "the tool has no path; fix: give `start"),
            ("shape = \"sphere\"\nradius = 1\nvelocity = [1, 0, 0]", "add `start = [x, y, z]`"),
            ("shape = \"sphere\"\nradius = 1\nstart = [0, 0, 0]\ntable = \"p.csv\"", "give the path once"),
            ("shape = \"sphere\"\nradius = 1\ntable = \"none.csv\"", "s.toml:8: [tool] table: "),
            ("shape = \"sphere\"\nradius = 1\ntable = \"p.csv\"", "p.csv:3: row 2 of the path table of [[tool]] 1: time 0 does not come after the previous row's time 0; fix:"),
            ("shape = \"sphere\"\nradius = 1\ntable = \"q.csv\"", "q.csv:2: row 2 of the path table of [[tool]] 1: z = `z` is not a number"),
            // each row finite, but the path between them passes through infinity
            ("shape = \"sphere\"\nradius = 1\ntable = \"h.csv\"", "h.csv:2: row 1 of the path table of [[tool]] 1: x = 1e308 is beyond +-1e100, where the contact's distances overflow; fix: give the tool's positions"),
            ("shape = \"sphere\"\nradius = 1\nstart = [1e200, 0, 0]", "[tool]: `start` has the component 1e200, beyond +-1e100"),
            ("shape = \"sphere\"\nradius = 1\nstart = [0, 0, 0]\nvelocity = [0, -1e101, 0]", "`velocity` has the component -1e101"),
            ("shape = \"sphere\"\nradius = 1e200\nstart = [0, 0, 0]", "`radius` = 1e200 is beyond 1e100"),
        ] {
            let e = tools(
                keys,
                &[
                    ("p.csv", "t,x,y,z\n0,0,0,1\n0,0,0,0\n"),
                    ("q.csv", "0,0,0,0\n1,0,0,z\n"),
                    ("h.csv", "t,x,y,z\n0,1e308,1e308,0\n10,-1e308,-1e308,0\n"),
                ],
            )
            .unwrap_err();
            assert!(e.contains(want), "{keys}:\n{e}");
            assert!(e.contains("fix:"), "{keys}:\n{e}");
        }
    }
}
