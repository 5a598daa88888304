//! VTK XML UnstructuredGrid (`.vtu`) reader and writer (own code; base64 and zlib by crates).
//!
//! Reads every encoding VTK and meshio write: `ascii`, inline `binary` (base64, with a UInt32 or
//! UInt64 header, optionally zlib-compressed in blocks), and `appended` data (raw or base64),
//! little or big endian. Cell-data arrays with integer values become cell tags (preferred names:
//! tissue, tag, gmsh:physical, CellEntityIds, label, region, material). Surface and line cells
//! are kept as facets with their tags; higher-order or unknown volume cells are refused.

use crate::mesh::{CellKind, Mesh};
use anyhow::{anyhow, bail, Result};
use base64::Engine;
use std::collections::HashMap;
use std::io::Read;
use std::path::Path;

pub fn read(path: &Path) -> Result<Mesh> {
    let bytes = std::fs::read(path).map_err(|e| anyhow!("{}: cannot read: {e}", path.display()))?;
    parse(&path.display().to_string(), &bytes)
}

/// A tag with its attributes and the byte range of its content.
struct Tag {
    name: String,
    attrs: HashMap<String, String>,
    content: std::ops::Range<usize>,
    line: usize,
}

fn line_of(b: &[u8], at: usize) -> usize {
    b[..at.min(b.len())].iter().filter(|&&c| c == b'\n').count() + 1
}

/// Scans the XML up to `<AppendedData` (raw bytes may follow): every element with its
/// attributes and text content (up to the next `<`).
fn scan(name: &str, b: &[u8]) -> Result<(Vec<Tag>, Option<(usize, HashMap<String, String>)>)> {
    let mut tags = Vec::new();
    let mut i = 0;
    while let Some(off) = b[i..].iter().position(|&c| c == b'<') {
        let start = i + off;
        let rest = &b[start + 1..];
        if rest.starts_with(b"?") || rest.starts_with(b"!") || rest.starts_with(b"/") {
            // declaration, comment or closing tag
            let end = if rest.starts_with(b"!--") {
                find(b, start, b"-->").map(|e| e + 3)
            } else {
                find(b, start, b">").map(|e| e + 1)
            };
            i = end.ok_or_else(|| {
                anyhow!(
                    "{name}:{}: unterminated markup; fix: the file is truncated",
                    line_of(b, start)
                )
            })?;
            continue;
        }
        let close = find(b, start, b">").ok_or_else(|| {
            anyhow!(
                "{name}:{}: unterminated tag; fix: the file is truncated",
                line_of(b, start)
            )
        })?;
        let inner = std::str::from_utf8(&b[start + 1..close])
            .map_err(|_| anyhow!("{name}:{}: a tag is not UTF-8", line_of(b, start)))?;
        let inner = inner.trim_end_matches('/');
        let mut parts = inner.splitn(2, char::is_whitespace);
        let tname = parts.next().unwrap_or("").to_string();
        let attrs = parse_attrs(parts.next().unwrap_or(""));
        if tname == "AppendedData" {
            return Ok((tags, Some((close + 1, attrs))));
        }
        let cend = b[close + 1..]
            .iter()
            .position(|&c| c == b'<')
            .map_or(b.len(), |p| close + 1 + p);
        tags.push(Tag {
            name: tname,
            attrs,
            content: close + 1..cend,
            line: line_of(b, start),
        });
        i = close + 1;
    }
    Ok((tags, None))
}

fn find(b: &[u8], from: usize, pat: &[u8]) -> Option<usize> {
    b[from..].windows(pat.len()).position(|w| w == pat).map(|p| from + p)
}

fn parse_attrs(s: &str) -> HashMap<String, String> {
    let mut m = HashMap::new();
    let mut rest = s;
    while let Some(eq) = rest.find('=') {
        let key = rest[..eq].trim().to_string();
        let after = rest[eq + 1..].trim_start();
        let Some(q) = after.chars().next().filter(|c| *c == '"' || *c == '\'') else {
            break;
        };
        let Some(end) = after[1..].find(q) else { break };
        m.insert(key, after[1..1 + end].to_string());
        rest = &after[end + 2..];
    }
    m
}

#[derive(Clone, Copy, PartialEq)]
enum Ty {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    I64,
    U64,
    F32,
    F64,
}

impl Ty {
    fn of(s: &str) -> Option<Ty> {
        Some(match s {
            "Int8" => Ty::I8,
            "UInt8" => Ty::U8,
            "Int16" => Ty::I16,
            "UInt16" => Ty::U16,
            "Int32" => Ty::I32,
            "UInt32" => Ty::U32,
            "Int64" => Ty::I64,
            "UInt64" => Ty::U64,
            "Float32" => Ty::F32,
            "Float64" => Ty::F64,
            _ => return None,
        })
    }
    fn size(self) -> usize {
        match self {
            Ty::I8 | Ty::U8 => 1,
            Ty::I16 | Ty::U16 => 2,
            Ty::I32 | Ty::U32 | Ty::F32 => 4,
            _ => 8,
        }
    }
    fn is_int(self) -> bool {
        !matches!(self, Ty::F32 | Ty::F64)
    }
}

/// Decodes raw bytes of `ty` into f64 (integers up to 2^53 are exact).
fn decode(ty: Ty, raw: &[u8], big: bool) -> Vec<f64> {
    let n = ty.size();
    raw.chunks_exact(n)
        .map(|c| {
            let mut b = [0u8; 8];
            b[..n].copy_from_slice(c);
            if big {
                b[..n].reverse();
            }
            match ty {
                Ty::I8 => b[0] as i8 as f64,
                Ty::U8 => b[0] as f64,
                Ty::I16 => i16::from_le_bytes([b[0], b[1]]) as f64,
                Ty::U16 => u16::from_le_bytes([b[0], b[1]]) as f64,
                Ty::I32 => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
                Ty::U32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
                Ty::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
                Ty::I64 => i64::from_le_bytes(b) as f64,
                Ty::U64 => u64::from_le_bytes(b) as f64,
                Ty::F64 => f64::from_le_bytes(b),
            }
        })
        .collect()
}

struct Ctx<'a> {
    big: bool,
    header64: bool,
    zlib: bool,
    appended: Option<(&'a [u8], bool)>, // data after '_', base64?
}

fn b64(s: &[u8]) -> Result<Vec<u8>> {
    let clean: Vec<u8> = s.iter().copied().filter(|c| !c.is_ascii_whitespace()).collect();
    base64::engine::general_purpose::STANDARD
        .decode(&clean)
        .map_err(|e| anyhow!("bad base64 ({e})"))
}

fn header_int(h: &[u8], k: usize, ctx: &Ctx) -> Result<usize> {
    let w = if ctx.header64 { 8 } else { 4 };
    let c = h
        .get(k * w..(k + 1) * w)
        .ok_or_else(|| anyhow!("a binary block header is truncated"))?;
    let mut b = [0u8; 8];
    b[..w].copy_from_slice(c);
    if ctx.big {
        b[..w].reverse();
    }
    Ok(u64::from_le_bytes(b) as usize)
}

/// Inflates VTK's zlib block layout: [nblocks, blocksize, lastsize, csize_1..csize_n] then data.
fn inflate_blocks(header: &[u8], data: &[u8], ctx: &Ctx, limit: usize) -> Result<Vec<u8>> {
    let nb = header_int(header, 0, ctx)?;
    let bs = header_int(header, 1, ctx)?;
    let last = header_int(header, 2, ctx)?;
    if nb > data.len() + 1 || bs.saturating_mul(nb) > limit.saturating_add(bs) {
        bail!("a compressed block header announces more data than the file can hold");
    }
    let mut out = Vec::with_capacity((bs * nb).min(limit));
    let mut at = 0usize;
    for k in 0..nb {
        let cs = header_int(header, 3 + k, ctx)?;
        let chunk = data
            .get(at..at + cs)
            .ok_or_else(|| anyhow!("compressed data is truncated"))?;
        at += cs;
        let want = if k + 1 == nb && last > 0 { last } else { bs };
        let mut d = flate2::read::ZlibDecoder::new(chunk).take(want as u64);
        let before = out.len();
        d.read_to_end(&mut out).map_err(|e| anyhow!("bad zlib data ({e})"))?;
        if out.len() - before != want {
            bail!("a zlib block inflates to {} bytes, expected {want}", out.len() - before);
        }
    }
    Ok(out)
}

fn header_len(ctx: &Ctx) -> usize {
    if ctx.header64 {
        8
    } else {
        4
    }
}

/// The values of one DataArray.
fn values(b: &[u8], t: &Tag, ctx: &Ctx, limit: usize) -> Result<(Ty, Vec<f64>)> {
    let ty_s = t.attrs.get("type").map(String::as_str).unwrap_or("");
    let ty = Ty::of(ty_s).ok_or_else(|| anyhow!("DataArray type `{ty_s}` is not supported"))?;
    let format = t.attrs.get("format").map(String::as_str).unwrap_or("ascii");
    let raw: Vec<u8> = match format {
        "ascii" => {
            let text = std::str::from_utf8(&b[t.content.clone()]).map_err(|_| anyhow!("ascii data is not text"))?;
            let mut v = Vec::new();
            for w in text.split_ascii_whitespace() {
                let x: f64 = w.parse().map_err(|_| anyhow!("`{w}` is not a number"))?;
                v.push(x);
            }
            return Ok((ty, v));
        }
        "binary" => {
            let s = &b[t.content.clone()];
            let clean: Vec<u8> = s.iter().copied().filter(|c| !c.is_ascii_whitespace()).collect();
            if ctx.zlib {
                // the header is encoded on its own: 3 + nblocks integers
                let hl = header_len(ctx);
                let first = b64(&clean[..clean.len().min((3 * hl).div_ceil(3) * 4)])?;
                let nb = header_int(&first, 0, ctx)?;
                let hbytes = (3 + nb).checked_mul(hl).ok_or_else(|| anyhow!("bad block count"))?;
                let henc = hbytes.div_ceil(3) * 4;
                if henc > clean.len() {
                    bail!("a compressed header is truncated");
                }
                let header = b64(&clean[..henc])?;
                let data = b64(&clean[henc..])?;
                inflate_blocks(&header, &data, ctx, limit)?
            } else {
                let all = b64(&clean)?;
                let hl = header_len(ctx);
                let nbytes = header_int(&all, 0, ctx)?;
                all.get(hl..hl + nbytes)
                    .ok_or_else(|| anyhow!("binary data is shorter than its header says"))?
                    .to_vec()
            }
        }
        "appended" => {
            let (data, enc64) = ctx
                .appended
                .ok_or_else(|| anyhow!("appended array but no <AppendedData>"))?;
            let off: usize = t
                .attrs
                .get("offset")
                .and_then(|o| o.trim().parse().ok())
                .ok_or_else(|| anyhow!("appended DataArray without a valid offset"))?;
            let hl = header_len(ctx);
            if enc64 {
                // base64 appended: each array is encoded separately from its offset
                let rest = data
                    .get(off..)
                    .ok_or_else(|| anyhow!("offset {off} is past the appended data"))?;
                let end = rest.iter().position(|&c| c == b'<').unwrap_or(rest.len());
                let clean: Vec<u8> = rest[..end]
                    .iter()
                    .copied()
                    .filter(|c| !c.is_ascii_whitespace())
                    .collect();
                let piece = |r: std::ops::Range<usize>| -> Result<Vec<u8>> {
                    b64(clean.get(r).ok_or_else(|| anyhow!("appended data is truncated"))?)
                };
                if ctx.zlib {
                    let first = piece(0..(3 * hl).div_ceil(3) * 4)?;
                    let nb = header_int(&first, 0, ctx)?;
                    let henc = 3usize.saturating_add(nb).saturating_mul(hl).div_ceil(3) * 4;
                    let header = piece(0..henc)?;
                    let mut total = 0usize;
                    for k in 0..nb {
                        total = total.saturating_add(header_int(&header, 3 + k, ctx)?);
                    }
                    let d = piece(henc..henc.saturating_add(total.div_ceil(3) * 4))?;
                    inflate_blocks(&header, &d, ctx, limit)?
                } else {
                    let first = piece(0..hl.div_ceil(3) * 4)?;
                    let nbytes = header_int(&first, 0, ctx)?;
                    let all = piece(0..hl.saturating_add(nbytes).div_ceil(3) * 4)?;
                    all.get(hl..hl + nbytes)
                        .ok_or_else(|| anyhow!("appended data is truncated"))?
                        .to_vec()
                }
            } else {
                let rest = data
                    .get(off..)
                    .ok_or_else(|| anyhow!("offset {off} is past the appended data"))?;
                if ctx.zlib {
                    let nb = header_int(rest, 0, ctx)?;
                    let hbytes = (3usize).saturating_add(nb).saturating_mul(hl);
                    let header = rest
                        .get(..hbytes)
                        .ok_or_else(|| anyhow!("appended header is truncated"))?;
                    inflate_blocks(header, &rest[hbytes..], ctx, limit)?
                } else {
                    let nbytes = header_int(rest, 0, ctx)?;
                    rest.get(hl..hl.saturating_add(nbytes))
                        .ok_or_else(|| anyhow!("appended data is truncated"))?
                        .to_vec()
                }
            }
        }
        f => bail!("DataArray format `{f}` is not known"),
    };
    if !raw.len().is_multiple_of(ty.size()) {
        bail!("{} bytes do not make whole {ty_s} values", raw.len());
    }
    Ok((ty, decode(ty, &raw, ctx.big)))
}

/// Parses a `.vtu` file's bytes.
pub fn parse(name: &str, b: &[u8]) -> Result<Mesh> {
    let (tags, app) = scan(name, b)?;
    let root = tags
        .iter()
        .find(|t| t.name == "VTKFile")
        .ok_or_else(|| anyhow!("{name}: no <VTKFile> element; fix: this is not a VTK XML file"))?;
    let ty = root.attrs.get("type").map(String::as_str).unwrap_or("");
    if ty != "UnstructuredGrid" {
        bail!(
            "{name}: VTKFile type `{ty}`; fix: eprop reads UnstructuredGrid (.vtu) files; save the volume mesh as one"
        );
    }
    let big = root.attrs.get("byte_order").map(String::as_str) == Some("BigEndian");
    let header64 = root.attrs.get("header_type").map(String::as_str) == Some("UInt64");
    let zlib = match root.attrs.get("compressor").map(String::as_str) {
        None | Some("") => false,
        Some("vtkZLibDataCompressor") => true,
        Some(c) => bail!("{name}: compressor `{c}` is not supported; fix: save with zlib or without compression"),
    };
    let appended = match &app {
        Some((at, attrs)) => {
            let enc64 = attrs.get("encoding").map(String::as_str) == Some("base64");
            let us = b[*at..]
                .iter()
                .position(|&c| c == b'_')
                .ok_or_else(|| anyhow!("{name}: <AppendedData> without its `_` marker; fix: the file is damaged"))?;
            Some((&b[at + us + 1..], enc64))
        }
        None => None,
    };
    let ctx = Ctx {
        big,
        header64,
        zlib,
        appended,
    };
    let piece = tags
        .iter()
        .find(|t| t.name == "Piece")
        .ok_or_else(|| anyhow!("{name}: no <Piece>; fix: the file holds no grid"))?;
    if tags.iter().filter(|t| t.name == "Piece").count() > 1 {
        bail!("{name}: several <Piece> elements; fix: merge the pieces (ParaView: Merge Blocks) and save again");
    }
    let count = |k: &str| -> Result<usize> {
        piece.attrs.get(k).and_then(|v| v.trim().parse().ok()).ok_or_else(|| {
            anyhow!(
                "{name}:{}: <Piece> lacks a valid {k}; fix: repair the header",
                piece.line
            )
        })
    };
    let (np, nc) = (count("NumberOfPoints")?, count("NumberOfCells")?);
    let limit = b.len().saturating_mul(1100).max(1 << 20); // zlib expands at most ~1000x
    if np.saturating_mul(3) > limit || nc > limit {
        bail!("{name}: the header announces {np} points and {nc} cells, more than the file can hold; fix: repair the header");
    }
    // the section each DataArray belongs to
    let mut section = "";
    let mut arrays: Vec<(&str, &Tag)> = Vec::new();
    for t in &tags {
        match t.name.as_str() {
            "Points" | "Cells" | "CellData" | "PointData" => section = t.name.as_str(),
            "DataArray" => arrays.push((section, t)),
            _ => {}
        }
    }
    let get = |sec: &str, pick: &dyn Fn(&Tag) -> bool, what: &str| -> Result<(Ty, Vec<f64>)> {
        let t = arrays
            .iter()
            .find(|(s, t)| *s == sec && pick(t))
            .map(|(_, t)| *t)
            .ok_or_else(|| anyhow!("{name}: no {what} array; fix: the file is incomplete"))?;
        values(b, t, &ctx, limit)
            .map_err(|e| anyhow!("{name}:{}: {what}: {e}; fix: the data is damaged or truncated", t.line))
    };
    let named = |n: &'static str| move |t: &Tag| t.attrs.get("Name").map(String::as_str) == Some(n);
    let (_, pts) = get("Points", &|_| true, "Points")?;
    if pts.len() != 3 * np {
        bail!(
            "{name}: Points holds {} values, expected 3 x {np}; fix: the counts disagree",
            pts.len()
        );
    }
    let (_, conn) = get("Cells", &named("connectivity"), "connectivity")?;
    let (_, offs) = get("Cells", &named("offsets"), "offsets")?;
    let (_, types) = get("Cells", &named("types"), "types")?;
    if offs.len() != nc || types.len() != nc {
        bail!(
            "{name}: {nc} cells but {} offsets and {} types; fix: the counts disagree",
            offs.len(),
            types.len()
        );
    }
    // an integer cell-data array as tags
    let prefer = [
        "tissue",
        "tag",
        "gmsh:physical",
        "CellEntityIds",
        "label",
        "region",
        "material",
    ];
    let mut tag_arr: Option<(&str, Vec<f64>)> = None;
    let mut candidates: Vec<&Tag> = arrays
        .iter()
        .filter(|(s, t)| *s == "CellData" && t.attrs.get("NumberOfComponents").is_none_or(|c| c.trim() == "1"))
        .map(|(_, t)| *t)
        .collect();
    candidates.sort_by_key(|t| {
        let n = t.attrs.get("Name").map(String::as_str).unwrap_or("");
        prefer
            .iter()
            .position(|p| p.eq_ignore_ascii_case(n))
            .unwrap_or(prefer.len())
    });
    for t in candidates {
        let (ty, v) = values(b, t, &ctx, limit).map_err(|e| anyhow!("{name}:{}: cell data: {e}", t.line))?;
        if v.len() == nc && (ty.is_int() || v.iter().all(|x| x.fract() == 0.0 && x.abs() < 2e9)) {
            tag_arr = Some((t.attrs.get("Name").map(String::as_str).unwrap_or("?"), v));
            break;
        }
    }
    let mut mesh = Mesh::new(name);
    mesh.points = pts.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    if mesh.points.iter().flatten().any(|x| !x.is_finite()) {
        let k = mesh
            .points
            .iter()
            .position(|p| p.iter().any(|x| !x.is_finite()))
            .unwrap_or(0);
        bail!("{name}: point {k} has a NaN or infinite coordinate; fix: repair or re-export the mesh");
    }
    mesh.node_ids = (0..np as u64).collect();
    if let Some((_, t)) = arrays
        .iter()
        .find(|(s, t)| *s == "PointData" && t.attrs.get("Name").map(String::as_str) == Some("node_ids"))
    {
        let (_, ids) = values(b, t, &ctx, limit).map_err(|e| anyhow!("{name}:{}: node_ids: {e}", t.line))?;
        if ids.len() == np && ids.iter().all(|&x| x >= 0.0 && x.fract() == 0.0) {
            mesh.node_ids = ids.iter().map(|&x| x as u64).collect();
        }
    }
    let mut start = 0usize;
    let mut buf: Vec<u32> = Vec::with_capacity(8);
    let mut skipped = 0usize;
    for c in 0..nc {
        let end = offs[c];
        if !(end >= start as f64 && end <= conn.len() as f64) {
            bail!("{name}: cell {c}: offset {end} is out of order or past the connectivity; fix: the cell arrays are damaged");
        }
        let end = end as usize;
        buf.clear();
        for &v in &conn[start..end] {
            if !(v >= 0.0 && (v as usize) < np) {
                bail!("{name}: cell {c} names point {v}, outside 0..{np}; fix: the connectivity is damaged");
            }
            buf.push(v as u32);
        }
        start = end;
        let tag = tag_arr.as_ref().map_or(0, |(_, v)| v[c] as i32);
        let vt = types[c] as i64;
        let want = |k: usize| -> Result<()> {
            if buf.len() != k {
                bail!(
                    "{name}: cell {c} (VTK type {vt}) has {} points, expected {k}; fix: the cell arrays are damaged",
                    buf.len()
                );
            }
            Ok(())
        };
        match vt {
            10 => {
                want(4)?;
                mesh.push_cell(CellKind::Tet, &buf, tag);
            }
            12 => {
                want(8)?;
                mesh.push_cell(CellKind::Hex, &buf, tag);
            }
            13 => {
                want(6)?;
                // VTK wedges wind their first triangle the other way round from Gmsh's
                let w = [buf[0], buf[2], buf[1], buf[3], buf[5], buf[4]];
                mesh.push_cell(CellKind::Wedge, &w, tag);
            }
            14 => {
                want(5)?;
                mesh.push_cell(CellKind::Pyramid, &buf, tag);
            }
            5 | 9 => mesh.facets.push(2, tag, &buf),
            3 => mesh.facets.push(1, tag, &buf),
            1 => mesh.facets.push(0, tag, &buf),
            24 | 25 | 26 | 27 | 29 | 32 => {
                bail!("{name}: cell {c} is a second-order cell (VTK type {vt}); fix: re-mesh with first-order elements")
            }
            _ => skipped += 1,
        }
    }
    if skipped > 0 {
        mesh.warnings
            .push(format!("{skipped} cell(s) of types eprop does not use were skipped"));
    }
    if let Some((n, _)) = &tag_arr {
        mesh.warnings.push(format!("cell tags from the cell-data array `{n}`"));
    }
    if mesh.n_cells() == 0 {
        bail!("{name}: no volume cells (tetrahedra, hexahedra, prisms or pyramids); fix: mesh the volume, not only its surface");
    }
    mesh.orient_cells()?;
    Ok(mesh)
}

/// Writes a mesh as VTU (ascii), with the cell tags and the input node ids.
pub fn write(mesh: &Mesh, path: &Path) -> Result<()> {
    use std::fmt::Write as _;
    let mut s = String::new();
    let _ = writeln!(s, "<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\">\n<UnstructuredGrid>");
    let _ = writeln!(
        s,
        "<Piece NumberOfPoints=\"{}\" NumberOfCells=\"{}\">",
        mesh.n_nodes(),
        mesh.n_cells()
    );
    s.push_str("<PointData>\n<DataArray type=\"Int64\" Name=\"node_ids\" format=\"ascii\">\n");
    for id in &mesh.node_ids {
        let _ = writeln!(s, "{id}");
    }
    s.push_str("</DataArray>\n</PointData>\n<CellData>\n<DataArray type=\"Int32\" Name=\"tag\" format=\"ascii\">\n");
    for t in &mesh.cell_tags {
        let _ = writeln!(s, "{t}");
    }
    s.push_str(
        "</DataArray>\n</CellData>\n<Points>\n<DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">\n",
    );
    for p in &mesh.points {
        let _ = writeln!(s, "{:?} {:?} {:?}", p[0], p[1], p[2]);
    }
    s.push_str("</DataArray>\n</Points>\n<Cells>\n<DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n");
    for c in 0..mesh.n_cells() {
        let v = crate::vtkhdf::vtk_order(mesh.kinds[c], mesh.cell(c));
        let line: Vec<String> = v.iter().map(|x| x.to_string()).collect();
        let _ = writeln!(s, "{}", line.join(" "));
    }
    s.push_str("</DataArray>\n<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n");
    let mut at = 0;
    for c in 0..mesh.n_cells() {
        at += mesh.cell(c).len();
        let _ = writeln!(s, "{at}");
    }
    s.push_str("</DataArray>\n<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n");
    for k in &mesh.kinds {
        let _ = writeln!(s, "{}", k.vtk_type());
    }
    s.push_str("</DataArray>\n</Cells>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n");
    std::fs::write(path, s).map_err(|e| anyhow!("{}: cannot write: {e}; fix: check the directory", path.display()))
}
