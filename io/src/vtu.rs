//! VTK XML `.vtu` reader and writer.
//!
//! Reads ascii, inline base64 (`format="binary"`, UInt32 or UInt64 headers), appended raw and
//! appended base64 data, zlib-compressed (`vtkZLibDataCompressor`) or not, in either byte order.
//! Writes inline base64 with a `tag` cell-data array and `node_ids` point data.

use crate::mesh::Mesh;
use crate::scan::{decode, parse_text, short, Scan, Ty, Vals};
use crate::vtk::{build, vtk_order, VtkData};
use anyhow::{anyhow, bail, Result};
use base64::engine::general_purpose::{GeneralPurpose, GeneralPurposeConfig};
use base64::{alphabet, Engine as _};
use quick_xml::events::attributes::AttrError;
use quick_xml::events::Event;
use quick_xml::Reader;
use std::io::{Read, Write as _};
use std::path::Path;

/// One XML start tag.
struct Tag {
    name: String,
    attrs: Vec<(String, String)>,
    /// Byte position of the `<`.
    pos: usize,
    /// First byte after the `>`.
    end: usize,
    self_closing: bool,
}

impl Tag {
    fn attr(&self, k: &str) -> Option<&str> {
        self.attrs.iter().find(|(a, _)| a == k).map(|(_, v)| v.as_str())
    }
}

/// The XML layer: quick-xml's tokenizer over the file's bytes, as start and end tags with their
/// byte positions; declarations, comments and text are skipped. The reader matches end tags
/// itself (a `</DataArray>` closes nothing), so quick-xml's own checks of them are off.
struct Xml<'a> {
    sc: Scan<'a>,
    rd: Reader<&'a [u8]>,
    /// Length of the byte-order mark quick-xml does not see.
    bom: usize,
}

enum Ev {
    Start(Tag),
    End(String),
}

impl<'a> Xml<'a> {
    fn new(name: &'a str, bytes: &'a [u8]) -> Self {
        // quick-xml skips a byte-order mark without counting it: positions here count it
        let bom = if bytes.starts_with(b"\xEF\xBB\xBF") { 3 } else { 0 };
        let mut rd = Reader::from_reader(&bytes[bom..]);
        let c = rd.config_mut();
        c.check_end_names = false;
        c.allow_unmatched_ends = true;
        c.allow_dangling_amp = true;
        Xml {
            sc: Scan::new(name, bytes),
            rd,
            bom,
        }
    }
    fn find(&self, from: usize, pat: &[u8]) -> Option<usize> {
        let b = self.sc.b;
        if from > b.len() || pat.is_empty() {
            return None;
        }
        b[from..].windows(pat.len()).position(|w| w == pat).map(|p| p + from)
    }
    /// The next start or end tag, or None at the end of the file.
    fn next(&mut self) -> Result<Option<Ev>> {
        loop {
            let before = self.bom + self.rd.buffer_position() as usize;
            let ev = match self.rd.read_event() {
                Ok(ev) => ev,
                Err(e) => return Err(self.syntax_error(e)),
            };
            let end = self.bom + self.rd.buffer_position() as usize;
            self.sc.pos = end;
            let (t, self_closing) = match ev {
                Event::Start(t) => (t, false),
                Event::Empty(t) => (t, true),
                Event::End(t) => {
                    let raw = t.name().into_inner();
                    let n = raw.iter().take_while(|c| !c.is_ascii_whitespace()).count();
                    let name = String::from_utf8_lossy(&raw[..n]).into_owned();
                    if name.is_empty() {
                        return Err(self
                            .sc
                            .err_at(before, "a `<` without a tag name; fix: the XML is malformed"));
                    }
                    return Ok(Some(Ev::End(name)));
                }
                Event::Eof => return Ok(None),
                _ => continue,
            };
            let name = String::from_utf8_lossy(t.name().as_ref()).into_owned();
            if name.is_empty() {
                return Err(self
                    .sc
                    .err_at(before, "a `<` without a tag name; fix: the XML is malformed"));
            }
            let mut attrs = Vec::new();
            for a in t.attributes().with_checks(false) {
                let a = a.map_err(|e| self.attribute_error(before, e))?;
                attrs.push((
                    String::from_utf8_lossy(a.key.as_ref()).into_owned(),
                    String::from_utf8_lossy(a.value.as_ref()).into_owned(),
                ));
            }
            return Ok(Some(Ev::Start(Tag {
                name,
                attrs,
                pos: before,
                end,
                self_closing,
            })));
        }
    }
    /// A tokenizer error as `file:line: what; fix`.
    fn syntax_error(&self, e: quick_xml::Error) -> anyhow::Error {
        use quick_xml::errors::SyntaxError as S;
        let at = self.bom + self.rd.error_position() as usize;
        let msg = match &e {
            quick_xml::Error::Syntax(S::UnclosedComment) => {
                "comment without `-->`; fix: the file is truncated".to_string()
            }
            quick_xml::Error::Syntax(S::UnclosedTag) => {
                let b = &self.sc.b[(at + 1).min(self.sc.b.len())..];
                let b = b.strip_prefix(b"/").unwrap_or(b);
                let n = b
                    .iter()
                    .take_while(|&&c| !c.is_ascii_whitespace() && c != b'>' && c != b'/')
                    .count();
                let name = String::from_utf8_lossy(&b[..n]).into_owned();
                format!("tag <{}> is not closed; fix: the file is truncated", short(&name))
            }
            quick_xml::Error::Syntax(S::UnclosedDoubleQuotedAttributeValue | S::UnclosedSingleQuotedAttributeValue) => {
                "attribute value not closed; fix: the file is truncated".to_string()
            }
            quick_xml::Error::Syntax(S::UnclosedPI | S::UnclosedXmlDecl) => {
                "declaration `<?` without `?>`; fix: the file is truncated or the XML is malformed".to_string()
            }
            quick_xml::Error::Syntax(S::InvalidBangMarkup) => {
                "`<!` starts neither a comment, CDATA nor DOCTYPE; fix: the XML is malformed".to_string()
            }
            quick_xml::Error::Syntax(_) => "declaration without `>`; fix: the file is truncated".to_string(),
            e => format!("{e}; fix: the XML is malformed"),
        };
        self.sc.err_at(at, msg)
    }
    /// An attribute error in the tag whose `<` is at `tag`, naming the attribute.
    fn attribute_error(&self, tag: usize, e: AttrError) -> anyhow::Error {
        let b = self.sc.b;
        // quick-xml counts from the byte after the `<`; the attribute's key is the word
        // before that position (before its `=`, if any)
        let at = |p: usize| (tag + 1 + p).min(b.len());
        let key_before = |p: usize| {
            let mut e = at(p);
            while e > tag && (b[e - 1].is_ascii_whitespace() || b[e - 1] == b'=') {
                e -= 1;
            }
            let mut s = e;
            while s > tag && !b[s - 1].is_ascii_whitespace() {
                s -= 1;
            }
            short(&String::from_utf8_lossy(&b[s..e]))
        };
        let (p, msg) = match e {
            AttrError::ExpectedEq(p) => (
                p,
                format!(
                    "attribute `{}` without a value; fix: the XML is malformed",
                    key_before(p)
                ),
            ),
            AttrError::ExpectedValue(p) | AttrError::UnquotedValue(p) => (
                p,
                format!(
                    "attribute `{}` value is not quoted; fix: the XML is malformed",
                    key_before(p)
                ),
            ),
            AttrError::ExpectedQuote(p, _) => (p, "attribute value not closed; fix: the file is truncated".to_string()),
            AttrError::Duplicated(p, _) => (p, "an attribute is given twice; fix: the XML is malformed".to_string()),
        };
        self.sc.err_at(at(p), msg)
    }
}

/// A streaming base64 decoder over concatenated base64 blocks (each may carry padding), as VTK
/// writes a header and its payload. Decoding is the `base64` crate's; this reads only the
/// groups of four symbols a request needs, so a request never looks past its array.
struct B64<'a> {
    s: &'a [u8],
    pos: usize,
    pending: Vec<u8>,
    name: &'a str,
    base: usize,
}

/// VTK's base64: the standard alphabet, padded groups; bits after the last byte are ignored.
const VTK_BASE64: GeneralPurpose = GeneralPurpose::new(
    &alphabet::STANDARD,
    GeneralPurposeConfig::new().with_decode_allow_trailing_bits(true),
);

/// Symbols decoded in one call at most (a multiple of 4).
const B64_BATCH: usize = 1 << 16;

impl<'a> B64<'a> {
    fn remaining_bytes(&self) -> usize {
        self.pending.len() + (self.s.len().saturating_sub(self.pos)) / 4 * 3 + 3
    }
    /// Fails if the data left cannot hold `n` more bytes.
    fn ensure(&self, n: usize, what: &str) -> Result<()> {
        if n > self.remaining_bytes() {
            bail!(
                "{}: byte {}: base64 data ends while reading {what} ({n} bytes announced); fix: the data is truncated or its header is wrong, export again",
                self.name,
                self.base + self.pos
            );
        }
        Ok(())
    }
    fn take(&mut self, n: usize, what: &str) -> Result<Vec<u8>> {
        self.ensure(n, what)?;
        let mut quads: Vec<u8> = Vec::new();
        while self.pending.len() < n {
            // the groups still needed, up to and including the first padded one (it ends a block)
            let want = (n - self.pending.len()).div_ceil(3).saturating_mul(4).min(B64_BATCH);
            let start = self.pos;
            quads.clear();
            while quads.len() < want {
                let Some(&c) = self.s.get(self.pos) else {
                    // report a bad group read before the end first, as a group-by-group decoder would
                    let whole = quads.len() / 4 * 4;
                    self.decode(&quads[..whole], start)?;
                    bail!("{}: byte {}: base64 data ends while reading {what}; fix: the data is truncated or its header is wrong, export again", self.name, self.base + self.pos);
                };
                self.pos += 1;
                if c.is_ascii_whitespace() {
                    continue;
                }
                quads.push(c);
                if c == b'=' && quads.len().is_multiple_of(4) {
                    break;
                }
            }
            self.decode(&quads, start)?;
        }
        Ok(self.pending.drain(..n).collect())
    }
    /// Decodes whole groups of symbols read from `start` on into `pending`.
    fn decode(&mut self, quads: &[u8], start: usize) -> Result<()> {
        VTK_BASE64
            .decode_vec(quads, &mut self.pending)
            .map_err(|e| self.decode_error(quads, start, e))
    }
    /// Names the first bad group: where it ends in the file and what is wrong with it.
    fn decode_error(&self, quads: &[u8], start: usize, e: base64::DecodeError) -> anyhow::Error {
        let at = match e {
            base64::DecodeError::InvalidByte(i, _) | base64::DecodeError::InvalidLastSymbol(i, _) => i,
            base64::DecodeError::InvalidLength(_) | base64::DecodeError::InvalidPadding => {
                quads.len().saturating_sub(1)
            }
        };
        let group = &quads[at / 4 * 4..(at / 4 * 4 + 4).min(quads.len())];
        // the file position just after that group
        let mut seen = 0;
        let mut end = start;
        while seen < at / 4 * 4 + group.len() && end < self.s.len() {
            if !self.s[end].is_ascii_whitespace() {
                seen += 1;
            }
            end += 1;
        }
        let pad = group.iter().rev().take_while(|&&c| c == b'=').count();
        let bad = group[..group.len() - pad]
            .iter()
            .find(|&&c| !(c.is_ascii_alphanumeric() || c == b'+' || c == b'/'));
        match bad {
            _ if pad > 2 => anyhow!(
                "{}: byte {}: bad base64 padding; fix: the data is corrupt, export again",
                self.name,
                self.base + end
            ),
            Some(c) => anyhow!(
                "{}: byte {}: `{}` is not a base64 character; fix: the data is corrupt, export again",
                self.name,
                self.base + end,
                c.escape_ascii()
            ),
            None => anyhow!(
                "{}: byte {}: bad base64 data ({e}); fix: the data is corrupt, export again",
                self.name,
                self.base + end
            ),
        }
    }
}

/// Where the bytes of a binary array come from.
enum Src<'a> {
    Raw {
        b: &'a [u8],
        pos: usize,
        base: usize,
        name: &'a str,
    },
    B64(B64<'a>),
}

impl Src<'_> {
    /// Fails as `take` would if fewer than `n` bytes are left.
    fn ensure(&self, n: usize, what: &str) -> Result<()> {
        match self {
            Src::Raw { b, pos, base, name } => {
                if n > b.len().saturating_sub(*pos) {
                    bail!(
                        "{name}: byte {}: appended data ends while reading {what} ({n} bytes announced, {} left); fix: the file is truncated or its header is wrong, export again",
                        *base + *pos,
                        b.len().saturating_sub(*pos)
                    );
                }
            }
            Src::B64(d) => d.ensure(n, what)?,
        }
        Ok(())
    }
    fn take(&mut self, n: usize, what: &str) -> Result<Vec<u8>> {
        self.ensure(n, what)?;
        match self {
            Src::Raw { b, pos, .. } => {
                let v = b[*pos..*pos + n].to_vec();
                *pos += n;
                Ok(v)
            }
            Src::B64(d) => d.take(n, what),
        }
    }
}

struct Fmt {
    big: bool,
    header: Ty,
    zlib: bool,
}

fn uint(b: &[u8], ty: Ty, big: bool) -> u64 {
    match decode(b, ty, big) {
        Vals::I(v) => v.first().copied().unwrap_or(0).max(0) as u64,
        Vals::F(_) => 0,
    }
}

/// How many values an array must hold: exactly (counts from the `<Piece>`), or at most (the
/// connectivity: what the cell offsets use).
#[derive(Clone, Copy, Debug)]
enum Count {
    Exactly(usize),
    AtMost(usize),
}

impl Count {
    fn exactly(self) -> Option<usize> {
        match self {
            Count::Exactly(n) => Some(n),
            Count::AtMost(_) => None,
        }
    }
}

/// What a binary array must inflate to: `count` values of `size` bytes; `at` (`file:line` of
/// its `<DataArray>`) for messages.
struct Need<'a> {
    count: Count,
    size: usize,
    at: &'a str,
}

/// zlib cannot expand data more than about 1032:1: a block claiming more is a corrupt header.
const ZLIB_MAX_RATIO: usize = 1100;

/// Reads one binary array (header + data, possibly zlib blocks) from `src`. `need` bounds what
/// zlib blocks may inflate to: their header is checked against it, and against what the
/// compressed bytes can hold, before anything is inflated or allocated.
fn read_binary(src: &mut Src, f: &Fmt, what: &str, name: &str, need: &Need) -> Result<Vec<u8>> {
    let hs = f.header.size();
    if !f.zlib {
        // the data is in the file: `take` checks that it is there before copying it
        let n = uint(&src.take(hs, what)?, f.header, f.big);
        let n = usize::try_from(n)
            .map_err(|_| anyhow!("{name}: {what}: size {n} too large; fix: the header is corrupt"))?;
        return src.take(n, what);
    }
    let h = src.take(3 * hs, what)?;
    let nblocks = uint(&h[..hs], f.header, f.big) as usize;
    let bsize = uint(&h[hs..2 * hs], f.header, f.big) as usize;
    let last = uint(&h[2 * hs..], f.header, f.big) as usize;
    let sizes_len = nblocks
        .checked_mul(hs)
        .ok_or_else(|| anyhow!("{name}: {what}: {nblocks} compressed blocks announced; fix: the header is corrupt"))?;
    let sizes = src.take(sizes_len, what)?;
    let block = |k: usize| {
        let cs = uint(&sizes[k * hs..(k + 1) * hs], f.header, f.big) as usize;
        let want = if k + 1 == nblocks && last != 0 { last } else { bsize };
        (cs, want)
    };
    let (mut total, mut total_cs) = (0u128, 0u128);
    for k in 0..nblocks {
        let (cs, want) = block(k);
        if want / ZLIB_MAX_RATIO > cs.saturating_add(64) {
            bail!("{name}: {what}: block {k} claims {want} bytes from {cs} compressed bytes; fix: the compression header is corrupt, export again");
        }
        total += want as u128;
        total_cs += cs as u128;
    }
    check_declared(total, need, what)?;
    src.ensure(usize::try_from(total_cs).unwrap_or(usize::MAX), what)?;
    let total = total as usize; // at most count * size
    let mut out = Vec::new();
    out.try_reserve_exact(total).map_err(|_| {
        anyhow!("{name}: {what}: not enough memory for its {total} bytes; fix: free memory or use a machine with more")
    })?;
    for k in 0..nblocks {
        let (cs, want) = block(k);
        let comp = src.take(cs, what)?;
        let mut dec = flate2::read::ZlibDecoder::new(&comp[..]).take(want as u64 + 1);
        let before = out.len();
        dec.read_to_end(&mut out).map_err(|e| {
            anyhow!(
                "{name}: {what}: zlib block {k} cannot be decompressed ({e}); fix: the data is corrupt, export again"
            )
        })?;
        if out.len() - before != want {
            bail!(
                "{name}: {what}: zlib block {k} holds {} bytes, its header says {want}; fix: the data is corrupt, export again",
                out.len() - before
            );
        }
    }
    Ok(out)
}

/// The size a compression header declares against what the array's values take.
fn check_declared(total: u128, need: &Need, what: &str) -> Result<()> {
    let bytes = |n: usize| n as u128 * need.size as u128;
    let name = need.at;
    match need.count {
        Count::Exactly(n) if total != bytes(n) => bail!(
            "{name}: {what}: its compression header declares {total} bytes, but its {n} values take {}; fix: the counts disagree or the header is corrupt, export again",
            bytes(n)
        ),
        Count::AtMost(n) if total > bytes(n) => bail!(
            "{name}: {what}: its compression header declares {total} bytes, more than the {n} values the cell offsets use ({} bytes); fix: the header is corrupt, export again",
            bytes(n)
        ),
        _ => Ok(()),
    }
}

/// A `<DataArray>` as found in the file.
struct Arr {
    parent: String,
    tag: Tag,
    /// The text between the start and end tags.
    text: (usize, usize),
}

/// What the XML structure of a `.vtu` says, before any array is decoded.
struct Doc<'a> {
    name: &'a str,
    bytes: &'a [u8],
    /// For messages (`file:line`).
    sc: Scan<'a>,
    fmt: Fmt,
    arrays: Vec<Arr>,
    /// NumberOfPoints and NumberOfCells of the one `<Piece>`.
    np: usize,
    nc: usize,
    /// Appended data: start (after the `_`), end (the closing tag or the end of the file),
    /// base64 or raw.
    appended: Option<(usize, usize, bool)>,
}

/// Parses the bytes of a `.vtu` file.
pub fn parse(name: &str, bytes: &[u8]) -> Result<Mesh> {
    let doc = structure(name, bytes)?;
    let points = doc.points()?;
    let (types, starts, conn) = doc.cells()?;
    let (cell_arrays, point_arrays) = doc.tag_arrays()?;
    build(
        name,
        VtkData {
            points,
            conn,
            starts,
            types,
            cell_arrays,
            point_arrays,
        },
    )
}

/// Walks the XML: the `<VTKFile>` format, the `<Piece>` counts, every `<DataArray>` with its
/// parent element, and where appended data starts (the walk stops there: what follows is data).
fn structure<'a>(name: &'a str, bytes: &'a [u8]) -> Result<Doc<'a>> {
    let mut x = Xml::new(name, bytes);
    let mut stack: Vec<String> = Vec::new();
    let mut fmt = Fmt {
        big: false,
        header: Ty::U32,
        zlib: false,
    };
    let mut arrays: Vec<Arr> = Vec::new();
    let mut piece: Option<(usize, usize)> = None;
    let mut appended: Option<(usize, bool)> = None; // (start of data after `_`, base64)
    let mut saw_root = false;
    while let Some(ev) = x.next()? {
        match ev {
            Ev::Start(t) => {
                match t.name.as_str() {
                    "VTKFile" => {
                        saw_root = true;
                        fmt = file_format(&x.sc, &t)?;
                    }
                    "Piece" => {
                        if piece.is_some() {
                            return Err(x.sc.err_at(t.pos, "more than one <Piece>; fix: merge the pieces into one (e.g. ParaView Merge Blocks) and save again"));
                        }
                        piece = Some(piece_counts(&x.sc, &t)?);
                    }
                    "DataArray" => {
                        let parent = stack.last().cloned().unwrap_or_default();
                        let text = if t.self_closing {
                            (t.end, t.end)
                        } else {
                            let e = x.find(t.end, b"<").unwrap_or(bytes.len());
                            (t.end, e)
                        };
                        arrays.push(Arr { parent, tag: t, text });
                        continue; // its end tag pops nothing
                    }
                    "AppendedData" => {
                        appended = Some(appended_start(&x, &t)?);
                        break;
                    }
                    _ => {}
                }
                if !t.self_closing {
                    stack.push(t.name);
                }
            }
            Ev::End(n) => {
                if n == "DataArray" {
                    continue;
                }
                match stack.pop() {
                    Some(open) if open == n => {}
                    other => {
                        return Err(x.sc.err(format!(
                            "</{}> closes <{}>; fix: the XML is malformed",
                            short(&n),
                            other.unwrap_or_default()
                        )))
                    }
                }
            }
        }
    }
    if !saw_root {
        bail!("{name}: no <VTKFile> element; fix: check that this is a VTK XML file");
    }
    let Some((np, nc)) = piece else {
        bail!("{name}: no <Piece>; fix: the file holds no unstructured grid");
    };
    Ok(Doc {
        name,
        bytes,
        sc: x.sc,
        fmt,
        arrays,
        np,
        nc,
        appended: appended.map(|(s, b64)| (s, appended_end(bytes, s), b64)),
    })
}

/// The attributes of `<VTKFile>`: dataset type, byte order, header type, compressor.
fn file_format(sc: &Scan, t: &Tag) -> Result<Fmt> {
    if let Some(ty) = t.attr("type") {
        if ty != "UnstructuredGrid" {
            return Err(sc.err_at(t.pos, format!("VTK XML type {} is not a volume mesh (UnstructuredGrid is read); fix: save as .vtu (unstructured grid)", short(ty))));
        }
    }
    let big = match t.attr("byte_order") {
        Some("BigEndian") => true,
        Some("LittleEndian") | None => false,
        Some(o) => {
            return Err(sc.err_at(
                t.pos,
                format!("unknown byte_order `{}`; fix: use LittleEndian or BigEndian", short(o)),
            ))
        }
    };
    let header = match t.attr("header_type") {
        None | Some("UInt32") => Ty::U32,
        Some("UInt64") => Ty::U64,
        Some(h) => {
            return Err(sc.err_at(
                t.pos,
                format!("unknown header_type `{}`; fix: use UInt32 or UInt64", short(h)),
            ))
        }
    };
    let zlib = match t.attr("compressor") {
        None | Some("") => false,
        Some("vtkZLibDataCompressor") => true,
        Some(c) => {
            return Err(sc.err_at(
                t.pos,
                format!(
                    "compressor {} is not supported; fix: save with zlib compression or none",
                    short(c)
                ),
            ))
        }
    };
    Ok(Fmt { big, header, zlib })
}

/// NumberOfPoints and NumberOfCells of a `<Piece>`.
fn piece_counts(sc: &Scan, t: &Tag) -> Result<(usize, usize)> {
    let num = |k: &str| -> Result<usize> {
        t.attr(k)
            .ok_or_else(|| sc.err_at(t.pos, format!("<Piece> has no {k}; fix: repair the file")))?
            .trim()
            .parse::<usize>()
            .map_err(|_| sc.err_at(t.pos, format!("<Piece> {k} is not a count; fix: repair the file")))
    };
    Ok((num("NumberOfPoints")?, num("NumberOfCells")?))
}

/// Where the data of `<AppendedData>` starts (after its `_` marker), and whether it is base64.
fn appended_start(x: &Xml, t: &Tag) -> Result<(usize, bool)> {
    let enc = t.attr("encoding").unwrap_or("raw");
    let b64 = match enc {
        "raw" => false,
        "base64" => true,
        _ => {
            return Err(x.sc.err_at(
                t.pos,
                format!("appended encoding `{}` is unknown; fix: use raw or base64", short(enc)),
            ))
        }
    };
    let us = x.find(t.end, b"_").ok_or_else(|| {
        x.sc.err_at(t.pos, "<AppendedData> has no `_` marker; fix: the file is truncated")
    })?;
    Ok((us + 1, b64))
}

/// The end of appended data starting at `start`: its closing tag, when present.
fn appended_end(bytes: &[u8], start: usize) -> usize {
    bytes[start..]
        .windows(16)
        .rposition(|w| w == b"</AppendedData>\n" || w.starts_with(b"</AppendedData>"))
        .map(|p| p + start)
        .unwrap_or(bytes.len())
}

impl Doc<'_> {
    /// The first array under `parent` (with that `Name`, if given).
    fn find(&self, parent: &str, nm: Option<&str>) -> Option<&Arr> {
        self.arrays
            .iter()
            .find(|a| a.parent == parent && (nm.is_none() || a.tag.attr("Name") == nm))
    }

    /// Decodes an array of `count` values.
    fn read(&self, a: &Arr, count: Count) -> Result<Vals> {
        let count_hint = count.exactly();
        let (name, sc) = (self.name, &self.sc);
        let t = &a.tag;
        let aname = t.attr("Name").unwrap_or("");
        let what = format!("DataArray `{}`", short(aname));
        let ty_s = t.attr("type").unwrap_or("");
        let ty = Ty::from_xml(ty_s).ok_or_else(|| {
            sc.err_at(
                t.pos,
                format!(
                    "{what} has unknown type `{}`; fix: use Int32, Int64, UInt8, Float32 or Float64",
                    short(ty_s)
                ),
            )
        })?;
        let format = t.attr("format").unwrap_or("ascii");
        let at = format!("{name}:{}", sc.line_of(t.pos));
        let need = Need {
            count,
            size: ty.size(),
            at: &at,
        };
        let bytes_out = match format {
            "ascii" => return self.read_ascii(a, ty, &what, count_hint),
            "binary" => {
                let mut src = Src::B64(B64 {
                    s: &self.bytes[a.text.0..a.text.1],
                    pos: 0,
                    pending: Vec::new(),
                    name,
                    base: a.text.0,
                });
                read_binary(&mut src, &self.fmt, &what, name, &need)?
            }
            "appended" => {
                let mut src = self.appended_source(t, &what)?;
                read_binary(&mut src, &self.fmt, &what, name, &need)?
            }
            f => {
                return Err(sc.err_at(
                    t.pos,
                    format!(
                        "{what} has unknown format `{}`; fix: use ascii, binary or appended",
                        short(f)
                    ),
                ))
            }
        };
        if bytes_out.len() % ty.size() != 0 {
            return Err(sc.err_at(t.pos, format!("{what} holds {} bytes, not a whole number of {ty_s} values; fix: the data is corrupt, export again", bytes_out.len())));
        }
        let v = decode(&bytes_out, ty, self.fmt.big);
        if let Some(h) = count_hint {
            if v.len() != h {
                return Err(sc.err_at(
                    t.pos,
                    format!(
                        "{what} holds {} values, expected {h}; fix: the counts disagree, export again",
                        v.len()
                    ),
                ));
            }
        }
        Ok(v)
    }

    /// An ascii array: its values are counted before they are parsed.
    fn read_ascii(&self, a: &Arr, ty: Ty, what: &str, count_hint: Option<usize>) -> Result<Vals> {
        let text = &self.bytes[..a.text.1];
        let mut c = Scan::new(self.name, text);
        c.pos = a.text.0;
        let mut n = 0usize;
        while c.token().is_some() {
            n += 1;
        }
        if let Some(h) = count_hint {
            if n != h {
                return Err(self.sc.err_at(
                    a.tag.pos,
                    format!("{what} holds {n} values, expected {h}; fix: the counts disagree, export again"),
                ));
            }
        }
        let mut s = Scan::new(self.name, text);
        s.pos = a.text.0;
        parse_text(&mut s, n, ty, what)
    }

    /// The bytes of an appended array, from its offset in the appended data.
    fn appended_source(&self, t: &Tag, what: &str) -> Result<Src<'_>> {
        let sc = &self.sc;
        let Some((start, end, b64)) = self.appended else {
            return Err(sc.err_at(
                t.pos,
                format!("{what} is appended but the file has no <AppendedData>; fix: the file is truncated"),
            ));
        };
        let end = end.max(start);
        let off: usize = t
            .attr("offset")
            .and_then(|o| o.trim().parse().ok())
            .ok_or_else(|| sc.err_at(t.pos, format!("{what} has no valid offset; fix: repair the file")))?;
        let region = &self.bytes[start..end];
        if off > region.len() {
            return Err(sc.err_at(
                t.pos,
                format!(
                    "{what}: offset {off} is past the end of the appended data ({} bytes); fix: the file is truncated",
                    region.len()
                ),
            ));
        }
        Ok(if b64 {
            Src::B64(B64 {
                s: &region[off..],
                pos: 0,
                pending: Vec::new(),
                name: self.name,
                base: start + off,
            })
        } else {
            Src::Raw {
                b: region,
                pos: off,
                base: start,
                name: self.name,
            }
        })
    }

    /// The `<Points>` array: NumberOfPoints points of 3 components.
    fn points(&self) -> Result<Vec<f64>> {
        let (name, np) = (self.name, self.np);
        let pts_a = self
            .find("Points", None)
            .ok_or_else(|| anyhow!("{name}: no <Points> array; fix: the file holds no mesh"))?;
        let ncomp: usize = pts_a
            .tag
            .attr("NumberOfComponents")
            .and_then(|s| s.trim().parse().ok())
            .unwrap_or(1);
        if ncomp != 3 {
            return Err(self.sc.err_at(
                pts_a.tag.pos,
                format!("points have {ncomp} components, expected 3; fix: export 3D points"),
            ));
        }
        let np3 = np
            .checked_mul(3)
            .ok_or_else(|| anyhow!("{name}: NumberOfPoints {np} too large; fix: repair the file"))?;
        Ok(self.read(pts_a, Count::Exactly(np3))?.to_f64())
    }

    /// The `<Cells>` arrays: types, starts (0 then the offsets) and connectivity.
    fn cells(&self) -> Result<(Vec<i64>, Vec<i64>, Vec<i64>)> {
        let (name, nc) = (self.name, self.nc);
        let cell = |n: &str| {
            self.find("Cells", Some(n))
                .ok_or_else(|| anyhow!("{name}: no `{n}` array in <Cells>; fix: the file is incomplete, export again"))
        };
        let ints = |a: &Arr, hint: Count| -> Result<Vec<i64>> {
            self.read(a, hint)?.to_i64().ok_or_else(|| {
                self.sc
                    .err_at(a.tag.pos, "cell array holds non-integers; fix: repair the file")
            })
        };
        let types = ints(cell("types")?, Count::Exactly(nc))?;
        let offsets = ints(cell("offsets")?, Count::Exactly(nc))?;
        // the offsets say how many connectivity entries the cells use
        let used = offsets.last().map_or(0, |&o| usize::try_from(o).unwrap_or(0));
        let conn = ints(cell("connectivity")?, Count::AtMost(used))?;
        let mut starts = Vec::with_capacity(nc + 1);
        starts.push(0i64);
        starts.extend_from_slice(&offsets);
        Ok((types, starts, conn))
    }

    /// One-component cell-data arrays (cell tag candidates) and the `node_ids` point data.
    fn tag_arrays(&self) -> Result<(Vec<(String, Vals)>, Vec<(String, Vals)>)> {
        let mut cell_arrays = Vec::new();
        let mut point_arrays = Vec::new();
        for a in &self.arrays {
            let one = a
                .tag
                .attr("NumberOfComponents")
                .map(|s| s.trim() == "1")
                .unwrap_or(true);
            if !one {
                continue;
            }
            let nm = a.tag.attr("Name").unwrap_or("").to_string();
            if a.parent == "CellData" {
                cell_arrays.push((nm, self.read(a, Count::Exactly(self.nc))?));
            } else if a.parent == "PointData" && nm == "node_ids" {
                point_arrays.push((nm, self.read(a, Count::Exactly(self.np))?));
            }
        }
        Ok((cell_arrays, point_arrays))
    }
}

/// How to encode the data arrays of a written `.vtu`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Encoding {
    Ascii,
    /// Inline base64 (`format="binary"`).
    Base64,
    /// Appended raw bytes.
    AppendedRaw,
    /// Appended base64.
    AppendedBase64,
}

/// Options of the `.vtu` writer.
#[derive(Clone, Copy, Debug)]
pub struct VtuOptions {
    pub encoding: Encoding,
    pub zlib: bool,
    pub header64: bool,
    pub big_endian: bool,
}

impl Default for VtuOptions {
    fn default() -> Self {
        VtuOptions {
            encoding: Encoding::Base64,
            zlib: false,
            header64: true,
            big_endian: false,
        }
    }
}

fn b64encode(b: &[u8]) -> String {
    base64::engine::general_purpose::STANDARD.encode(b)
}

/// Encodes a mesh as `.vtu` bytes.
/// One data array of a written `.vtu`.
enum Array {
    F(Vec<f64>),
    I(Vec<i64>),
    I32(Vec<i32>),
    U8(Vec<u8>),
}

impl Array {
    /// The values as bytes in the file's byte order.
    fn raw(&self, big: bool) -> Vec<u8> {
        fn put<const N: usize>(v: &mut Vec<u8>, le: [u8; N], be: [u8; N], big: bool) {
            v.extend(if big { be } else { le });
        }
        let mut v = Vec::new();
        match self {
            Array::F(x) => x
                .iter()
                .for_each(|y| put(&mut v, y.to_le_bytes(), y.to_be_bytes(), big)),
            Array::I(x) => x
                .iter()
                .for_each(|y| put(&mut v, y.to_le_bytes(), y.to_be_bytes(), big)),
            Array::I32(x) => x
                .iter()
                .for_each(|y| put(&mut v, y.to_le_bytes(), y.to_be_bytes(), big)),
            Array::U8(x) => v.extend_from_slice(x),
        }
        v
    }

    /// The values as ASCII text, twelve to a line.
    fn ascii(&self) -> String {
        let t: Vec<String> = match self {
            Array::F(x) => x.iter().map(|v| format!("{v:?}")).collect(),
            Array::I(x) => x.iter().map(|v| v.to_string()).collect(),
            Array::I32(x) => x.iter().map(|v| v.to_string()).collect(),
            Array::U8(x) => x.iter().map(|v| v.to_string()).collect(),
        };
        let mut s = String::new();
        for line in t.chunks(12) {
            s.push_str(&line.join(" "));
            s.push('\n');
        }
        s
    }
}

/// The cells of the mesh then its facets, as VTK lists them: connectivity, offsets, types and
/// tags.
fn cell_arrays(mesh: &Mesh) -> (Vec<i64>, Vec<i64>, Vec<u8>, Vec<i32>) {
    let (mut conn, mut offs, mut types, mut tags) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for c in 0..mesh.n_cells() {
        conn.extend(vtk_order(mesh.kinds[c], mesh.cell(c)).into_iter().map(|x| x as i64));
        offs.push(conn.len() as i64);
        types.push(mesh.kinds[c].vtk_type());
        tags.push(mesh.cell_tags[c]);
    }
    for f in 0..mesh.facets.len() {
        let nodes = mesh.facets.nodes(f);
        let Some(t) = crate::vtk::facet_vtk_type(mesh.facets.dim[f], nodes.len()) else {
            continue;
        };
        conn.extend(nodes.iter().map(|&x| x as i64));
        offs.push(conn.len() as i64);
        types.push(t);
        tags.push(mesh.facets.tags[f]);
    }
    (conn, offs, types, tags)
}

impl VtuOptions {
    /// A header integer (a size) in the file's width and byte order.
    fn header(&self, x: usize) -> Vec<u8> {
        match (self.header64, self.big_endian) {
            (true, true) => (x as u64).to_be_bytes().to_vec(),
            (true, false) => (x as u64).to_le_bytes().to_vec(),
            (false, true) => (x as u32).to_be_bytes().to_vec(),
            (false, false) => (x as u32).to_le_bytes().to_vec(),
        }
    }

    /// A binary array as VTK stores it: its header and its payload (compressed in blocks of
    /// 32 KiB under zlib), each base64-encoded separately when inline.
    fn block(&self, data: Vec<u8>) -> (Vec<u8>, Vec<u8>) {
        if !self.zlib {
            return (self.header(data.len()), data);
        }
        const BS: usize = 1 << 15;
        let chunks: Vec<&[u8]> = data.chunks(BS).collect();
        let mut comp = Vec::new();
        let mut h = self.header(chunks.len());
        h.extend(self.header(BS));
        h.extend(self.header(chunks.last().map(|c| c.len() % BS).unwrap_or(0)));
        for c in &chunks {
            let mut e = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
            let _ = e.write_all(c);
            let z = e.finish().unwrap_or_default();
            h.extend(self.header(z.len()));
            comp.extend(z);
        }
        (h, comp)
    }

    /// The `<VTKFile ...>` line.
    fn file_tag(&self) -> String {
        let mut s = String::from("<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\"");
        s.push_str(if self.big_endian {
            " byte_order=\"BigEndian\""
        } else {
            " byte_order=\"LittleEndian\""
        });
        s.push_str(if self.header64 {
            " header_type=\"UInt64\""
        } else {
            " header_type=\"UInt32\""
        });
        if self.zlib && self.encoding != Encoding::Ascii {
            s.push_str(" compressor=\"vtkZLibDataCompressor\"");
        }
        s.push_str(">\n");
        s
    }

    /// One `<DataArray>`: inline (ASCII or base64), or a reference to the appended block `app`
    /// where its bytes go.
    fn data_array(&self, s: &mut String, app: &mut Vec<u8>, name: &str, ty: &str, nc: usize, a: &Array) {
        let fmt = match self.encoding {
            Encoding::Ascii => "ascii",
            Encoding::Base64 => "binary",
            _ => "appended",
        };
        s.push_str(&format!(
            "<DataArray type=\"{ty}\" Name=\"{name}\" NumberOfComponents=\"{nc}\" format=\"{fmt}\""
        ));
        match self.encoding {
            Encoding::Ascii => {
                s.push_str(">\n");
                s.push_str(&a.ascii());
                s.push_str("</DataArray>\n");
            }
            Encoding::Base64 => {
                let (h, d) = self.block(a.raw(self.big_endian));
                s.push_str(">\n");
                s.push_str(&b64encode(&h));
                s.push_str(&b64encode(&d));
                s.push_str("\n</DataArray>\n");
            }
            Encoding::AppendedRaw | Encoding::AppendedBase64 => {
                s.push_str(&format!(" offset=\"{}\"/>\n", app.len()));
                let (h, d) = self.block(a.raw(self.big_endian));
                if self.encoding == Encoding::AppendedRaw {
                    app.extend(h);
                    app.extend(d);
                } else {
                    app.extend(b64encode(&h).bytes());
                    app.extend(b64encode(&d).bytes());
                }
            }
        }
    }
}

/// A mesh as `.vtu` bytes with the given options: points, cells then facets (with their tags
/// as CellData `tag`), node ids as PointData `node_ids`.
pub fn to_bytes(mesh: &Mesh, o: &VtuOptions) -> Vec<u8> {
    let n = mesh.n_nodes();
    let (conn, offs, types, tags) = cell_arrays(mesh);
    let ncells = types.len();
    let ids: Vec<i64> = if mesh.node_ids.len() == n {
        mesh.node_ids.iter().map(|&i| i as i64).collect()
    } else {
        (0..n as i64).collect()
    };
    let arrays: Vec<(&str, &str, &str, usize, Array)> = vec![
        (
            "Points",
            "Points",
            "Float64",
            3,
            Array::F(mesh.points.iter().flatten().copied().collect()),
        ),
        ("Cells", "connectivity", "Int64", 1, Array::I(conn)),
        ("Cells", "offsets", "Int64", 1, Array::I(offs)),
        ("Cells", "types", "UInt8", 1, Array::U8(types)),
        ("CellData", "tag", "Int32", 1, Array::I32(tags)),
        ("PointData", "node_ids", "Int64", 1, Array::I(ids)),
    ];
    let mut s = o.file_tag();
    s.push_str("<!-- written by eprop -->\n<UnstructuredGrid>\n");
    s.push_str(&format!("<Piece NumberOfPoints=\"{n}\" NumberOfCells=\"{ncells}\">\n"));
    let mut app: Vec<u8> = Vec::new();
    let mut open = "";
    for (parent, name, ty, nc, a) in &arrays {
        if *parent != open {
            if !open.is_empty() {
                s.push_str(&format!("</{open}>\n"));
            }
            s.push_str(&format!("<{parent}>\n"));
            open = parent;
        }
        o.data_array(&mut s, &mut app, name, ty, *nc, a);
    }
    s.push_str(&format!("</{open}>\n</Piece>\n</UnstructuredGrid>\n"));
    let mut out = s.into_bytes();
    if matches!(o.encoding, Encoding::AppendedRaw | Encoding::AppendedBase64) {
        let enc = if o.encoding == Encoding::AppendedRaw {
            "raw"
        } else {
            "base64"
        };
        out.extend(format!("<AppendedData encoding=\"{enc}\">\n_").bytes());
        out.extend(app);
        out.extend(b"\n</AppendedData>\n");
    }
    out.extend(b"</VTKFile>\n");
    out
}

/// Writes a mesh as `.vtu` (inline base64, UInt64 headers).
pub fn write(mesh: &Mesh, path: &Path) -> Result<()> {
    std::fs::write(path, to_bytes(mesh, &VtuOptions::default()))
        .map_err(|e| anyhow!("{}: cannot write: {e}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_stream_reads_across_padded_blocks() {
        // header and payload encoded separately, as VTK does
        let s = format!("{}{}", b64encode(&[4, 0, 0, 0]), b64encode(b"abcd"));
        let mut d = B64 {
            s: s.as_bytes(),
            pos: 0,
            pending: Vec::new(),
            name: "t",
            base: 0,
        };
        assert_eq!(d.take(4, "h").unwrap(), vec![4, 0, 0, 0]);
        assert_eq!(d.take(4, "d").unwrap(), b"abcd".to_vec());
        assert!(d.take(1, "x").is_err());
        let mut bad = B64 {
            s: b"AB!D",
            pos: 0,
            pending: Vec::new(),
            name: "t",
            base: 0,
        };
        assert!(format!("{:#}", bad.take(2, "x").unwrap_err()).contains("not a base64 character"));
    }

    #[test]
    fn zlib_header_claiming_huge_blocks_is_refused() {
        // one block of 2^40 bytes from 10 compressed bytes
        let mut h = Vec::new();
        for v in [1u64, 1 << 40, 1 << 40, 10] {
            h.extend(v.to_le_bytes());
        }
        h.extend([0u8; 10]);
        let mut src = Src::Raw {
            b: &h,
            pos: 0,
            base: 0,
            name: "t",
        };
        let f = Fmt {
            big: false,
            header: Ty::U64,
            zlib: true,
        };
        let e = format!(
            "{:#}",
            read_binary(
                &mut src,
                &f,
                "a",
                "t",
                &Need {
                    count: Count::AtMost(usize::MAX),
                    size: 1,
                    at: "t",
                },
            )
            .unwrap_err()
        );
        assert!(e.contains("compression header is corrupt"), "{e}");
    }
}
