//! A scenario resolved on one process's share of a mesh, for a run under mpirun that starts
//! from a VTKHDF mesh in slabs (`distribute::slabs::start`): no process holds the whole mesh.
//!
//! `Setup::deferred` resolves the sections that do not need the mesh (time, output, model,
//! tools, ...) on rank 0, which sends it; every process then resolves the rest on its local
//! mesh (owned nodes first, then its halo nodes, with every cell that touches an owned node),
//! `Setup::resolve_local`, with what needs the whole mesh taken by reductions (`Global`): the
//! bounds, a `nearest` node, the supports' planes, a load's contact nodes and weights. The
//! result is what `Setup::restrict` gives for the same plan on the rank-0 path, bit for bit.
//!
//! Not resolved on this path yet (refused by name, with the fix): `[[material.region]]`,
//! `tag` and `group` selectors, the continuum reading's `patch`.

use super::fixed::{FixedSet, Plane};
use super::loads::{Load, Push};
use super::select::{distance, nearest_in_reach, nearest_surface_flags, surface_node_areas, Keys, Selector};
use super::{Reading, Scenario, Setup};
use anyhow::{anyhow, Result};
use eprop_io::geom::{dot, norm, sub};
use eprop_mesh::Mesh;
use toml::Spanned;

/// The collectives a local resolution needs (every process calls each in the same order);
/// `distribute` implements it on its `Comm`.
pub trait Reduce {
    /// The largest `x` of every process.
    fn max(&self, x: f64) -> f64;
    /// The largest of each entry over every process.
    fn max_each(&self, x: &[f64]) -> Vec<f64>;
    /// Every process's `x`, in rank order.
    fn all_gather_var(&self, x: &[f64]) -> Vec<f64>;
    /// Overwrites the halo entries of `x` (one value per local node) with their owners'.
    fn exchange(&self, x: &mut [f64]);
}

/// What a process knows of the whole mesh beside its local mesh.
pub struct Global<'a> {
    /// Local nodes `0..n_owned` are owned here (the others are halo nodes).
    pub n_owned: usize,
    /// Global index of each local node.
    pub gid: &'a [u32],
    /// Nodes of the whole mesh.
    pub n_nodes: usize,
    /// Bounds of the whole mesh.
    pub bounds: ([f64; 3], [f64; 3]),
    pub red: &'a dyn Reduce,
    /// The piece (connected component) of each local node, named by the lowest global index
    /// in it (`piece_labels`).
    pub pieces: &'a [f64],
}

/// Whether `b` holds on any process.
fn any(red: &dyn Reduce, b: bool) -> bool {
    red.max(f64::from(u8::from(b))) > 0.0
}

/// The piece (connected component of the whole mesh) of each local node, named by the lowest
/// global index in it: the local components' least labels spread through the halos until no
/// process changes one (a few rounds: one per local part a piece crosses). Every process calls.
pub fn piece_labels(mesh: &Mesh, gid: &[u32], n_owned: usize, red: &dyn Reduce) -> Vec<f64> {
    let (comp, k) = eprop_mesh::mesh::components(mesh);
    let mut label: Vec<f64> = gid.iter().map(|&g| f64::from(g)).collect();
    let mut rounds = 0;
    loop {
        let mut low = vec![f64::INFINITY; k];
        for (i, &c) in comp.iter().enumerate() {
            low[c as usize] = low[c as usize].min(label[i]);
        }
        let mut changed = false;
        for i in 0..n_owned {
            let l = low[comp[i] as usize];
            if l < label[i] {
                label[i] = l;
                changed = true;
            }
        }
        red.exchange(&mut label);
        rounds += 1;
        if !any(red, changed) {
            break;
        }
    }
    tracing::debug!("pieces labelled in {rounds} rounds of the halo exchange");
    label
}

impl Global<'_> {
    fn any(&self, b: bool) -> bool {
        any(self.red, b)
    }
    /// 1e-9 of the whole mesh's diagonal (the half-space selector's tolerance).
    fn tol(&self) -> f64 {
        1e-9 * norm(sub(self.bounds.1, self.bounds.0))
    }
}

/// Whether a scenario's mesh is a VTKHDF file (read in slabs under mpirun).
pub fn slab_mesh(sc: &Scenario) -> bool {
    sc.mesh_path()
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("vtkhdf"))
}

fn refuse(sc: &Scenario, s: &Spanned<Selector>, table: &str) -> anyhow::Error {
    sc.error_at(
        s.span(),
        table,
        s.get_ref().key(),
        format!(
            "`{}` is not resolved yet when a run under mpirun starts from a .vtkhdf mesh (each process reads its slab); fix: run from the mesh file the .vtkhdf was converted from (.msh, ...), or on one process, or select by `box`, `sphere` or `halfspace`",
            s.get_ref().key()
        ),
    )
}

impl Setup {
    /// The sections that do not need the mesh resolved, the others left empty (an empty mesh):
    /// `resolve_local` finishes it on each process's share of the mesh.
    pub fn deferred(scenario: Scenario) -> Result<Setup> {
        let sc = &scenario;
        super::mesh::factor(sc)?;
        check_supported(sc)?;
        let mesh = Mesh::new(sc.mesh_path().display().to_string());
        Setup::without_mesh_sections(scenario, mesh)
    }

    /// Whether this setup waits for `resolve_local` (made by `deferred`).
    pub fn is_deferred(&self) -> bool {
        self.mesh.n_nodes() == 0 && slab_mesh(&self.scenario)
    }

    /// Resolves the mesh's sections of a `deferred` setup on this process's local mesh (owned
    /// nodes first; every process calls, in the same order).
    pub fn resolve_local(mut self, mesh: Mesh, g: &Global) -> Result<Setup> {
        let sc = &self.scenario;
        let f = &sc.file;
        let (lo, hi) = g.bounds;
        let extent = distance(hi, lo);
        if g.n_nodes > 0 && !(super::mesh::EXTENT.0..=super::mesh::EXTENT.1).contains(&extent) {
            return Err(anyhow!(
                "{}: the mesh spans {extent:.4e} units (its bounding-box diagonal), outside {:e} to {:e}, where volumes and contact stresses overflow or underflow; fix: a [mesh] unit that names the unit of the file's coordinates, or a [mesh] scale that makes it a few units to a few thousand across",
                sc.path.display(),
                super::mesh::EXTENT.0,
                super::mesh::EXTENT.1
            ));
        }
        let materials = super::material::resolve(sc, &f.material, &f.model, self.law, f.tissue.poisson, &mesh)?;
        let n = mesh.n_nodes();
        let mut fixed = vec![false; n];
        let mut supports = Vec::new();
        if f.fixed.is_empty() {
            // the same refusal as the whole mesh's
            super::fixed::resolve(sc, &f.fixed, &mesh)?;
        }
        for e in &f.fixed {
            let s = &e.selector;
            let set = nodes(s.get_ref(), &mesh, g)
                .map_err(|e| sc.error_at(s.span(), FixedSet::TABLE, s.get_ref().key(), e))?;
            if !g.any(set[..g.n_owned].iter().any(|&b| b)) {
                return Err(sc.error_at(
                    s.span(),
                    FixedSet::TABLE,
                    s.get_ref().key(),
                    "selects no node; fix: check it against the mesh (eprop info MESH)",
                ));
            }
            for i in 0..n {
                fixed[i] |= set[i];
            }
            supports.extend(support_plane(s.get_ref(), &set, &mesh, g));
        }
        every_piece_held(sc, &mesh, &fixed, g)?;
        let loads = loads(sc, &mesh, &fixed, g)?;
        self.materials = materials;
        self.fixed = fixed;
        self.supports = supports;
        self.loads = loads;
        self.mesh = mesh;
        super::scales::check_with(&self, g.bounds, g.n_nodes)?;
        Ok(self)
    }
}

/// Refuses what the local resolution does not do yet, naming the key and the fix.
fn check_supported(sc: &Scenario) -> Result<()> {
    let f = &sc.file;
    if let Some(r) = f.material.region.first() {
        return Err(sc.error_at(
            r.selector.span(),
            "material.region",
            r.selector.get_ref().key(),
            "material regions are not resolved yet when a run under mpirun starts from a .vtkhdf mesh (each process reads its slab); fix: run from the mesh file the .vtkhdf was converted from (.msh, ...), or on one process",
        ));
    }
    for e in &f.fixed {
        if !matches!(
            e.selector.get_ref(),
            Selector::Box(_) | Selector::Sphere(_) | Selector::HalfSpace(_)
        ) {
            return Err(refuse(sc, &e.selector, FixedSet::TABLE));
        }
    }
    for l in &f.load {
        match l.selector.get_ref() {
            Selector::Tag(_) | Selector::Group(_) => return Err(refuse(sc, &l.selector, Push::TABLE)),
            Selector::Patch(_) if f.model.reading == Reading::Continuum => {
                return Err(sc.error_at(
                    l.selector.span(),
                    Push::TABLE,
                    "patch",
                    "the continuum reading's `patch` is not resolved yet when a run under mpirun starts from a .vtkhdf mesh (each process reads its slab); fix: run from the mesh file the .vtkhdf was converted from (.msh, ...), or on one process",
                ))
            }
            _ => {}
        }
    }
    Ok(())
}

/// The nodes a selector picks among the local nodes (the same flags as on the whole mesh for
/// every local node); `tag`, `group` and `patch` are not resolved here.
fn nodes(s: &Selector, mesh: &Mesh, g: &Global) -> Result<Vec<bool>, String> {
    match s {
        Selector::Box(_) | Selector::Sphere(_) => s.nodes(mesh),
        Selector::HalfSpace(h) => {
            let nn = norm(h.normal);
            let tol = g.tol();
            Ok(mesh
                .points
                .iter()
                .map(|p| dot(sub(*p, h.point), h.normal) / nn >= -tol)
                .collect())
        }
        Selector::Node(id) => nodes(&Selector::Nodes(vec![*id]), mesh, g).map_err(|e| {
            if e.contains("is not in the mesh") {
                format!("node {id} is not in the mesh; fix: use a node id of the mesh file")
            } else {
                e
            }
        }),
        Selector::Nodes(ids) => {
            let index: std::collections::HashMap<u64, usize> =
                mesh.node_ids.iter().enumerate().map(|(i, &id)| (id, i)).collect();
            let mut set = vec![false; mesh.n_nodes()];
            let mut found = vec![0.0; ids.len()];
            for (k, id) in ids.iter().enumerate() {
                if let Some(&i) = index.get(id) {
                    set[i] = true;
                    found[k] = f64::from(u8::from(i < g.n_owned));
                }
            }
            let found = g.red.max_each(&found);
            if let Some(k) = found.iter().position(|&x| x == 0.0) {
                return Err(format!("node {} is not in the mesh", ids[k]));
            }
            Ok(set)
        }
        Selector::Nearest(p) => {
            nearest_in_reach(p.0, g.bounds)?;
            // this process's nearest owned surface node, then the nearest of those (ties: the
            // lowest global index, as on the whole mesh)
            let on_surface = nearest_surface_flags(mesh);
            let mine = (0..g.n_owned)
                .filter(|&i| on_surface[i])
                .map(|i| (distance(mesh.points[i], p.0), g.gid[i]))
                .min_by(|a, b| a.0.partial_cmp(&b.0).unwrap().then(a.1.cmp(&b.1)));
            let all = g
                .red
                .all_gather_var(&mine.map(|(d, i)| vec![d, f64::from(i)]).unwrap_or_default());
            let best = all
                .chunks_exact(2)
                .map(|c| (c[0], c[1] as u32))
                .min_by(|a, b| a.0.partial_cmp(&b.0).unwrap().then(a.1.cmp(&b.1)))
                .ok_or("the mesh has no surface node")?;
            Ok(g.gid.iter().map(|&i| i == best.1).collect())
        }
        Selector::Tag(_) | Selector::Group(_) | Selector::Patch(_) => {
            Err(format!("internal: `{}` is not resolved on a local mesh", s.key()))
        }
    }
}

/// A point with its global index, as the gathers carry it.
fn gather_points(g: &Global, mine: Option<(u32, [f64; 3])>) -> Vec<(u32, [f64; 3])> {
    let v = mine
        .map(|(i, p)| vec![f64::from(i), p[0], p[1], p[2]])
        .unwrap_or_default();
    g.red
        .all_gather_var(&v)
        .chunks_exact(4)
        .map(|c| (c[0] as u32, [c[1], c[2], c[3]]))
        .collect()
}

/// `fixed::support_plane` of a set flagged on the local nodes: the same plane, its points
/// taken by reductions over the owned nodes.
fn support_plane(selector: &Selector, set: &[bool], mesh: &Mesh, g: &Global) -> Option<Plane> {
    let tol = g.tol();
    if let Some(p) = super::fixed::half_space_plane(selector, tol) {
        return Some(p);
    }
    let owned: Vec<usize> = (0..g.n_owned).filter(|&i| set[i]).collect();
    // the first point (lowest global index)
    let first = owned.iter().map(|&i| (g.gid[i], mesh.points[i])).min_by_key(|x| x.0);
    let a = gather_points(g, first).into_iter().min_by_key(|x| x.0)?.1;
    // the farthest by `from` (ties: the last, the highest global index, as `max_by`)
    let far = |from: &dyn Fn([f64; 3]) -> f64| -> [f64; 3] {
        let key = |x: &(u32, [f64; 3])| (from(x.1), x.0);
        let pick = |v: &mut dyn Iterator<Item = (u32, [f64; 3])>| {
            v.max_by(|p, q| key(p).0.total_cmp(&key(q).0).then(p.0.cmp(&q.0)))
        };
        let mine = pick(&mut owned.iter().map(|&i| (g.gid[i], mesh.points[i])));
        pick(&mut gather_points(g, mine).into_iter()).map_or(a, |x| x.1)
    };
    let pts = &mesh.points[..g.n_owned];
    super::fixed::plane_of_set(
        a,
        tol,
        &far,
        &|t| g.any(owned.iter().any(|&i| t(mesh.points[i]))),
        &|t| g.any(pts.iter().any(|&p| t(p))),
    )
}

/// `loads::resolve` on the local mesh: each load's contact nodes (global indices) and weights
/// gathered from their owners, summed in global order as on the whole mesh.
fn loads(sc: &Scenario, mesh: &Mesh, fixed: &[bool], g: &Global) -> Result<Vec<Load>> {
    let mut out = Vec::with_capacity(sc.file.load.len());
    for l in &sc.file.load {
        let s = &l.selector;
        let sel = s.get_ref();
        let at = |e: String| sc.error_at(s.span(), Push::TABLE, sel.key(), e);
        // per owned contact node: global index, weight, fixed, id (two halves)
        let (set, w): (Vec<bool>, Vec<f64>) = match sel {
            Selector::Patch(ball) => {
                let area = surface_node_areas(mesh);
                let set = (0..mesh.n_nodes())
                    .map(|i| area[i] > 0.0 && norm(sub(mesh.points[i], ball.center)) <= ball.radius)
                    .collect();
                (set, area)
            }
            _ => (nodes(sel, mesh, g).map_err(at)?, vec![1.0; mesh.n_nodes()]),
        };
        let mut mine = Vec::new();
        for i in (0..g.n_owned).filter(|&i| set[i]) {
            let id = mesh.node_ids[i];
            mine.extend([
                f64::from(g.gid[i]),
                w[i],
                f64::from(u8::from(fixed[i])),
                f64::from(id as u32),
                f64::from((id >> 32) as u32),
            ]);
        }
        let mut all: Vec<[f64; 5]> = g
            .red
            .all_gather_var(&mine)
            .chunks_exact(5)
            .map(|c| [c[0], c[1], c[2], c[3], c[4]])
            .collect();
        all.sort_by_key(|c| c[0] as u32);
        if all.is_empty() {
            if let Selector::Patch(ball) = sel {
                return Err(at(format!(
                    "no surface node within {} of [{}, {}, {}]; fix: move the center onto the surface or widen the radius (eprop info MESH gives the bounds)",
                    crate::diagnostics::short(ball.radius),
                    crate::diagnostics::short(ball.center[0]),
                    crate::diagnostics::short(ball.center[1]),
                    crate::diagnostics::short(ball.center[2])
                )));
            }
        }
        let id_of = |c: &[f64; 5]| u64::from(c[3] as u32) | (u64::from(c[4] as u32) << 32);
        if let Some(bad) = all.iter().find(|c| c[2] > 0.0) {
            return Err(at(format!(
                "the load's node {} is in the fixed set; fix: load free nodes or shrink the [[fixed]] set",
                id_of(bad)
            )));
        }
        let total: f64 = all.iter().map(|c| c[1]).sum();
        let p = &l.with;
        let history = match &p.table {
            Some(file) => {
                let base = sc.path.parent().unwrap_or(std::path::Path::new("."));
                let role = format!("force table of [[load]] {}", out.len() + 1);
                let h = super::tables::read_table(&base.join(file.get_ref()), &role, super::FORCE_COLUMNS)
                    .map_err(|e| sc.error_at(file.span(), Push::TABLE, "table", format!("{e:#}")))?;
                Some(h)
            }
            None => None,
        };
        out.push(Load {
            shares: Vec::new(),
            area_vector: [0.0; 3],
            history,
            live: p.live,
            depth: match sel {
                Selector::Patch(b) => Some(b.radius),
                _ => None,
            },
            node_ids: all.iter().map(id_of).collect(),
            nodes: all.iter().map(|c| c[0] as u32).collect(),
            weights: all.iter().map(|c| c[1] / total).collect(),
            force: p.force.unwrap_or([0.0; 3]),
            area: 0.0,
            ramp: p.ramp.clone(),
            normal: p.normal,
        });
    }
    Ok(out)
}

/// `fixed::every_piece_held` on the local meshes: each node's piece (`Global::pieces`), then
/// the pieces' sizes and fixed nodes summed over the processes.
fn every_piece_held(sc: &Scenario, mesh: &Mesh, fixed: &[bool], g: &Global) -> Result<()> {
    let label = g.pieces;
    // per piece (by its label) seen here: owned nodes, whether one is fixed, the label's id
    let mut pieces: std::collections::BTreeMap<u32, [f64; 5]> = Default::default();
    for i in 0..g.n_owned {
        let e = pieces.entry(label[i] as u32).or_insert([label[i], 0.0, 0.0, 0.0, 0.0]);
        e[1] += 1.0;
        e[2] = e[2].max(f64::from(u8::from(fixed[i])));
        if g.gid[i] == label[i] as u32 {
            let id = mesh.node_ids[i];
            (e[3], e[4]) = (f64::from(id as u32), f64::from((id >> 32) as u32));
        }
    }
    let mine: Vec<f64> = pieces.values().flatten().copied().collect();
    let all = g.red.all_gather_var(&mine);
    let mut total: std::collections::BTreeMap<u32, [f64; 5]> = Default::default();
    for c in all.chunks_exact(5) {
        let e = total.entry(c[0] as u32).or_insert([c[0], 0.0, 0.0, 0.0, 0.0]);
        e[1] += c[1];
        e[2] = e[2].max(c[2]);
        if c[3] != 0.0 || c[4] != 0.0 {
            (e[3], e[4]) = (c[3], c[4]);
        }
    }
    if total.len() <= 1 {
        return Ok(());
    }
    if let Some(q) = total.values().find(|e| e[2] == 0.0) {
        let id = u64::from(q[3] as u32) | (u64::from(q[4] as u32) << 32);
        return Err(anyhow!(
            "{}: the mesh has {} separate pieces and the one with node {} ({} nodes) holds no fixed node; \
             fix: add a [[fixed]] set on that piece (every piece needs its own)",
            sc.path.display(),
            total.len(),
            id,
            q[1] as usize
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use eprop_io::generate::{box_mesh, BoxCells};

    /// One process: every collective is the identity.
    struct One;

    impl Reduce for One {
        fn max(&self, x: f64) -> f64 {
            x
        }
        fn max_each(&self, x: &[f64]) -> Vec<f64> {
            x.to_vec()
        }
        fn all_gather_var(&self, x: &[f64]) -> Vec<f64> {
            x.to_vec()
        }
        fn exchange(&self, _: &mut [f64]) {}
    }

    #[test]
    fn a_local_resolution_of_the_whole_mesh_is_the_whole_resolution() {
        let text =
            "[mesh]\nfile = \"m.vtkhdf\"\n[[fixed]]\nhalfspace = { point = [0, 0, 0.01], normal = [0, 0, -1] }\n\
                    [[fixed]]\nbox = [[0.99, -1, -1], [2, 2, 2]]\n\
                    [[load]]\nnearest = [0.5, 0.5, 1.0]\nnormal = 1.0\n\
                    [[load]]\npatch = { center = [0.5, 0.0, 0.5], radius = 0.3 }\nforce = [0, 1, 0]\n\
                    [[load]]\nnode = 77\nforce = [1, 0, 0]\n\
                    [model]\nreading = \"paper\"\n[time]\nsteps = 1\n";
        let parse = || Scenario::parse(std::path::Path::new("s.toml"), text.into()).unwrap();
        let mesh = box_mesh([1.0; 3], [8, 7, 6], BoxCells::Tet).unwrap();
        let whole = Setup::with_mesh(parse(), mesh.clone()).unwrap();
        let deferred = Setup::deferred(parse()).unwrap();
        assert!(deferred.is_deferred());
        let gid: Vec<u32> = (0..mesh.n_nodes() as u32).collect();
        let pieces = piece_labels(&mesh, &gid, mesh.n_nodes(), &One);
        let g = Global {
            n_owned: mesh.n_nodes(),
            gid: &gid,
            n_nodes: mesh.n_nodes(),
            bounds: mesh.bounds(),
            red: &One,
            pieces: &pieces,
        };
        let local = deferred.resolve_local(mesh, &g).unwrap();
        assert!(!local.is_deferred());
        assert_eq!(local.fixed, whole.fixed);
        assert_eq!(local.supports, whole.supports);
        assert_eq!(whole.supports.len(), 2);
        assert_eq!(local.loads, whole.loads);
        assert_eq!(local.materials, whole.materials);
        assert_eq!(
            (local.tools, local.time, local.law),
            (whole.tools, whole.time, whole.law)
        );
    }
}
