//! Selectors: which nodes a `[[fixed]]` set, a `[[material.region]]` or a `[[load]]` applies to.
//!
//! One `Selector` type serves the three tables. Each table is an `Entry<X>`: exactly one
//! selector key, among those its kind `X` accepts, and the keys of its own (a region's
//! material, a load's force). A key of another kind, a second selector or none fail the parse
//! at their line with the list of what the table accepts.

use super::values::{Aabb, Ball, HalfSpace, Point};
use crate::diagnostics::short;
use eprop_io::geom::{dot, norm, sub};
use eprop_mesh::Mesh;
use serde::de::{self, DeserializeSeed, Deserializer, MapAccess, Visitor};
use serde::Deserialize;
use std::marker::PhantomData;
use toml::Spanned;

/// A set of nodes, by geometry, ids or tags.
#[derive(Clone, Debug, PartialEq)]
pub enum Selector {
    /// Nodes inside an axis-aligned box (boundary included).
    Box(Aabb),
    /// Nodes inside a ball.
    Sphere(Ball),
    /// Nodes on the side of a plane its normal points to (the plane included, within 1e-9 of
    /// the mesh's size).
    HalfSpace(HalfSpace),
    /// Nodes by their ids in the mesh file.
    Nodes(Vec<u64>),
    /// Nodes of the cells and facets with a physical tag.
    Tag(i32),
    /// Nodes of a named physical group.
    Group(String),
    /// One node by its id in the mesh file.
    Node(u64),
    /// The surface node nearest to a point.
    Nearest(Point),
    /// The surface nodes within a ball (a contact patch).
    Patch(Ball),
}

impl Selector {
    /// Every selector key, in the order messages list them.
    pub const KEYS: [&'static str; 9] = [
        "box",
        "sphere",
        "halfspace",
        "nodes",
        "tag",
        "group",
        "node",
        "nearest",
        "patch",
    ];

    /// The scenario key of this selector.
    pub fn key(&self) -> &'static str {
        match self {
            Selector::Box(_) => "box",
            Selector::Sphere(_) => "sphere",
            Selector::HalfSpace(_) => "halfspace",
            Selector::Nodes(_) => "nodes",
            Selector::Tag(_) => "tag",
            Selector::Group(_) => "group",
            Selector::Node(_) => "node",
            Selector::Nearest(_) => "nearest",
            Selector::Patch(_) => "patch",
        }
    }

    /// How a key is written, for messages.
    fn usage(key: &str) -> &'static str {
        match key {
            "box" => "`box = [[x0, y0, z0], [x1, y1, z1]]`",
            "sphere" => "`sphere = { center = [x, y, z], radius = R }`",
            "halfspace" => "`halfspace = { point = [x, y, z], normal = [nx, ny, nz] }`",
            "nodes" => "`nodes = [id, ...]`",
            "tag" => "`tag = N`",
            "group" => "`group = \"name\"`",
            "node" => "`node = ID`",
            "nearest" => "`nearest = [x, y, z]`",
            _ => "`patch = { center = [x, y, z], radius = R }`",
        }
    }

    /// Reads the value of selector `key` (with its place in the file).
    fn read<'de, A: MapAccess<'de>>(key: &str, map: &mut A) -> Result<Spanned<Selector>, A::Error> {
        fn at<T, U>(s: Spanned<T>, f: impl FnOnce(T) -> U) -> Spanned<U> {
            let span = s.span();
            Spanned::new(span, f(s.into_inner()))
        }
        Ok(match key {
            "box" => at(map.next_value()?, Selector::Box),
            "sphere" => at(map.next_value()?, Selector::Sphere),
            "halfspace" => at(map.next_value()?, Selector::HalfSpace),
            "nodes" => at(map.next_value()?, Selector::Nodes),
            "tag" => at(map.next_value()?, Selector::Tag),
            "group" => at(map.next_value()?, Selector::Group),
            "node" => at(map.next_value()?, Selector::Node),
            "nearest" => at(map.next_value()?, Selector::Nearest),
            "patch" => at(map.next_value()?, Selector::Patch),
            _ => return Err(de::Error::custom(format!("internal: `{key}` is not a selector"))),
        })
    }

    /// The selected nodes of `mesh` (a flag per node), or what is wrong with the selector on
    /// this mesh.
    pub fn nodes(&self, mesh: &Mesh) -> Result<Vec<bool>, String> {
        let n = mesh.n_nodes();
        let mut set = vec![false; n];
        match self {
            Selector::Box(b) => {
                for (i, p) in mesh.points.iter().enumerate() {
                    set[i] = (0..3).all(|d| p[d] >= b.min[d] && p[d] <= b.max[d]);
                }
            }
            Selector::Sphere(s) => {
                for (i, p) in mesh.points.iter().enumerate() {
                    set[i] = norm(sub(*p, s.center)) <= s.radius;
                }
            }
            Selector::HalfSpace(h) => {
                let nn = norm(h.normal);
                let (lo, hi) = mesh.bounds();
                let tol = 1e-9 * norm(sub(hi, lo));
                for (i, p) in mesh.points.iter().enumerate() {
                    set[i] = dot(sub(*p, h.point), h.normal) / nn >= -tol;
                }
            }
            Selector::Nodes(ids) => {
                let index: std::collections::HashMap<u64, usize> =
                    mesh.node_ids.iter().enumerate().map(|(i, &id)| (id, i)).collect();
                for id in ids {
                    match index.get(id) {
                        Some(&i) => set[i] = true,
                        None => return Err(format!("node {id} is not in the mesh")),
                    }
                }
            }
            Selector::Tag(t) => {
                mark_tags(mesh, &[(None, *t)], &mut set);
                if !set.contains(&true) {
                    return Err(format!(
                        "no cell or facet of {} carries tag {t}; its tags: {}; fix: name one of those (`eprop info MESH` lists them with their cells and volumes)",
                        mesh.source,
                        tag_list(mesh)
                    ));
                }
            }
            Selector::Group(name) => {
                let found: Vec<(Option<u8>, i32)> = mesh
                    .group_names
                    .iter()
                    .filter(|(_, v)| *v == name)
                    .map(|((d, t), _)| (Some(*d), *t))
                    .collect();
                if found.is_empty() {
                    let known: Vec<&str> = mesh.group_names.values().map(|s| s.as_str()).collect();
                    return Err(format!(
                        "no physical group `{name}` in {}; known groups: {:?}; fix: name one of those, or select by `tag = N`, `box`, `sphere` or `halfspace` (.vtu, .vtk and TetGen files carry tags but no group names)",
                        mesh.source, known
                    ));
                }
                mark_tags(mesh, &found, &mut set);
            }
            Selector::Node(id) => match mesh.node_ids.iter().position(|x| x == id) {
                Some(i) => set[i] = true,
                None => {
                    return Err(format!(
                        "node {id} is not in the mesh; fix: use a node id of the mesh file"
                    ))
                }
            },
            Selector::Nearest(p) => {
                nearest_in_reach(p.0, mesh.bounds())?;
                let i = nearest_surface_node(mesh, p.0).ok_or("the mesh has no surface node")?;
                set[i as usize] = true;
            }
            Selector::Patch(ball) => {
                let area = surface_node_areas(mesh);
                patch(mesh, ball, &area, &mut set)?;
            }
        }
        Ok(set)
    }

    /// The contact nodes of a load (increasing index) and their weights (summing to 1): a
    /// patch's nodes weighted by their boundary dual areas, otherwise equal weights.
    pub fn contacts(&self, mesh: &Mesh) -> Result<(Vec<u32>, Vec<f64>), String> {
        let area = match self {
            Selector::Patch(ball) => {
                let area = surface_node_areas(mesh);
                let mut set = vec![false; mesh.n_nodes()];
                patch(mesh, ball, &area, &mut set)?;
                return Ok(weighted(&set, |i| area[i]));
            }
            _ => self.nodes(mesh)?,
        };
        Ok(weighted(&area, |_| 1.0))
    }
}

/// The flagged nodes and their weights `w(i) / sum w`.
fn weighted(set: &[bool], w: impl Fn(usize) -> f64) -> (Vec<u32>, Vec<f64>) {
    let picked: Vec<u32> = (0..set.len()).filter(|&i| set[i]).map(|i| i as u32).collect();
    let total: f64 = picked.iter().map(|&i| w(i as usize)).sum();
    let weights = picked.iter().map(|&i| w(i as usize) / total).collect();
    (picked, weights)
}

/// A contact patch's share of the boundary surface, smooth in the mesh (docs/model.md
/// section 4): the disc `ball` cuts out of the surface, integrated over every boundary face
/// by sub-sampling (each triangle split into n^2 sub-triangles of equal area, n such that a
/// sub-triangle is at most 1/16 of the radius across) and shared to the face's corners by
/// their linear shape functions. Returns the nodes with a share (increasing index), their
/// shares a_i (summing to the patch area) and the patch's outward area vector. A disc that no
/// sample falls in (far smaller than its faces) takes the surface nodes within it with their
/// boundary dual areas; none is an error.
pub(crate) fn patch_shares(mesh: &Mesh, ball: &Ball) -> Result<(Vec<u32>, Vec<f64>, [f64; 3]), String> {
    let mut share = vec![0.0; mesh.n_nodes()];
    let mut vector = [0.0; 3];
    let (c, r) = (ball.center, ball.radius);
    for (cell, f) in eprop_io::mesh::boundary_faces(mesh) {
        let nodes = mesh.cell(cell as usize);
        let face = mesh.kinds[cell as usize].faces()[f as usize];
        let ids: Vec<u32> = face.iter().map(|&l| nodes[l]).collect();
        // triangles (0, k, k+1): a quadrilateral in two
        for k in 1..ids.len() - 1 {
            let tri = [ids[0], ids[k], ids[k + 1]];
            let p = tri.map(|i| mesh.points[i as usize]);
            let mid = [0, 1, 2].map(|d| (p[0][d] + p[1][d] + p[2][d]) / 3.0);
            let reach = p.iter().map(|q| norm(sub(*q, mid))).fold(0.0f64, f64::max);
            if norm(sub(mid, c)) > r + reach {
                continue;
            }
            let av = eprop_io::geom::loop_area(&p);
            let a = norm(av);
            let n = ((16.0 * 2.0 * reach / r).ceil() as usize).clamp(4, 256);
            let w = 1.0 / (n * n) as f64;
            let e1 = sub(p[1], p[0]);
            let e2 = sub(p[2], p[0]);
            let nf = n as f64;
            let mut sample = |s: f64, t: f64| {
                let x = [0, 1, 2].map(|d| p[0][d] + s * e1[d] + t * e2[d]);
                if norm(sub(x, c)) <= r {
                    for (v, nv) in tri.iter().zip([1.0 - s - t, s, t]) {
                        share[*v as usize] += a * w * nv;
                    }
                    for d in 0..3 {
                        vector[d] += av[d] * w;
                    }
                }
            };
            for i in 0..n {
                for j in 0..n - i {
                    let (fi, fj) = (i as f64, j as f64);
                    sample((fi + 1.0 / 3.0) / nf, (fj + 1.0 / 3.0) / nf);
                    if i + j + 2 <= n {
                        sample((fi + 2.0 / 3.0) / nf, (fj + 2.0 / 3.0) / nf);
                    }
                }
            }
        }
    }
    let mut nodes: Vec<u32> = (0..share.len()).filter(|&i| share[i] > 0.0).map(|i| i as u32).collect();
    if nodes.is_empty() {
        // a disc far smaller than the faces it lies on (no sample inside it): the surface
        // nodes within it, with their boundary dual areas, as the paper reading's patch
        let area = surface_node_areas(mesh);
        let mut set = vec![false; mesh.n_nodes()];
        patch(mesh, ball, &area, &mut set)?;
        for (cell, f) in eprop_io::mesh::boundary_faces(mesh) {
            let cn = mesh.cell(cell as usize);
            let face = mesh.kinds[cell as usize].faces()[f as usize];
            let pts: Vec<[f64; 3]> = face.iter().map(|&l| mesh.points[cn[l] as usize]).collect();
            let av = eprop_io::geom::loop_area(&pts);
            for &l in face {
                if set[cn[l] as usize] {
                    for d in 0..3 {
                        vector[d] += av[d] / face.len() as f64;
                    }
                }
            }
        }
        nodes = (0..set.len()).filter(|&i| set[i]).map(|i| i as u32).collect();
        for &i in &nodes {
            share[i as usize] = area[i as usize];
        }
    }
    let shares = nodes.iter().map(|&i| share[i as usize]).collect();
    Ok((nodes, shares, vector))
}

/// Flags the surface nodes within `ball` (surface: a positive boundary dual area).
fn patch(mesh: &Mesh, ball: &Ball, area: &[f64], set: &mut [bool]) -> Result<(), String> {
    let mut any = false;
    for i in 0..mesh.n_nodes() {
        set[i] = area[i] > 0.0 && norm(sub(mesh.points[i], ball.center)) <= ball.radius;
        any |= set[i];
    }
    if !any {
        return Err(format!(
            "no surface node within {} of [{}, {}, {}]; fix: move the center onto the surface or widen the radius (eprop info MESH gives the bounds)",
            short(ball.radius),
            short(ball.center[0]),
            short(ball.center[1]),
            short(ball.center[2])
        ));
    }
    Ok(())
}

/// The tags a mesh carries, for a message: "cells 1 (n), 2 (n); facets 5 (n)" (or "none").
pub fn tag_list(mesh: &Mesh) -> String {
    let count = |tags: &[i32]| {
        let mut m = std::collections::BTreeMap::<i32, usize>::new();
        for &t in tags {
            *m.entry(t).or_default() += 1;
        }
        m.iter()
            .map(|(t, n)| format!("{t} ({n})"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let mut parts = vec![];
    if mesh.n_cells() > 0 {
        parts.push(format!("cells {}", count(&mesh.cell_tags)));
    }
    if !mesh.facets.is_empty() {
        parts.push(format!("facets {}", count(&mesh.facets.tags)));
    }
    if parts.is_empty() {
        "none".to_string()
    } else {
        parts.join("; ")
    }
}

/// Flags the nodes of the cells and facets with one of `tags`: (dimension, tag), any
/// dimension when None (volume cells count as dimension 3).
fn mark_tags(mesh: &Mesh, tags: &[(Option<u8>, i32)], set: &mut [bool]) {
    for &(dim, t) in tags {
        if dim.is_none() || dim == Some(3) {
            for c in 0..mesh.n_cells() {
                if mesh.cell_tags[c] == t {
                    for &v in mesh.cell(c) {
                        set[v as usize] = true;
                    }
                }
            }
        }
        for f in 0..mesh.facets.len() {
            if mesh.facets.tags[f] == t && dim.is_none_or(|d| d == mesh.facets.dim[f]) {
                for &v in mesh.facets.nodes(f) {
                    set[v as usize] = true;
                }
            }
        }
    }
}

/// The boundary dual area of every node: each boundary face's area shared equally by its
/// corners (exact for the median dual of triangles; quadrilaterals are split evenly).
pub(crate) fn surface_node_areas(mesh: &Mesh) -> Vec<f64> {
    let mut area = vec![0.0; mesh.n_nodes()];
    for (c, f) in eprop_io::mesh::boundary_faces(mesh) {
        let cell = mesh.cell(c as usize);
        let face = mesh.kinds[c as usize].faces()[f as usize];
        let pts: Vec<[f64; 3]> = face.iter().map(|&l| mesh.points[cell[l] as usize]).collect();
        let a = norm(eprop_io::geom::loop_area(&pts)) / face.len() as f64;
        for &l in face {
            area[cell[l] as usize] += a;
        }
    }
    area
}

/// A `nearest` point farther than this multiple of the mesh's extent from its centre is
/// refused.
pub(crate) const NEAREST_FAR: f64 = 1e6;

/// Refuses a `nearest` point farther than `NEAREST_FAR` extents from the centre of the mesh
/// of bounds (lo, hi): from far enough away every node is equally far in floating point, and
/// the choice would be the lowest index.
pub(crate) fn nearest_in_reach(p: [f64; 3], (lo, hi): ([f64; 3], [f64; 3])) -> Result<(), String> {
    let extent = distance(hi, lo);
    let centre = [0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), 0.5 * (lo[2] + hi[2])];
    let far = distance(p, centre);
    if !(far <= NEAREST_FAR * extent.max(f64::MIN_POSITIVE)) {
        return Err(format!(
            "[{:e}, {:e}, {:e}] is {far:.4e} from the centre of the mesh, more than {NEAREST_FAR:e} times its extent {extent:.4e}, so no node is nearer than another; fix: give a point on the surface of the mesh",
            p[0], p[1], p[2]
        ));
    }
    Ok(())
}

/// |a - b| without overflow where |a - b| itself is finite (the difference is scaled by its
/// largest component first: a point 1e150 away is 1e150 away, not inf).
pub fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    let d = sub(a, b);
    let m = d.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    if m == 0.0 || !m.is_finite() {
        return m;
    }
    m * norm([d[0] / m, d[1] / m, d[2] / m])
}

/// Whether each node is on a boundary face of the volume cells (`nearest`'s surface).
pub(crate) fn nearest_surface_flags(mesh: &Mesh) -> Vec<bool> {
    let mut on_surface = vec![false; mesh.n_nodes()];
    for (c, f) in eprop_io::mesh::boundary_faces(mesh) {
        let cell = mesh.cell(c as usize);
        for &l in mesh.kinds[c as usize].faces()[f as usize].iter() {
            on_surface[cell[l] as usize] = true;
        }
    }
    on_surface
}

/// The surface node nearest to a point (surface = on a boundary face of the volume cells;
/// ties: the lowest index).
pub(crate) fn nearest_surface_node(mesh: &Mesh, p: [f64; 3]) -> Option<u32> {
    let on_surface = nearest_surface_flags(mesh);
    (0..mesh.n_nodes())
        .filter(|&i| on_surface[i])
        .min_by(|&a, &b| {
            let da = distance(mesh.points[a], p);
            let db = distance(mesh.points[b], p);
            da.partial_cmp(&db).unwrap().then(a.cmp(&b))
        })
        .map(|i| i as u32)
}

/// A kind of selecting table: the selectors it accepts and the keys of its own.
pub trait Keys: Default + Clone {
    /// The table's name as the scenario writes it (`fixed`, `material.region`, `load`).
    const TABLE: &'static str;
    /// What its selector chooses, for messages ("a fixed set").
    const CHOOSES: &'static str;
    /// The selector keys it accepts (some of `Selector::KEYS`).
    const SELECTORS: &'static [&'static str];
    /// Its own keys.
    const OWN: &'static [&'static str];
    /// Reads the value of one of its own keys.
    fn read<'de, A: MapAccess<'de>>(&mut self, key: &str, map: &mut A) -> Result<(), A::Error>;
    /// Checks the own keys together once the table is read.
    fn finish(&self) -> Result<(), String> {
        Ok(())
    }
}

/// One selecting table: its selector (with its place in the file) and its own keys.
#[derive(Clone, Debug)]
pub struct Entry<X> {
    pub selector: Spanned<Selector>,
    pub with: X,
}

/// `"a", "b" or "c"` from a list of words.
pub fn either(words: &[&str], quote: &str) -> String {
    let q: Vec<String> = words.iter().map(|w| format!("{quote}{w}{quote}")).collect();
    match q.split_last() {
        Some((last, rest)) if !rest.is_empty() => format!("{} or {last}", rest.join(", ")),
        Some((last, _)) => last.clone(),
        None => String::new(),
    }
}

/// Reads a key of an `Entry<X>`: one of its selectors or own keys, else an error at the key.
struct KeySeed<X>(PhantomData<X>);

impl<'de, X: Keys> DeserializeSeed<'de> for KeySeed<X> {
    type Value = &'static str;
    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<&'static str, D::Error> {
        d.deserialize_str(self)
    }
}

impl<'de, X: Keys> Visitor<'de> for KeySeed<X> {
    type Value = &'static str;
    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        write!(f, "a key of [[{}]]", X::TABLE)
    }
    fn visit_str<E: de::Error>(self, key: &str) -> Result<&'static str, E> {
        if let Some(k) = X::SELECTORS.iter().chain(X::OWN).find(|k| **k == key) {
            return Ok(k);
        }
        if Selector::KEYS.contains(&key) {
            return Err(E::custom(format!(
                "`{key}` does not select {}; fix: use {}",
                X::CHOOSES,
                either(X::SELECTORS, "`")
            )));
        }
        let all: Vec<&str> = X::SELECTORS.iter().chain(X::OWN).copied().collect();
        Err(E::custom(format!(
            "unknown field `{key}`, expected one of {}",
            either(&all, "`")
        )))
    }
}

impl<'de, X: Keys> Deserialize<'de> for Entry<X> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_map(EntryVisitor(PhantomData))
    }
}

struct EntryVisitor<X>(PhantomData<X>);

impl<'de, X: Keys> Visitor<'de> for EntryVisitor<X> {
    type Value = Entry<X>;
    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        write!(f, "a [[{}]] table", X::TABLE)
    }
    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Entry<X>, A::Error> {
        let mut selectors: Vec<Spanned<Selector>> = Vec::new();
        let mut with = X::default();
        while let Some(key) = map.next_key_seed(KeySeed::<X>(PhantomData))? {
            if Selector::KEYS.contains(&key) {
                selectors.push(Selector::read(key, &mut map)?);
            } else {
                with.read(key, &mut map)?;
            }
        }
        if selectors.len() > 1 {
            let keys: Vec<&str> = selectors.iter().map(|s| s.get_ref().key()).collect();
            return Err(de::Error::custom(format!(
                "{} select the same table; fix: keep one of them",
                either(&keys, "`").replace(" or ", " and ")
            )));
        }
        let Some(selector) = selectors.pop() else {
            let usage: Vec<&str> = X::SELECTORS.iter().map(|k| Selector::usage(k)).collect();
            return Err(de::Error::custom(format!(
                "no selector; fix: give one of {}",
                either(&usage, "")
            )));
        };
        with.finish().map_err(de::Error::custom)?;
        Ok(Entry { selector, with })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use eprop_io::generate::{box_mesh, BoxCells};

    #[derive(Clone, Debug, Default)]
    struct Weight(Option<f64>);

    impl Keys for Weight {
        const TABLE: &'static str = "thing";
        const CHOOSES: &'static str = "a thing";
        const SELECTORS: &'static [&'static str] = &["box", "tag", "nearest"];
        const OWN: &'static [&'static str] = &["weight"];
        fn read<'de, A: MapAccess<'de>>(&mut self, _: &str, map: &mut A) -> Result<(), A::Error> {
            self.0 = Some(map.next_value()?);
            Ok(())
        }
        fn finish(&self) -> Result<(), String> {
            match self.0 {
                Some(w) if w < 0.0 => Err("weight must not be negative".into()),
                _ => Ok(()),
            }
        }
    }

    #[derive(Deserialize, Debug)]
    #[allow(dead_code)]
    struct File {
        thing: Vec<Entry<Weight>>,
    }

    fn entry(body: &str) -> Result<Entry<Weight>, String> {
        toml::from_str::<File>(&format!("[[thing]]\n{body}"))
            .map(|mut f| f.thing.remove(0))
            .map_err(|e| e.message().to_string())
    }

    #[test]
    fn a_table_takes_one_selector_of_its_kind_and_its_own_keys() {
        let text = "[[thing]]\nweight = 2.0\nbox = [[0, 0, 0], [1, 1, 1]]\n";
        let e = toml::from_str::<File>(text).unwrap().thing.remove(0);
        assert_eq!(e.with.0, Some(2.0));
        assert_eq!(e.selector.get_ref().key(), "box");
        assert_eq!(&text[e.selector.span()], "[[0, 0, 0], [1, 1, 1]]");
        assert!(matches!(
            entry("tag = 3").unwrap().selector.into_inner(),
            Selector::Tag(3)
        ));

        let none = entry("weight = 1.0").unwrap_err();
        assert_eq!(
            none,
            "no selector; fix: give one of `box = [[x0, y0, z0], [x1, y1, z1]]`, `tag = N` or `nearest = [x, y, z]`"
        );
        let two = entry("tag = 1\nbox = [[0, 0, 0], [1, 1, 1]]").unwrap_err();
        assert!(two.contains("`tag` and `box`") && two.contains("keep one"), "{two}");
        let other = entry("sphere = { center = [0, 0, 0], radius = 1 }").unwrap_err();
        assert!(
            other.contains("`sphere` does not select a thing") && other.contains("`box`, `tag` or `nearest`"),
            "{other}"
        );
        let unknown = entry("tag = 1\ncolour = 2").unwrap_err();
        assert!(
            unknown.contains("unknown field `colour`") && unknown.contains("`weight`"),
            "{unknown}"
        );
        assert!(entry("tag = 1\nweight = -1.0").unwrap_err().contains("negative"));
        assert!(entry("box = [[1, 0, 0], [0, 1, 1]]")
            .unwrap_err()
            .contains("min <= max"));
    }

    #[test]
    fn selectors_pick_nodes_of_a_mesh() {
        // 3 x 3 x 3 nodes on the unit box, spacing 0.5; faces tagged xmin, xmax, ...
        let m = box_mesh([1.0; 3], [2; 3], BoxCells::Hex).unwrap();
        let count = |s: Selector| s.nodes(&m).map(|v| v.iter().filter(|&&b| b).count());
        let ball = |c: [f64; 3], r: f64| Ball { center: c, radius: r };
        let aabb = Aabb {
            min: [0.0; 3],
            max: [0.5, 1.0, 1.0],
        };
        assert_eq!(count(Selector::Box(aabb)), Ok(18));
        assert_eq!(count(Selector::Sphere(ball([0.0; 3], 0.6))), Ok(4));
        let h = HalfSpace {
            point: [0.0, 0.0, 0.5],
            normal: [0.0, 0.0, 2.0],
        };
        assert_eq!(count(Selector::HalfSpace(h)), Ok(18));
        assert_eq!(count(Selector::Nodes(vec![1, 27])), Ok(2));
        assert!(count(Selector::Nodes(vec![99]))
            .unwrap_err()
            .contains("node 99 is not in the mesh"));
        assert_eq!(count(Selector::Group("xmin".into())), Ok(9));
        let e = count(Selector::Group("nowhere".into())).unwrap_err();
        assert!(e.contains("known groups") && e.contains("xmax"), "{e}");
        assert_eq!(count(Selector::Node(14)), Ok(1));
        assert!(count(Selector::Node(0)).unwrap_err().contains("fix:"));
        // a tag no cell or facet carries names the tags there are
        let tags = tag_list(&m);
        assert!(tags.starts_with("cells ") && tags.contains("; facets "), "{tags}");
        let e = count(Selector::Tag(99)).unwrap_err();
        assert!(
            e.contains("carries tag 99; its tags: cells ") && e.contains("fix:"),
            "{e}"
        );
        // the centre node (0.5, 0.5, 0.5) is interior: the nearest surface node is another
        let near = Selector::Nearest(Point([0.5, 0.5, 0.45])).nodes(&m).unwrap();
        let i = near.iter().position(|&b| b).unwrap();
        assert_eq!(m.points[i], [0.5, 0.5, 0.0]);
        // a patch on the face z = 0 around its centre: the centre and its 4 edge neighbours
        let (nodes, w) = Selector::Patch(ball([0.5, 0.5, 0.0], 0.5)).contacts(&m).unwrap();
        assert_eq!(nodes.len(), 5);
        assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-15);
        // boundary dual areas: the centre has 4 quarter faces, an edge midpoint 2 on each of
        // two faces, so all five carry the same share
        assert!(w.iter().all(|&x| (x - 0.2).abs() < 1e-15), "{w:?}");
        assert!(Selector::Patch(ball([5.0; 3], 0.1))
            .contacts(&m)
            .unwrap_err()
            .contains("no surface node"));
        // equal weights elsewhere
        let (nodes, w) = Selector::Node(14).contacts(&m).unwrap();
        assert_eq!((nodes.len(), w), (1, vec![1.0]));
    }
}
