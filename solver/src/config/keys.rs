//! Every scenario key in one place: its choices, its default and its unit in both readings.
//! `eprop run --help` prints `KEYS`; the README and docs/model.md point here. It stays beside
//! the typed sections it describes, and a test checks that it names every key they accept.

/// The scenario keys, as `eprop run --help` prints them.
pub const KEYS: &str = r#"Scenario keys (all but [mesh] file and [time] have defaults). Units: [model] reading = "continuum"
(the default) reads SI units (m, s, N, Pa, kg/m^3) and converts the mesh to metres; "paper" is the
paper's per-node, unit-free reading (its defaults in parentheses). docs/model.md explains the two
readings and derives the defaults.
  [mesh]      file = "organ.msh" (relative to the scenario file; .msh .vtk .vtu .ele .mesh),
              unit = "m" | "cm" | "mm" | "um" (the file's coordinates; continuum: unit or scale
              required), scale = F (metres per file unit, instead of unit),
              strict = false (refuse inverted cells)
  [material]  mass = 1060 kg/m^3 (1, per node), damping = 4.118e4 kg/(m^3 s) (2, per node),
              conductivity = 0.1 m^2/s (0.05) | [rx, ry, rz] | 3x3 table
  [[material.region]]  box | sphere | halfspace | tag | group, and any of conductivity, mass,
              damping, young, beta, poisson, stiffness, coupling: a tissue of its own where it holds
              (a later region wins where regions overlap; docs/model.md section 1)
  [model]     reading = "continuum" | "paper", scheme = "compact" | "paper",
              paper_correction = true, operator_precision = "float64" | "float32",
              stiffness = 4e5 N/m^4 (k_e = 1, per node), coupling = 15 1/m (kappa = 1),
              exponent = 1.0 (p), integrator = "auto" | "euler" | "rkl2" | "implicit"
              (docs/integrators.md), screening = l m (none: a sink -(D/l^2) phi in the
              propagation, docs/model.md section 3)
  [integrator] accuracy = 1e-3 (rkl2, implicit: relative error per step; inf: no error control),
              tolerance = 1e-2 of accuracy (implicit: relative residual of each solve),
              preconditioner = "auto" | "jacobi" | "multigrid" | "amg" (implicit),
              max_iterations = 2000 (implicit, per solve), max_stages = 4096 (rkl2, per step)
  [tissue]    young = 4000 Pa (100), beta = 0.0 (exponential law when > 0),
              poisson = 0.45 (0 <= nu < 0.5; a tool's contact modulus, not the propagation)
  [[fixed]]   box = [[x0,y0,z0],[x1,y1,z1]] | sphere = {center, radius} |
              halfspace = {point, normal} | nodes = [ids] | tag = N | group = "name"
  [[load]]    node = ID | nearest = [x,y,z] m | patch = {center, radius} m;
              force = [fx,fy,fz] N | normal = magnitude N | table = "forces.csv" (columns t s,
              fx, fy, fz N); ramp = [[t0, s0], [t1, s1], ...] (optional scale in time);
              live = false (eprop serve)
  [[tool]]    shape = "sphere" | "punch", radius = R m, normal = [nx,ny,nz] (punch: pressing
              direction); start = [x,y,z] m and velocity = [vx,vy,vz] m/s | table = "path.csv"
              (columns t, x, y, z); law = "kinematic" (the tool holds the tissue it
              touches; the force is the model's reaction) | "foundation" (elastic foundation);
              contact = "slide" (sphere) | "stick" (punch) (kinematic); foundation = radius
              (law = "foundation": its depth, m); live = false (eprop serve: the client moves
              it). See docs/tools.md
  [time]      steps = N | end = T s | equilibrium = tol m/s; dt, h s optional (automatic);
              realtime = false (eprop serve: true): a fixed, bounded work per step chosen at
              setup, implicit TR-BDF2 with direct solves (a factor made once; meshes of
              up to 60,000 nodes) or a fixed number of multigrid-preconditioned
              iterations, no error control (docs/realtime.md); realtime_solver = "auto"
              (direct where it can be) | "direct" (an error where it cannot) | "iterative"
              (the fixed iterations)
  [output]    file = "out.h5" (default: <scenario stem>.h5 beside the scenario), every = 1,
              fields = ["displacement", "velocity", "potential", "energy"] (all),
              precision = "float64" | "float32", compression = 0..9 (gzip),
              overwrite = false (replace an existing series), flush = 1 s (written steps are
              flushed, synced and counted at most this far apart and at every end: a crash
              loses at most that much; 0: every output step)
  [performance] fuse = "auto" | 1..16 (explicit Euler substeps per fused sweep; auto: timed on
              one process, 1 on several), simd = true (false: the portable kernel, other
              rounding), partitioner = "metis" | "ptscotch" (who splits the nodes among
              processes: METIS on rank 0, or PT-Scotch on all of them; the same results)"#;

#[cfg(test)]
mod tests {
    use super::KEYS;
    use crate::config::{
        FixedSet, IntegratorSec, Keys, MaterialSec, MeshSec, Model, OutputSec, PerformanceSec, Push, Region,
        ScenarioFile, TimeSec, TissueSec, ToolSec,
    };
    use serde::de::{self, DeserializeOwned, Visitor};

    /// The keys a derived `Deserialize` of a struct accepts (the field list it gives the
    /// deserializer).
    fn accepted<T: DeserializeOwned>() -> Vec<&'static str> {
        struct Ask(Option<&'static [&'static str]>);
        impl<'de> de::Deserializer<'de> for &mut Ask {
            type Error = de::value::Error;
            fn deserialize_any<V: Visitor<'de>>(self, _: V) -> Result<V::Value, Self::Error> {
                Err(de::Error::custom("not a struct"))
            }
            fn deserialize_struct<V: Visitor<'de>>(
                self,
                _: &'static str,
                fields: &'static [&'static str],
                _: V,
            ) -> Result<V::Value, Self::Error> {
                self.0 = Some(fields);
                Err(de::Error::custom("asked"))
            }
            serde::forward_to_deserialize_any! {
                bool i8 i16 i32 i64 i128 u8 u16 u32 u64 u128 f32 f64 char str string bytes byte_buf
                option unit unit_struct newtype_struct seq tuple tuple_struct map enum identifier
                ignored_any
            }
        }
        let mut ask = Ask(None);
        let _ = T::deserialize(&mut ask);
        ask.0.expect("a struct with derived Deserialize").to_vec()
    }

    /// The keys of a selecting table: its selectors and its own keys.
    fn selecting<X: Keys>() -> Vec<&'static str> {
        [X::SELECTORS, X::OWN].concat()
    }

    /// The lines of `KEYS` from the one that starts with `table` to the next table's.
    fn block(table: &str) -> String {
        let lines: Vec<&str> = KEYS.lines().collect();
        let start = lines
            .iter()
            .position(|l| l.trim_start().starts_with(table))
            .unwrap_or_else(|| panic!("config/keys.rs has no {table}"));
        let end = lines[start + 1..]
            .iter()
            .position(|l| l.trim_start().starts_with('['))
            .map_or(lines.len(), |k| start + 1 + k);
        lines[start..end].join("\n")
    }

    #[test]
    fn the_reference_names_every_key_the_sections_accept() {
        let tables = [
            ("[mesh]", accepted::<MeshSec>()),
            ("[material]", accepted::<MaterialSec>()),
            ("[[material.region]]", selecting::<Region>()),
            ("[model]", accepted::<Model>()),
            ("[integrator]", accepted::<IntegratorSec>()),
            ("[tissue]", accepted::<TissueSec>()),
            ("[[fixed]]", selecting::<FixedSet>()),
            ("[[load]]", selecting::<Push>()),
            ("[[tool]]", accepted::<ToolSec>()),
            ("[time]", accepted::<TimeSec>()),
            ("[output]", accepted::<OutputSec>()),
            ("[performance]", accepted::<PerformanceSec>()),
        ];
        for section in accepted::<ScenarioFile>() {
            assert!(
                tables.iter().any(|(t, _)| t.trim_matches(['[', ']']) == section),
                "[{section}] is not described"
            );
        }
        for (table, keys) in &tables {
            let text = block(table);
            let words: Vec<&str> = text.split(|c: char| !(c.is_ascii_alphanumeric() || c == '_')).collect();
            for key in keys {
                // a key that is a table of its own ([material] region) is described as one
                let own = format!("[[{}.{key}]]", table.trim_matches(['[', ']']));
                assert!(
                    words.contains(key) || KEYS.contains(&own),
                    "{table} {key} is missing from config/keys.rs:\n{text}"
                );
            }
        }
    }
}
