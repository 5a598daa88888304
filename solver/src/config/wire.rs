//! Serde forms of what a `Setup` (a process's part) carries and serde cannot derive by itself:
//! the mesh (a type of `eprop_io`, sent as a mirror of the fields a part needs) and file paths
//! (as their bytes, so a path that is not UTF-8 arrives unchanged). Used with
//! `#[serde(with = "crate::config::wire::...")]`; `distribute::parts` encodes the whole with
//! postcard.

use eprop_io::CellKind;

/// A stable code per cell kind (the mesh hash and the wire use it).
pub(crate) fn kind_code(k: CellKind) -> u8 {
    match k {
        CellKind::Tet => 0,
        CellKind::Hex => 1,
        CellKind::Wedge => 2,
        CellKind::Pyramid => 3,
    }
}

fn kind_of(c: u8) -> Option<CellKind> {
    Some(match c {
        0 => CellKind::Tet,
        1 => CellKind::Hex,
        2 => CellKind::Wedge,
        3 => CellKind::Pyramid,
        _ => return None,
    })
}

/// A mesh as a part sends it: source, points, node ids, cells with their tags, warnings
/// (the facets and group names stay on rank 0, which resolved the selectors).
pub mod mesh {
    use super::{kind_code, kind_of};
    use eprop_mesh::{CellKind, Mesh};
    use serde::de::Error;
    use serde::ser::Serializer;
    use serde::{Deserialize, Deserializer, Serialize};

    #[derive(Serialize)]
    struct Borrowed<'a> {
        source: &'a str,
        points: &'a [[f64; 3]],
        node_ids: &'a [u64],
        kinds: Kinds<'a>,
        conn: &'a [u32],
        cell_tags: &'a [i32],
        warnings: &'a [String],
    }

    struct Kinds<'a>(&'a [CellKind]);

    impl Serialize for Kinds<'_> {
        fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
            s.collect_seq(self.0.iter().map(|&k| kind_code(k)))
        }
    }

    #[derive(Deserialize)]
    struct Owned {
        source: String,
        points: Vec<[f64; 3]>,
        node_ids: Vec<u64>,
        kinds: Vec<u8>,
        conn: Vec<u32>,
        cell_tags: Vec<i32>,
        warnings: Vec<String>,
    }

    pub fn serialize<S: Serializer>(m: &Mesh, s: S) -> Result<S::Ok, S::Error> {
        Borrowed {
            source: &m.source,
            points: &m.points,
            node_ids: &m.node_ids,
            kinds: Kinds(&m.kinds),
            conn: &m.conn,
            cell_tags: &m.cell_tags,
            warnings: &m.warnings,
        }
        .serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Mesh, D::Error> {
        let w = Owned::deserialize(d)?;
        let mut m = Mesh::new(w.source);
        m.points = w.points;
        m.node_ids = w.node_ids;
        m.warnings = w.warnings;
        if w.kinds.len() != w.cell_tags.len() {
            return Err(D::Error::custom("cells and cell tags differ in number"));
        }
        let mut at = 0;
        for (&k, &t) in w.kinds.iter().zip(&w.cell_tags) {
            let kind = kind_of(k).ok_or_else(|| D::Error::custom(format!("unknown cell kind {k}")))?;
            let nodes = w
                .conn
                .get(at..at + kind.n_nodes())
                .ok_or_else(|| D::Error::custom("cells do not match their connectivity"))?;
            m.push_cell(kind, nodes, t);
            at += kind.n_nodes();
        }
        Ok(m)
    }
}

/// A path as its bytes.
pub mod path {
    use serde::{Deserialize, Deserializer, Serialize, Serializer};
    use std::os::unix::ffi::{OsStrExt, OsStringExt};
    use std::path::{Path, PathBuf};

    pub fn serialize<S: Serializer>(p: &Path, s: S) -> Result<S::Ok, S::Error> {
        p.as_os_str().as_bytes().serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<PathBuf, D::Error> {
        Vec::<u8>::deserialize(d).map(|b| PathBuf::from(std::ffi::OsString::from_vec(b)))
    }
}
