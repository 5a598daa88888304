//! Byte scanning shared by the readers: whitespace tokens with line numbers, raw binary
//! reads with byte offsets, typed array decoding, and a cap for counts announced by a file.

use anyhow::{anyhow, Result};

/// A cursor over a file's bytes. Errors name the file and the line (text) of the cursor.
pub struct Scan<'a> {
    pub name: &'a str,
    pub b: &'a [u8],
    pub pos: usize,
    /// A byte that starts a comment running to the end of the line (`#` in TetGen and Medit).
    pub comment: Option<u8>,
}

impl<'a> Scan<'a> {
    pub fn new(name: &'a str, b: &'a [u8]) -> Self {
        Scan {
            name,
            b,
            pos: 0,
            comment: None,
        }
    }
    /// 1-based line number of a byte position.
    pub fn line_of(&self, pos: usize) -> usize {
        let end = pos.min(self.b.len());
        self.b[..end].iter().filter(|&&c| c == b'\n').count() + 1
    }
    pub fn line(&self) -> usize {
        self.line_of(self.pos)
    }
    /// `file:line: msg` at the cursor.
    pub fn err(&self, msg: impl std::fmt::Display) -> anyhow::Error {
        anyhow!("{}:{}: {}", self.name, self.line(), msg)
    }
    /// `file:line: msg` at a given position.
    pub fn err_at(&self, pos: usize, msg: impl std::fmt::Display) -> anyhow::Error {
        anyhow!("{}:{}: {}", self.name, self.line_of(pos), msg)
    }
    /// `file: byte N: msg`, for binary data.
    pub fn err_byte(&self, pos: usize, msg: impl std::fmt::Display) -> anyhow::Error {
        anyhow!("{}: byte {}: {}", self.name, pos, msg)
    }
    pub fn remaining(&self) -> usize {
        self.b.len().saturating_sub(self.pos)
    }
    pub fn at_end(&mut self) -> bool {
        self.skip_ws();
        self.pos >= self.b.len()
    }
    /// Skips whitespace and comments.
    pub fn skip_ws(&mut self) {
        while self.pos < self.b.len() {
            let c = self.b[self.pos];
            if c.is_ascii_whitespace() {
                self.pos += 1;
            } else if Some(c) == self.comment {
                while self.pos < self.b.len() && self.b[self.pos] != b'\n' {
                    self.pos += 1;
                }
            } else {
                break;
            }
        }
    }
    /// Skips spaces and tabs only (not newlines).
    pub fn skip_blanks(&mut self) {
        while self.pos < self.b.len()
            && (self.b[self.pos] == b' ' || self.b[self.pos] == b'\t' || self.b[self.pos] == b'\r')
        {
            self.pos += 1;
        }
    }
    /// The next whitespace-separated token, or None at the end.
    pub fn token(&mut self) -> Option<&'a [u8]> {
        self.skip_ws();
        let s = self.pos;
        while self.pos < self.b.len()
            && !self.b[self.pos].is_ascii_whitespace()
            && Some(self.b[self.pos]) != self.comment
        {
            self.pos += 1;
        }
        if self.pos > s {
            Some(&self.b[s..self.pos])
        } else {
            None
        }
    }
    /// Peeks at the next token without moving.
    pub fn peek(&mut self) -> Option<&'a [u8]> {
        let p = self.pos;
        let t = self.token();
        self.pos = p;
        t
    }
    /// The next token as text; truncation is an error naming `what`.
    pub fn word(&mut self, what: &str) -> Result<&'a str> {
        match self.token() {
            Some(t) => std::str::from_utf8(t)
                .map_err(|_| self.err(format!("unreadable bytes where {what} should be; fix: repair the file"))),
            None => Err(self.truncated(what)),
        }
    }
    pub fn truncated(&self, what: &str) -> anyhow::Error {
        anyhow!(
            "{}:{}: file ends while reading {what}; fix: the file is truncated or a count is too large, export it again",
            self.name,
            self.line_of(self.b.len())
        )
    }
    /// The next token parsed as a number.
    pub fn num<T: std::str::FromStr>(&mut self, what: &str) -> Result<T> {
        let w = self.word(what)?;
        w.parse::<T>()
            .map_err(|_| self.err(format!("cannot read `{}` as {what}; fix: repair the line", short(w))))
    }
    /// A count announced by the file (non-negative integer).
    pub fn count(&mut self, what: &str) -> Result<usize> {
        self.num::<usize>(what)
    }
    /// The rest of the current line (without the newline); moves past the newline.
    pub fn rest_of_line(&mut self) -> &'a [u8] {
        let s = self.pos;
        while self.pos < self.b.len() && self.b[self.pos] != b'\n' {
            self.pos += 1;
        }
        let l = &self.b[s..self.pos];
        if self.pos < self.b.len() {
            self.pos += 1;
        }
        l
    }
    /// The next line that is not blank, without the whitespace around it, and the position of
    /// its first byte; None at the end.
    pub fn next_line(&mut self) -> Option<(usize, &'a [u8])> {
        while self.pos < self.b.len() {
            let start = self.pos;
            let l = self.rest_of_line();
            let t = l.trim_ascii_start();
            if !t.is_empty() {
                return Some((start + (l.len() - t.len()), t.trim_ascii_end()));
            }
        }
        None
    }
    /// `n` raw bytes.
    pub fn raw(&mut self, n: usize, what: &str) -> Result<&'a [u8]> {
        if n > self.remaining() {
            return Err(anyhow!(
                "{}: byte {}: file ends while reading {what} ({n} bytes announced, {} left); fix: the file is truncated or a count is wrong, export it again",
                self.name,
                self.pos,
                self.remaining()
            ));
        }
        let s = &self.b[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }
}

/// Room for `n` more items in `v`, `n` coming from a file (and capped by what the file can
/// hold, see `cap`): an allocation that fails is an error naming memory, not an abort.
pub fn reserve<T>(v: &mut Vec<T>, n: usize, name: &str) -> Result<()> {
    v.try_reserve(n).map_err(|_| {
        anyhow!(
            "{name}: not enough memory for {n} more values of {} bytes; fix: free memory or use a machine with more",
            std::mem::size_of::<T>()
        )
    })
}

/// A count announced by a file, capped for pre-allocation: never more items than the
/// remaining bytes could hold at `min_bytes` each.
pub fn cap(count: usize, remaining: usize, min_bytes: usize) -> usize {
    count.min(remaining / min_bytes.max(1) + 1)
}

pub fn short(s: &str) -> String {
    match s.char_indices().nth(40) {
        Some((i, _)) => format!("{}...", &s[..i]),
        None => s.to_string(),
    }
}

/// Scalar types of VTK arrays.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ty {
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
    pub fn size(self) -> usize {
        match self {
            Ty::I8 | Ty::U8 => 1,
            Ty::I16 | Ty::U16 => 2,
            Ty::I32 | Ty::U32 | Ty::F32 => 4,
            Ty::I64 | Ty::U64 | Ty::F64 => 8,
        }
    }
    pub fn is_float(self) -> bool {
        matches!(self, Ty::F32 | Ty::F64)
    }
    /// XML type names (`Int32`, `Float64`, ...).
    pub fn from_xml(s: &str) -> Option<Ty> {
        Some(match s {
            "Int8" | "Char" => Ty::I8,
            "UInt8" | "UChar" => Ty::U8,
            "Int16" => Ty::I16,
            "UInt16" => Ty::U16,
            "Int32" => Ty::I32,
            "UInt32" => Ty::U32,
            "Int64" | "IdType" => Ty::I64,
            "UInt64" => Ty::U64,
            "Float32" => Ty::F32,
            "Float64" => Ty::F64,
            _ => return None,
        })
    }
    /// Legacy type names (`int`, `double`, `vtktypeint64`, ...).
    pub fn from_legacy(s: &str) -> Option<Ty> {
        Some(match s.to_ascii_lowercase().as_str() {
            "char" => Ty::I8,
            "unsigned_char" | "bit" => Ty::U8,
            "short" => Ty::I16,
            "unsigned_short" => Ty::U16,
            "int" => Ty::I32,
            "unsigned_int" => Ty::U32,
            "long" | "vtktypeint64" | "vtkidtype" => Ty::I64,
            "unsigned_long" | "vtktypeuint64" => Ty::U64,
            "float" => Ty::F32,
            "double" => Ty::F64,
            _ => return None,
        })
    }
}

/// Decoded array values.
#[derive(Clone, Debug)]
pub enum Vals {
    I(Vec<i64>),
    F(Vec<f64>),
}

impl Vals {
    pub fn len(&self) -> usize {
        match self {
            Vals::I(v) => v.len(),
            Vals::F(v) => v.len(),
        }
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    pub fn to_f64(&self) -> Vec<f64> {
        match self {
            Vals::I(v) => v.iter().map(|&x| x as f64).collect(),
            Vals::F(v) => v.clone(),
        }
    }
    /// Integer values; floats must be whole numbers in range.
    pub fn to_i64(&self) -> Option<Vec<i64>> {
        match self {
            Vals::I(v) => Some(v.clone()),
            Vals::F(v) => v
                .iter()
                .map(|&x| {
                    if x.fract() == 0.0 && x.abs() < 9.0e15 {
                        Some(x as i64)
                    } else {
                        None
                    }
                })
                .collect(),
        }
    }
}

/// Decodes `bytes` (a whole number of values) of type `ty`.
pub fn decode(bytes: &[u8], ty: Ty, big_endian: bool) -> Vals {
    let sz = ty.size();
    let mut chunks = bytes.chunks_exact(sz);
    macro_rules! conv {
        ($t:ty, $n:expr) => {{
            let mut a = [0u8; $n];
            chunks
                .by_ref()
                .map(|c| {
                    a.copy_from_slice(c);
                    if big_endian {
                        <$t>::from_be_bytes(a)
                    } else {
                        <$t>::from_le_bytes(a)
                    }
                })
                .collect::<Vec<$t>>()
        }};
    }
    match ty {
        Ty::I8 => Vals::I(bytes.iter().map(|&b| b as i8 as i64).collect()),
        Ty::U8 => Vals::I(bytes.iter().map(|&b| b as i64).collect()),
        Ty::I16 => Vals::I(conv!(i16, 2).into_iter().map(|x| x as i64).collect()),
        Ty::U16 => Vals::I(conv!(u16, 2).into_iter().map(|x| x as i64).collect()),
        Ty::I32 => Vals::I(conv!(i32, 4).into_iter().map(|x| x as i64).collect()),
        Ty::U32 => Vals::I(conv!(u32, 4).into_iter().map(|x| x as i64).collect()),
        Ty::I64 => Vals::I(conv!(i64, 8)),
        Ty::U64 => Vals::I(
            conv!(u64, 8)
                .into_iter()
                .map(|x| x.min(i64::MAX as u64) as i64)
                .collect(),
        ),
        Ty::F32 => Vals::F(conv!(f32, 4).into_iter().map(|x| x as f64).collect()),
        Ty::F64 => Vals::F(conv!(f64, 8)),
    }
}

/// Parses whitespace-separated text values of type `ty`.
pub fn parse_text(sc: &mut Scan, n: usize, ty: Ty, what: &str) -> Result<Vals> {
    let cap = cap(n, sc.remaining(), 2);
    if ty.is_float() {
        let mut v = Vec::new();
        reserve(&mut v, cap, sc.name)?;
        for _ in 0..n {
            v.push(sc.num::<f64>(what)?);
        }
        Ok(Vals::F(v))
    } else {
        let mut v = Vec::new();
        reserve(&mut v, cap, sc.name)?;
        for _ in 0..n {
            let w = sc.word(what)?;
            let x = match w.parse::<i64>() {
                Ok(x) => x,
                Err(_) => match w.parse::<u64>() {
                    Ok(x) => x.min(i64::MAX as u64) as i64,
                    Err(_) => {
                        return Err(sc.err(format!("cannot read `{}` as {what}; fix: repair the value", short(w))))
                    }
                },
            };
            v.push(x);
        }
        Ok(Vals::I(v))
    }
}

/// Cell-data array names preferred as cell tags, in order.
pub const TAG_NAMES: [&str; 8] = [
    "tissue",
    "tag",
    "gmsh:physical",
    "cellentityids",
    "label",
    "region",
    "material",
    "medit:ref",
];

/// Chooses the cell tag array among (name, values) arrays of one value per cell:
/// a preferred name first, else the first integer-valued one. Adds a warning saying which.
pub fn pick_tags(arrays: &[(String, Vals)], n_cells: usize, warnings: &mut Vec<String>) -> Option<Vec<i32>> {
    let usable: Vec<(&String, Vec<i64>)> = arrays
        .iter()
        .filter(|(_, v)| v.len() == n_cells)
        .filter_map(|(n, v)| v.to_i64().map(|i| (n, i)))
        .filter(|(_, i)| i.iter().all(|&x| i32::try_from(x).is_ok()))
        .collect();
    let pick = TAG_NAMES
        .iter()
        .find_map(|want| usable.iter().find(|(n, _)| n.to_ascii_lowercase() == *want))
        .or_else(|| usable.first())?;
    warnings.push(format!("cell tags taken from cell-data array `{}`", pick.0));
    Some(pick.1.iter().map(|&x| x as i32).collect())
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_reservation_too_large_for_memory_is_an_error_naming_memory() {
        let mut v: Vec<[f64; 3]> = Vec::new();
        let e = super::reserve(&mut v, usize::MAX / 64, "big.msh")
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("big.msh: not enough memory") && e.contains("fix:"), "{e}");
        super::reserve(&mut v, 10, "small.msh").unwrap();
        assert!(v.capacity() >= 10);
    }
}
