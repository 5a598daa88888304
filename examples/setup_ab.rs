//! Times (in CPU seconds) the setup's mesh-side phases on one mesh file: read, incidence, dual geometry (with
//! its parts in `-vv`-style lines), compact coefficients, and both as a compact-scheme run builds
//! them (`Dual::build_compact`: no dual faces, one pass); REPS repetitions, each phase's median.
//! A digest of the dual and the coefficients (sum of their bits) is printed so that two builds
//! can be compared bit for bit.
//!   cargo run --release --example setup_ab -- MESH [REPS]
//! (MESH `box:tet`, `box:hex`, `box:wedge` or `box:pyramid`: a generated box of those cells)
use eprop::config::tissue::{Materials, Tissue};
use eprop::discretize::geometry::{compact_coefficients, Dual, Incidence};

/// CPU seconds of this process so far (user + system; /proc/self/stat, 10 ms ticks): the
/// machine may be shared, so wall time alone says little.
fn cpu() -> f64 {
    let s = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let rest = s.rsplit(')').next().unwrap_or("");
    let f: Vec<f64> = rest.split_whitespace().map(|x| x.parse().unwrap_or(0.0)).collect();
    (f.get(11).unwrap_or(&0.0) + f.get(12).unwrap_or(&0.0)) / 100.0
}

/// A stopwatch of CPU seconds.
struct Instant(f64);
impl Instant {
    fn now() -> Self {
        Instant(cpu())
    }
    fn elapsed(&self) -> std::time::Duration {
        std::time::Duration::from_secs_f64(cpu() - self.0)
    }
}

fn main() -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().collect();
    let path = std::path::PathBuf::from(a.get(1).expect("a mesh file"));
    let reps: usize = a.get(2).map(|s| s.parse()).transpose()?.unwrap_or(3);
    // the phases' own `-vv` lines (where the dual's seconds go), on stderr
    tracing_subscriber::fmt()
        .with_max_level(tracing::Level::DEBUG)
        .with_writer(std::io::stderr)
        .init();
    let mut times = vec![Vec::new(); 5];
    for _ in 0..reps {
        let t = Instant::now();
        // `box:tet`, `box:hex`, `box:wedge`, `box:pyramid`: a generated 6 x 5 x 4 box of those cells
        let mesh = match path.to_str().and_then(|p| p.strip_prefix("box:")) {
            Some(kind) => {
                use eprop_io::generate::{box_mesh, BoxCells};
                let cells = match kind {
                    "hex" => BoxCells::Hex,
                    "wedge" => BoxCells::Wedge,
                    "pyramid" => BoxCells::PyramidTet,
                    _ => BoxCells::Tet,
                };
                box_mesh([1.0, 0.8, 0.6], [6, 5, 4], cells)?
            }
            None => eprop_io::read_mesh(&path)?,
        };
        times[0].push(t.elapsed().as_secs_f64());
        let n = mesh.n_nodes();
        let t = Instant::now();
        let inc = Incidence::new(&mesh);
        times[1].push(t.elapsed().as_secs_f64());
        let t = Instant::now();
        let dual = Dual::build(&mesh, &inc, n, None);
        times[2].push(t.elapsed().as_secs_f64());
        let r = Materials::uniform(
            n,
            Tissue {
                r: nalgebra::Matrix3::identity() * 0.05,
                ..eprop::config::PAPER_TISSUE
            },
        );
        let t = Instant::now();
        let c = compact_coefficients(&mesh, &inc, &dual, &r);
        times[3].push(t.elapsed().as_secs_f64());
        // as a compact-scheme run builds them: the dual without its faces and the coefficients
        // in one pass, the same bits
        let t = Instant::now();
        let (lean, c2) = Dual::build_compact(&mesh, &inc, n, None, &r);
        times[4].push(t.elapsed().as_secs_f64());
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<u64>>();
        assert_eq!(bits(&lean.vol), bits(&dual.vol));
        assert_eq!(bits(lean.area.as_flattened()), bits(dual.area.as_flattened()));
        assert_eq!((&lean.row_ptr, &lean.col), (&dual.row_ptr, &dual.col));
        assert_eq!(bits(&c2), bits(&c));
        assert!(lean.s.is_empty() && lean.dual_area.is_empty());
        drop((lean, c2));
        let mut h = 0u64;
        let mut mix = |x: f64| h = h.rotate_left(5) ^ x.to_bits();
        dual.s.iter().flatten().for_each(|&x| mix(x));
        dual.vol.iter().for_each(|&x| mix(x));
        dual.area.iter().flatten().for_each(|&x| mix(x));
        dual.dual_area.iter().for_each(|&x| mix(x));
        c.iter().for_each(|&x| mix(x));
        let cols: u64 = dual
            .col
            .iter()
            .enumerate()
            .map(|(k, &j)| (k as u64 + 1) * j as u64)
            .sum();
        println!(
            "{n} nodes, {} cells: digest {h:016x} {cols:x}; read {:.2} s, incidence {:.2} s, dual {:.2} s, coefficients {:.2} s, compact (dual without faces and coefficients) {:.2} s",
            mesh.n_cells(),
            times[0].last().unwrap(),
            times[1].last().unwrap(),
            times[2].last().unwrap(),
            times[3].last().unwrap(),
            times[4].last().unwrap()
        );
    }
    let med = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let m: Vec<f64> = times.iter_mut().map(med).collect();
    println!(
        "median: read {:.2} s, incidence {:.2} s, dual {:.2} s, coefficients {:.2} s, compact (dual without faces and coefficients) {:.2} s",
        m[0], m[1], m[2], m[3], m[4]
    );
    Ok(())
}
