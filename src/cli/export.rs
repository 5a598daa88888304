//! `eprop export`: the deformed outer surface of a series' steps as files a viewer or a game
//! engine loads (OBJ, STL, PLY, VTU), optionally with a scalar per vertex (as a colour in OBJ
//! and PLY, as point data in VTU).

use anyhow::{bail, Result};
use eprop::config::Input;
use eprop::guard::safety::claim_file;
use eprop_io::mesh::boundary_faces;
use eprop_mesh::Mesh;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// A surface file format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    Obj,
    Stl,
    Ply,
    Vtu,
}

impl Format {
    pub fn parse(s: &str) -> Result<Format> {
        Ok(match s {
            "obj" => Format::Obj,
            "stl" => Format::Stl,
            "ply" => Format::Ply,
            "vtu" => Format::Vtu,
            _ => bail!("--surface {s:?}: not a surface format; fix: give obj, stl, ply or vtu"),
        })
    }
    fn ext(self) -> &'static str {
        match self {
            Format::Obj => "obj",
            Format::Stl => "stl",
            Format::Ply => "ply",
            Format::Vtu => "vtu",
        }
    }
}

/// What to export.
pub struct ExportOptions {
    pub format: Format,
    /// Every k-th output step (1: all).
    pub every: usize,
    /// One output step only.
    pub step: Option<usize>,
    /// A point field whose value (its magnitude for vectors) goes with each vertex.
    pub scalar: Option<String>,
    /// Files are `<prefix>_<step>.<ext>` (one step to a prefix ending in `.<ext>`: the prefix).
    pub prefix: PathBuf,
    pub overwrite: bool,
    /// The length unit of the written coordinates: m, cm, mm, um, or `mesh` (the mesh file's
    /// own); None: the series' own (metres in the continuum reading).
    pub unit: Option<String>,
}

/// The factor from the series' coordinates to those written: 1 without `--unit`; refused in the
/// paper's unit-free reading, whose coordinates have no unit to convert.
pub fn unit_factor(series: &Path, unit: Option<&str>) -> Result<f64> {
    use eprop::config::Unit;
    let Some(unit) = unit else { return Ok(1.0) };
    let text = eprop_series::vtkhdf::read_scenario(series)?;
    let doc: toml::Table = text.parse().map_err(|e| {
        anyhow::anyhow!(
            "{}: its scenario text (/eprop/scenario) does not parse: {e}; fix: leave out --unit",
            series.display()
        )
    })?;
    let get = |sec: &str, key: &str| doc.get(sec).and_then(|t| t.get(key)).cloned();
    let reading = get("model", "reading").and_then(|v| v.as_str().map(str::to_string));
    if reading.as_deref() == Some("paper") {
        bail!(
            "--unit {unit}: {} is in the paper's unit-free reading ([model] reading = \"paper\"): its coordinates are the scenario's own units, with nothing to convert; fix: leave out --unit",
            series.display()
        );
    }
    let named = |u: &str| match u {
        "m" => Some(Unit::M),
        "cm" => Some(Unit::Cm),
        "mm" => Some(Unit::Mm),
        "um" => Some(Unit::Um),
        _ => None,
    };
    if let Some(u) = named(unit) {
        return Ok(1.0 / u.metres());
    }
    if unit != "mesh" {
        bail!("--unit {unit}: not a length unit; fix: m, cm, mm, um, or mesh (the mesh file's own unit)");
    }
    if let Some(u) = get("mesh", "unit").and_then(|v| v.as_str().and_then(named)) {
        return Ok(1.0 / u.metres());
    }
    match get("mesh", "scale").and_then(|v| v.as_float().or(v.as_integer().map(|i| i as f64))) {
        Some(f) if f > 0.0 && f.is_finite() => Ok(1.0 / f),
        _ => Ok(1.0),
    }
}

/// The outer surface of a mesh: its vertices (mesh node ids, in increasing order) and its
/// triangles (indices into the vertices, wound outward; quadrilateral faces split in two).
pub struct Surface {
    pub nodes: Vec<u32>,
    pub triangles: Vec<[u32; 3]>,
}

impl Surface {
    pub fn of(mesh: &Mesh) -> Surface {
        let mut tris_global = Vec::new();
        for (c, f) in boundary_faces(mesh) {
            let cell = mesh.cell(c as usize);
            let face = mesh.kinds[c as usize].faces()[f as usize];
            let v: Vec<u32> = face.iter().map(|&k| cell[k]).collect();
            for k in 1..v.len() - 1 {
                tris_global.push([v[0], v[k], v[k + 1]]);
            }
        }
        let mut nodes: Vec<u32> = tris_global.iter().flatten().copied().collect();
        nodes.sort_unstable();
        nodes.dedup();
        let index = |g: u32| nodes.binary_search(&g).expect("a surface node") as u32;
        let triangles = tris_global.iter().map(|t| t.map(index)).collect();
        Surface { nodes, triangles }
    }
}

/// The files of one export, in step order: (output step, path).
pub fn plan(steps: usize, o: &ExportOptions) -> Result<Vec<(usize, PathBuf)>> {
    if steps == 0 {
        bail!("the series holds no complete step; fix: export a series a run has written steps to");
    }
    let chosen: Vec<usize> = match o.step {
        Some(k) if k < steps => vec![k],
        Some(k) => bail!(
            "--step {k}: the series holds output steps 0 to {}; fix: give one of them",
            steps - 1
        ),
        None => (0..steps).step_by(o.every.max(1)).collect(),
    };
    // one step to a name with the format's extension: that name (not s.obj_000010.obj)
    let ext = format!(".{}", o.format.ext());
    if o.step.is_some() && o.prefix.to_string_lossy().to_ascii_lowercase().ends_with(&ext) {
        return Ok(chosen.into_iter().map(|k| (k, o.prefix.clone())).collect());
    }
    Ok(chosen
        .into_iter()
        .map(|k| {
            let mut s = o.prefix.as_os_str().to_owned();
            s.push(format!("_{k:06}.{}", o.format.ext()));
            (k, PathBuf::from(s))
        })
        .collect())
}

/// Writes the deformed surface of each chosen step; returns the files written.
pub fn export(series: &Path, o: &ExportOptions) -> Result<Vec<PathBuf>> {
    let (mesh, steps) = eprop_series::vtkhdf::read_mesh(series)?;
    let files = plan(steps, o)?;
    let inputs = [Input {
        role: format!("the series exported ({})", series.display()),
        path: series.to_path_buf(),
    }];
    let role = "an exported surface (-o)";
    // every file claimed as every writer claims its output, before any is written: not the
    // series read, not a file a run is writing (its lock, through any link), a regular file
    // (a FIFO would block the export forever), replaced only with --overwrite
    for (_, p) in &files {
        if same_file(p, series) {
            bail!(
                "{}: the export would overwrite the series it reads; fix: choose another -o prefix",
                p.display()
            );
        }
        if !o.overwrite && std::fs::symlink_metadata(p).is_ok() {
            bail!(
                "{}: exists; fix: add --overwrite to replace it, or choose another -o prefix",
                p.display()
            );
        }
    }
    if let Some(dir) = o.prefix.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .map_err(|e| anyhow::anyhow!("{}: cannot create the directory: {e}", dir.display()))?;
    }
    for (_, p) in &files {
        drop(claim_file(p, role, &inputs, o.overwrite)?);
    }
    let factor = unit_factor(series, o.unit.as_deref())?;
    let surf = Surface::of(&mesh);
    if surf.triangles.is_empty() {
        bail!(
            "{}: the mesh has no boundary faces (no volume cells); nothing to export",
            series.display()
        );
    }
    for (k, path) in &files {
        let u = eprop_series::vtkhdf::read_step(series, "displacement", *k)?;
        let scalar = match &o.scalar {
            Some(name) => Some(values(series, name, *k, mesh.n_nodes())?),
            None => None,
        };
        let points: Vec<[f64; 3]> = surf
            .nodes
            .iter()
            .map(|&g| {
                let (p, g) = (mesh.points[g as usize], g as usize);
                [p[0] + u[3 * g], p[1] + u[3 * g + 1], p[2] + u[3 * g + 2]].map(|x| x * factor)
            })
            .collect();
        let s: Option<Vec<f64>> = scalar.map(|v| surf.nodes.iter().map(|&g| v[g as usize]).collect());
        let text = render(
            o.format,
            &points,
            &surf.triangles,
            s.as_deref(),
            o.scalar.as_deref().unwrap_or(""),
        );
        // held while it is written
        let _claim = claim_file(path, role, &inputs, o.overwrite)?;
        write_regular(path, text.as_bytes())?;
    }
    Ok(files.into_iter().map(|f| f.1).collect())
}

/// Writes a file that must be a regular one: opened without blocking (a FIFO put in its place
/// since the claim fails or is refused, it never blocks the export).
fn write_regular(path: &Path, bytes: &[u8]) -> Result<()> {
    use std::io::Write;
    use std::os::unix::fs::OpenOptionsExt;
    let cannot = |e: std::io::Error| anyhow::anyhow!("{}: cannot write: {e}", path.display());
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(false)
        .custom_flags(libc::O_NONBLOCK)
        .open(path)
        .map_err(cannot)?;
    if !f.metadata().map_err(cannot)?.is_file() {
        bail!(
            "{}: is not a regular file; fix: give a -o prefix whose files are new or regular files",
            path.display()
        );
    }
    f.set_len(0).map_err(cannot)?;
    f.write_all(bytes).map_err(cannot)
}

fn same_file(a: &Path, b: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (std::fs::metadata(a), std::fs::metadata(b)) {
        (Ok(x), Ok(y)) => x.dev() == y.dev() && x.ino() == y.ino(),
        _ => false,
    }
}

/// A point field of step k as one value per node (the magnitude of a vector field).
fn values(series: &Path, name: &str, k: usize, n: usize) -> Result<Vec<f64>> {
    let v = eprop_series::vtkhdf::read_step(series, name, k).map_err(|e| {
        anyhow::anyhow!("{e}; fix: --scalar names a written point field (displacement, potential, energy, ...)")
    })?;
    let c = v.len() / n.max(1);
    Ok(match c {
        1 => v,
        _ => v
            .chunks(c)
            .map(|x| x.iter().map(|y| y * y).sum::<f64>().sqrt())
            .collect(),
    })
}

/// A value in [lo, hi] as a blue-white-red colour.
fn colour(x: f64, lo: f64, hi: f64) -> [u8; 3] {
    let t = if hi > lo {
        ((x - lo) / (hi - lo)).clamp(0.0, 1.0)
    } else {
        0.5
    };
    let (r, g, b) = if t < 0.5 {
        let s = 2.0 * t;
        (s, s, 1.0)
    } else {
        let s = 2.0 * (1.0 - t);
        (1.0, s, s)
    };
    [
        (r * 255.0).round() as u8,
        (g * 255.0).round() as u8,
        (b * 255.0).round() as u8,
    ]
}

fn normal(p: &[[f64; 3]], t: &[u32; 3]) -> [f64; 3] {
    let (a, b, c) = (p[t[0] as usize], p[t[1] as usize], p[t[2] as usize]);
    let (u, v) = (
        [b[0] - a[0], b[1] - a[1], b[2] - a[2]],
        [c[0] - a[0], c[1] - a[1], c[2] - a[2]],
    );
    let n = [
        u[1] * v[2] - u[2] * v[1],
        u[2] * v[0] - u[0] * v[2],
        u[0] * v[1] - u[1] * v[0],
    ];
    let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    if l > 0.0 {
        [n[0] / l, n[1] / l, n[2] / l]
    } else {
        [0.0; 3]
    }
}

/// One surface as the text of a file of `format`.
pub fn render(format: Format, p: &[[f64; 3]], tris: &[[u32; 3]], scalar: Option<&[f64]>, name: &str) -> String {
    let (lo, hi) = scalar.map_or((0.0, 0.0), |s| {
        s.iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)))
    });
    let mut s = String::new();
    match format {
        Format::Obj => {
            s.push_str("# eprop: deformed outer surface\n");
            for (i, x) in p.iter().enumerate() {
                match scalar {
                    Some(v) => {
                        let c = colour(v[i], lo, hi);
                        let _ = writeln!(
                            s,
                            "v {:e} {:e} {:e} {:.4} {:.4} {:.4}",
                            x[0],
                            x[1],
                            x[2],
                            c[0] as f64 / 255.0,
                            c[1] as f64 / 255.0,
                            c[2] as f64 / 255.0
                        );
                    }
                    None => {
                        let _ = writeln!(s, "v {:e} {:e} {:e}", x[0], x[1], x[2]);
                    }
                }
            }
            for t in tris {
                let _ = writeln!(s, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1);
            }
        }
        Format::Stl => {
            s.push_str("solid eprop\n");
            for t in tris {
                let n = normal(p, t);
                let _ = writeln!(s, "facet normal {:e} {:e} {:e}\nouter loop", n[0], n[1], n[2]);
                for &k in t {
                    let x = p[k as usize];
                    let _ = writeln!(s, "vertex {:e} {:e} {:e}", x[0], x[1], x[2]);
                }
                s.push_str("endloop\nendfacet\n");
            }
            s.push_str("endsolid eprop\n");
        }
        Format::Ply => {
            let _ = write!(
                s,
                "ply\nformat ascii 1.0\ncomment eprop: deformed outer surface\nelement vertex {}\nproperty double x\nproperty double y\nproperty double z\n",
                p.len()
            );
            if scalar.is_some() {
                let _ = write!(
                    s,
                    "property uchar red\nproperty uchar green\nproperty uchar blue\nproperty double {}\n",
                    if name.is_empty() { "value" } else { name }
                );
            }
            let _ = write!(
                s,
                "element face {}\nproperty list uchar int vertex_indices\nend_header\n",
                tris.len()
            );
            for (i, x) in p.iter().enumerate() {
                let _ = write!(s, "{:e} {:e} {:e}", x[0], x[1], x[2]);
                if let Some(v) = scalar {
                    let c = colour(v[i], lo, hi);
                    let _ = write!(s, " {} {} {} {:e}", c[0], c[1], c[2], v[i]);
                }
                s.push('\n');
            }
            for t in tris {
                let _ = writeln!(s, "3 {} {} {}", t[0], t[1], t[2]);
            }
        }
        Format::Vtu => {
            let _ = write!(
                s,
                "<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\">\n<!-- eprop: deformed outer surface -->\n<UnstructuredGrid>\n<Piece NumberOfPoints=\"{}\" NumberOfCells=\"{}\">\n<Points>\n<DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">\n",
                p.len(),
                tris.len()
            );
            for x in p {
                let _ = writeln!(s, "{:e} {:e} {:e}", x[0], x[1], x[2]);
            }
            s.push_str(
                "</DataArray>\n</Points>\n<Cells>\n<DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n",
            );
            for t in tris {
                let _ = writeln!(s, "{} {} {}", t[0], t[1], t[2]);
            }
            s.push_str("</DataArray>\n<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n");
            for i in 0..tris.len() {
                let _ = writeln!(s, "{}", 3 * (i + 1));
            }
            s.push_str("</DataArray>\n<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n");
            for _ in tris {
                s.push_str("5\n");
            }
            s.push_str("</DataArray>\n</Cells>\n");
            if let Some(v) = scalar {
                let _ = writeln!(
                    s,
                    "<PointData>\n<DataArray type=\"Float64\" Name=\"{}\" format=\"ascii\">",
                    if name.is_empty() { "value" } else { name }
                );
                for x in v {
                    let _ = writeln!(s, "{x:e}");
                }
                s.push_str("</DataArray>\n</PointData>\n");
            }
            s.push_str("</Piece>\n</UnstructuredGrid>\n</VTKFile>\n");
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cube_surface_is_closed_and_wound_outward() {
        let m = eprop_io::generate::box_mesh([1.0; 3], [2, 2, 2], eprop_io::generate::BoxCells::Tet).unwrap();
        let s = Surface::of(&m);
        // 6 faces of 2 x 2 squares, 2 triangles each
        assert_eq!(s.triangles.len(), 6 * 4 * 2);
        assert_eq!(s.nodes.len(), 26);
        // closed: every edge in exactly two triangles, once each way
        let mut edges = std::collections::HashMap::new();
        for t in &s.triangles {
            for k in 0..3 {
                *edges.entry((t[k], t[(k + 1) % 3])).or_insert(0) += 1;
            }
        }
        for (&(a, b), &n) in &edges {
            assert_eq!(n, 1);
            assert_eq!(edges.get(&(b, a)), Some(&1));
        }
        // outward: the enclosed volume by the divergence theorem is +1
        let p: Vec<[f64; 3]> = s.nodes.iter().map(|&g| m.points[g as usize]).collect();
        let vol: f64 = s
            .triangles
            .iter()
            .map(|t| {
                let (a, b, c) = (p[t[0] as usize], p[t[1] as usize], p[t[2] as usize]);
                (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                    + a[2] * (b[0] * c[1] - b[1] * c[0]))
                    / 6.0
            })
            .sum();
        assert!((vol - 1.0).abs() < 1e-12, "{vol}");
    }

    #[test]
    fn the_formats_hold_every_vertex_and_triangle() {
        let p = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let t = [[0u32, 1, 2]];
        let obj = render(Format::Obj, &p, &t, Some(&[0.0, 1.0, 2.0]), "u");
        assert_eq!(obj.lines().filter(|l| l.starts_with("v ")).count(), 3);
        assert!(obj.contains("f 1 2 3"));
        let stl = render(Format::Stl, &p, &t, None, "");
        assert!(stl.contains("facet normal 0e0 0e0 1e0"));
        let ply = render(Format::Ply, &p, &t, Some(&[0.0, 1.0, 2.0]), "energy");
        assert!(
            ply.contains("element vertex 3") && ply.contains("property double energy") && ply.ends_with("3 0 1 2\n")
        );
        let vtu = render(Format::Vtu, &p, &t, None, "");
        assert!(vtu.contains("NumberOfPoints=\"3\" NumberOfCells=\"1\""));
    }
}
