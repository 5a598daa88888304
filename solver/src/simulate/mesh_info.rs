//! What `eprop info` reports about a mesh: its size, groups, geometry checks, cell quality
//! and the stable substep of a reference conductivity (0.05), with the nodes and cells that
//! set it.

use crate::config::tissue::Tensor;
use crate::diagnostics::fixed;
use crate::discretize::geometry::{compact_coefficients, Dual, Incidence};
use crate::discretize::operator::Compact;
use crate::propagate::integrate::euler::SAFETY;
use eprop_io::geom::{cell_quality, cell_volume};
use eprop_mesh::Mesh;
use serde::Serialize;
/// What `eprop info` reports about a mesh.
#[derive(Serialize, Debug)]
pub struct MeshInfo {
    pub file: String,
    pub nodes: usize,
    pub cells: usize,
    pub cell_kinds: Vec<(String, usize)>,
    /// Surface facets stored in the file (gmsh's triangles and quads; none in .vtu/.vtk).
    pub surface_facets: usize,
    /// Faces of the volume cells that belong to one cell: the mesh's boundary, computed.
    pub boundary_faces: usize,
    pub groups: Vec<(u8, i32, String)>,
    /// The volume cells' tags (a multi-tissue atlas's tissues): tag, cells, their volume.
    pub cell_tags: Vec<(i32, usize, f64)>,
    pub bounds: [[f64; 3]; 2],
    pub volume: f64,
    pub control_volume_sum: f64,
    pub max_closure_error: f64,
    pub min_quality: f64,
    pub max_quality: f64,
    pub stable_h_r005: f64,
    /// Which nodes and cells set the stable substep (conductivity 0.05).
    pub stiffness: crate::discretize::quality::Stiffness,
    pub unreferenced_nodes: usize,
    pub warnings: Vec<String>,
}

pub fn mesh_info(mesh: &Mesh) -> MeshInfo {
    let n = mesh.n_nodes();
    let inc = Incidence::new(mesh);
    let dual = Dual::build(mesh, &inc, n, None);
    let mut by_tag = std::collections::BTreeMap::<i32, (usize, f64)>::new();
    let mut volume = 0.0;
    for c in 0..mesh.n_cells() {
        let v = cell_volume(mesh.kinds[c], mesh.cell(c), &mesh.points);
        volume += v;
        let e = by_tag.entry(mesh.cell_tags[c]).or_default();
        e.0 += 1;
        e.1 += v;
    }
    let (mut qmin, mut qmax) = (f64::INFINITY, 0.0f64);
    for c in 0..mesh.n_cells() {
        let q = cell_quality(mesh.kinds[c], mesh.cell(c), &mesh.points);
        qmin = qmin.min(q);
        qmax = qmax.max(q);
    }
    let r = crate::config::tissue::Materials::uniform(
        n,
        crate::config::tissue::Tissue {
            r: Tensor::identity() * 0.05,
            ..crate::config::PAPER_TISSUE
        },
    );
    let a = compact_coefficients(mesh, &inc, &dual, &r);
    let active: Vec<bool> = dual.vol.iter().map(|&v| v > 0.0).collect();
    let op = Compact::new(&dual, &a, &active);
    let g = op.gershgorin();
    let stiffness = crate::discretize::quality::analyse(mesh, &op, &dual.vol, &r, &|c| mesh.cell_id(c));
    let (lo, hi) = mesh.bounds();
    let unref = dual.vol.iter().filter(|&&v| v <= 0.0).count();
    let mut warnings = mesh.warnings.clone();
    if unref > 0 {
        warnings.push(format!("{unref} node(s) belong to no cell"));
    }
    MeshInfo {
        file: mesh.source.clone(),
        nodes: n,
        cells: mesh.n_cells(),
        cell_kinds: mesh
            .kind_counts()
            .into_iter()
            .map(|(k, c)| (k.name().to_string(), c))
            .collect(),
        surface_facets: mesh.facets.len(),
        boundary_faces: eprop_io::mesh::boundary_faces(mesh).len(),
        groups: mesh.group_names.iter().map(|((d, t), s)| (*d, *t, s.clone())).collect(),
        cell_tags: by_tag.into_iter().map(|(t, (n, v))| (t, n, v)).collect(),
        bounds: [lo, hi],
        volume,
        control_volume_sum: dual.vol.iter().sum(),
        max_closure_error: dual.max_closure_error(),
        min_quality: qmin,
        max_quality: qmax,
        stable_h_r005: SAFETY * 2.0 / g,
        stiffness,
        unreferenced_nodes: unref,
        warnings,
    }
}

impl std::fmt::Display for MeshInfo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "{}", self.file)?;
        let kinds: Vec<String> = self.cell_kinds.iter().map(|(k, c)| format!("{c} {k}")).collect();
        writeln!(f, "  nodes            {}", self.nodes)?;
        writeln!(f, "  cells            {} ({})", self.cells, kinds.join(", "))?;
        match self.surface_facets {
            0 => writeln!(
                f,
                "  surface facets   none stored in the file; {} boundary faces found",
                self.boundary_faces
            )?,
            n => writeln!(
                f,
                "  surface facets   {n} stored; {} boundary faces found",
                self.boundary_faces
            )?,
        }
        for (d, t, s) in &self.groups {
            writeln!(f, "  group            {s:?} (dim {d}, tag {t})")?;
        }
        if self.cell_tags.len() > 1 {
            // the tissues of an atlas, for `[[material.region]] tag = N`
            for (t, n, v) in &self.cell_tags {
                writeln!(f, "  cell tag         {t}: {n} cells, volume {v:.6e}")?;
            }
        }
        writeln!(
            f,
            "  bounds           [{}, {}, {}] .. [{}, {}, {}]",
            fixed(self.bounds[0][0], 4),
            fixed(self.bounds[0][1], 4),
            fixed(self.bounds[0][2], 4),
            fixed(self.bounds[1][0], 4),
            fixed(self.bounds[1][1], 4),
            fixed(self.bounds[1][2], 4)
        )?;
        writeln!(f, "  volume           {:.12e}", self.volume)?;
        writeln!(
            f,
            "  sum of V_i       {:.12e} (relative difference {:.1e})",
            self.control_volume_sum,
            ((self.control_volume_sum - self.volume) / self.volume).abs()
        )?;
        writeln!(
            f,
            "  closure error    {:.2e} (max |sum_j S_ij + A_i| / dual area)",
            self.max_closure_error
        )?;
        writeln!(
            f,
            "  cell quality     {:.4} .. {:.4} (1 = regular)",
            self.min_quality, self.max_quality
        )?;
        write!(
            f,
            "  stable h         {:.4e} (compact, conductivity 0.05, {SAFETY} of the bound)\n{}",
            self.stable_h_r005,
            self.stiffness.describe(17)
        )?;
        for w in &self.warnings {
            write!(f, "\n  warning          {w}")?;
        }
        Ok(())
    }
}
