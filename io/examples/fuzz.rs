//! A mutation fuzzer for the mesh readers, for the stable toolchain.
//!
//! cargo run --release -p eprop-io --example fuzz -- --reader vtu --seconds 600 [--corpus DIR]
//! cargo run --release -p eprop-io --example fuzz -- --write-seeds tests/data/fuzz-seeds
//!
//! Seeds are small meshes in every encoding of the format (`testwrite::seeds`, kept as files
//! `<reader>-<name>` in tests/data/fuzz-seeds, which `--write-seeds` rewrites and
//! tests/formats.rs replays), plus files of DIR with a matching extension; each input is a mutation of a corpus entry (bit flips, byte inserts/deletes,
//! splices, number tweaks, truncation). It is parsed and, when it parses, validated, under
//! `catch_unwind`. Inputs that panic are written to tests/data/fuzz-regressions/<reader>-<hash>;
//! inputs that take longer than 2 s to <reader>-slow-<hash>; an allocation above 256 MiB or a
//! parse running over 20 s writes the input as <reader>-huge-/<reader>-hang-<hash> and aborts.
//! Inputs that give an error message not seen before join the corpus (a cheap stand-in for
//! coverage feedback).

use eprop_io::{parse_mesh, validate, Format, ReadOptions};
use std::alloc::{GlobalAlloc, Layout, System};
use std::collections::HashSet;
use std::hash::{Hash, Hasher};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicPtr, AtomicU64, AtomicUsize, Ordering::SeqCst};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

const ALLOC_LIMIT: usize = 256 << 20;
static CUR_PTR: AtomicPtr<u8> = AtomicPtr::new(std::ptr::null_mut());
static CUR_LEN: AtomicUsize = AtomicUsize::new(0);
static STARTED_MS: AtomicU64 = AtomicU64::new(0);
static DUMPING: AtomicBool = AtomicBool::new(false);
static OUT: OnceLock<(PathBuf, String)> = OnceLock::new();
static EPOCH: OnceLock<Instant> = OnceLock::new();

/// Writes the input being parsed as `<reader>-<kind>-<hash>` and aborts.
fn dump_and_abort(kind: &str) -> ! {
    let p = CUR_PTR.load(SeqCst);
    let n = CUR_LEN.load(SeqCst);
    if !p.is_null() {
        // SAFETY: CUR_PTR/CUR_LEN describe the input slice alive for the whole parse
        let data = unsafe { std::slice::from_raw_parts(p, n) };
        if let Some((dir, reader)) = OUT.get() {
            let f = dir.join(format!("{reader}-{kind}-{:016x}", hash(data)));
            let _ = std::fs::write(&f, data);
            eprintln!("fuzz: {kind} input written to {}", f.display());
        }
    }
    std::process::abort()
}

struct Guard;
unsafe impl GlobalAlloc for Guard {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        if l.size() > ALLOC_LIMIT && !DUMPING.swap(true, SeqCst) {
            dump_and_abort("huge");
        }
        System.alloc(l)
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        System.dealloc(p, l)
    }
    unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
        if l.size() > ALLOC_LIMIT && !DUMPING.swap(true, SeqCst) {
            dump_and_abort("huge");
        }
        System.alloc_zeroed(l)
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        if n > ALLOC_LIMIT && !DUMPING.swap(true, SeqCst) {
            dump_and_abort("huge");
        }
        System.realloc(p, l, n)
    }
}
#[global_allocator]
static GLOBAL: Guard = Guard;

fn hash(b: &[u8]) -> u64 {
    let mut h = std::collections::hash_map::DefaultHasher::new();
    b.hash(&mut h);
    h.finish()
}

struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    fn below(&mut self, n: usize) -> usize {
        if n == 0 {
            0
        } else {
            (self.next() % n as u64) as usize
        }
    }
}

const NUMBERS: [&str; 16] = [
    "0",
    "-1",
    "1",
    "2",
    "3",
    "255",
    "65536",
    "2147483647",
    "4294967295",
    "4294967296",
    "18446744073709551615",
    "9223372036854775807",
    "1e308",
    "nan",
    "inf",
    "-0",
];

fn mutate(r: &mut Rng, data: &[u8], other: &[u8]) -> Vec<u8> {
    let mut d = data.to_vec();
    let rounds = 1 + r.below(4);
    for _ in 0..rounds {
        let len = d.len();
        match r.below(11) {
            0 if len > 0 => {
                let i = r.below(len);
                d[i] ^= 1 << r.below(8);
            }
            1 if len > 0 => {
                let i = r.below(len);
                d[i] = [0u8, 0xff, 0x7f, 0x80, b'\n', b' ', b'<', b'$', b'=', b'_'][r.below(10)];
            }
            2 => {
                let i = r.below(len + 1);
                let n = 1 + r.below(8);
                let b = r.next() as u8;
                d.splice(i..i, std::iter::repeat_n(b, n));
            }
            3 if len > 0 => {
                let i = r.below(len);
                let n = (1 + r.below(16)).min(len - i);
                d.drain(i..i + n);
            }
            4 if len > 0 => {
                // duplicate a range
                let i = r.below(len);
                let n = (1 + r.below(64)).min(len - i);
                let chunk = d[i..i + n].to_vec();
                let j = r.below(len + 1);
                d.splice(j..j, chunk);
            }
            5 if !other.is_empty() && len > 0 => {
                // splice: our head, the other's tail
                let i = r.below(len);
                let j = r.below(other.len());
                d.truncate(i);
                d.extend_from_slice(&other[j..]);
            }
            6 | 7 if len > 0 => {
                // replace a number token with an interesting one
                let start = r.below(len);
                if let Some(p) = d[start..].iter().position(|c| c.is_ascii_digit()) {
                    let s = start + p;
                    let mut e = s;
                    while e < len && (d[e].is_ascii_digit() || d[e] == b'.' || d[e] == b'e' || d[e] == b'-') {
                        e += 1;
                    }
                    let rep = NUMBERS[r.below(NUMBERS.len())].as_bytes().to_vec();
                    d.splice(s..e, rep);
                }
            }
            8 if len > 0 => {
                // change one digit
                let start = r.below(len);
                if let Some(p) = d[start..].iter().position(|c| c.is_ascii_digit()) {
                    d[start + p] = b'0' + r.below(10) as u8;
                }
            }
            9 if len > 1 => d.truncate(r.below(len)),
            10 if len >= 8 => {
                // overwrite a binary word with an extreme value
                let i = r.below(len - 7);
                let v: u64 = [0, u64::MAX, 1 << 31, 1 << 40, 0x7fff_ffff][r.below(5)];
                d[i..i + 8].copy_from_slice(&v.to_le_bytes());
            }
            _ => {}
        }
    }
    d
}

/// A short shape of an error message: no file name, no digits.
fn shape(msg: &str) -> String {
    let m = msg.split_once(": ").map(|x| x.1).unwrap_or(msg);
    let mut out = String::new();
    let mut quoted = false;
    for c in m.chars() {
        if c == '`' {
            quoted = !quoted;
        } else if !quoted && !c.is_ascii_digit() {
            out.push(c);
        }
        if out.len() >= 60 {
            break;
        }
    }
    out
}

/// The prefix of each reader's files in tests/data (fuzz-seeds, fuzz-regressions).
const READERS: [(&str, Format); 5] = [
    ("gmsh", Format::Gmsh),
    ("vtk", Format::VtkLegacy),
    ("vtu", Format::Vtu),
    ("tetgen", Format::TetGen),
    ("medit", Format::Medit),
];

/// Writes every reader's seeds into `dir` as `<reader>-<name>`.
fn write_seeds(dir: &std::path::Path) {
    if let Err(e) = std::fs::create_dir_all(dir) {
        eprintln!("fuzz: {}: {e}", dir.display());
        std::process::exit(1);
    }
    let mut n = 0;
    for (reader, format) in READERS {
        for (name, bytes) in eprop_io::testwrite::seeds(format) {
            let p = dir.join(format!("{reader}-{name}"));
            if let Err(e) = std::fs::write(&p, bytes) {
                eprintln!("fuzz: {}: {e}", p.display());
                std::process::exit(1);
            }
            n += 1;
        }
    }
    println!("fuzz: {n} seeds written to {}", dir.display());
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let get = |k: &str| args.iter().position(|a| a == k).and_then(|i| args.get(i + 1)).cloned();
    if let Some(dir) = get("--write-seeds") {
        write_seeds(&PathBuf::from(dir));
        return;
    }
    let reader = get("--reader").unwrap_or_else(|| "vtu".into());
    let seconds: u64 = get("--seconds").and_then(|s| s.parse().ok()).unwrap_or(60);
    let Some(format) = READERS.iter().find(|r| r.0 == reader).map(|r| r.1) else {
        eprintln!("fuzz: --reader gmsh|vtk|vtu|tetgen|medit, or --write-seeds DIR");
        std::process::exit(2);
    };
    let out = get("--out")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../tests/data/fuzz-regressions"));
    let _ = std::fs::create_dir_all(&out);
    let _ = OUT.set((out.clone(), reader.clone()));
    let _ = EPOCH.set(Instant::now());
    let mut corpus: Vec<Vec<u8>> = eprop_io::testwrite::seeds(format).into_iter().map(|s| s.1).collect();
    if let Some(dir) = get("--corpus") {
        let exts: &[&str] = match format {
            Format::Gmsh => &["msh"],
            Format::VtkLegacy => &["vtk"],
            Format::Vtu => &["vtu"],
            Format::TetGen => &["tetgen"],
            Format::Medit => &["mesh"],
        };
        if let Ok(rd) = std::fs::read_dir(&dir) {
            for e in rd.flatten() {
                let p = e.path();
                let ok = p
                    .extension()
                    .and_then(|x| x.to_str())
                    .is_some_and(|x| exts.contains(&x));
                if ok && e.metadata().map(|m| m.len() < 300_000).unwrap_or(false) {
                    if let Ok(b) = std::fs::read(&p) {
                        corpus.push(b);
                    }
                }
            }
        }
    }
    let n_seeds = corpus.len();
    // watchdog: a parse running too long is dumped
    std::thread::spawn(|| loop {
        std::thread::sleep(Duration::from_millis(500));
        let s = STARTED_MS.load(SeqCst);
        let now = EPOCH.get().map(|e| e.elapsed().as_millis() as u64).unwrap_or(0);
        if s > 0 && now.saturating_sub(s) > 20_000 && !DUMPING.swap(true, SeqCst) {
            dump_and_abort("hang");
        }
    });
    std::panic::set_hook(Box::new(|_| {}));
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15 ^ (std::process::id() as u64) << 17 ^ hash(reader.as_bytes()));
    let mut shapes: HashSet<String> = HashSet::new();
    let mut crashes: HashSet<u64> = HashSet::new();
    let mut slow = 0usize;
    let (mut execs, mut oks) = (0u64, 0u64);
    let t0 = Instant::now();
    let deadline = Duration::from_secs(seconds);
    let mut last_report = Instant::now();
    while t0.elapsed() < deadline {
        let a = rng.below(corpus.len());
        let b = rng.below(corpus.len());
        let input = mutate(&mut rng, &corpus[a], &corpus[b]);
        CUR_PTR.store(input.as_ptr() as *mut u8, SeqCst);
        CUR_LEN.store(input.len(), SeqCst);
        let start = Instant::now();
        STARTED_MS.store(
            EPOCH.get().map(|e| e.elapsed().as_millis() as u64).unwrap_or(0).max(1),
            SeqCst,
        );
        let res = std::panic::catch_unwind(|| {
            parse_mesh(format, "fuzz", &input).and_then(|mut m| {
                validate(&mut m, &ReadOptions::default())?;
                Ok(m.warnings.len())
            })
        });
        STARTED_MS.store(0, SeqCst);
        let took = start.elapsed();
        execs += 1;
        let h = hash(&input);
        match res {
            Err(_) => {
                if crashes.insert(h) {
                    let f = out.join(format!("{reader}-{h:016x}"));
                    let _ = std::fs::write(&f, &input);
                    eprintln!("fuzz: panic, input written to {}", f.display());
                }
            }
            Ok(r) => {
                let key = match &r {
                    Ok(w) => format!("ok {w}"),
                    Err(e) => shape(&format!("{e:#}")),
                };
                if r.is_ok() {
                    oks += 1;
                }
                // the set of shapes is bounded: unquoted file text in messages can make it grow
                if shapes.len() > 200_000 {
                    shapes.clear();
                }
                if shapes.insert(key) && corpus.len() < 1000 && input.len() < 400_000 {
                    corpus.push(input.clone());
                }
            }
        }
        if took > Duration::from_secs(2) {
            slow += 1;
            let _ = std::fs::write(out.join(format!("{reader}-slow-{h:016x}")), &input);
            eprintln!("fuzz: slow input ({:.1} s)", took.as_secs_f64());
        }
        if last_report.elapsed() > Duration::from_secs(60) {
            last_report = Instant::now();
            eprintln!(
                "fuzz {reader}: {execs} execs, {} s, corpus {}, crashes {}",
                t0.elapsed().as_secs(),
                corpus.len(),
                crashes.len()
            );
        }
    }
    println!(
        "fuzz {reader}: {execs} execs in {} s ({:.0}/s), {oks} parsed and validated, seeds {n_seeds}, corpus {}, distinct panics {}, slow inputs {slow}",
        t0.elapsed().as_secs(),
        execs as f64 / t0.elapsed().as_secs_f64(),
        corpus.len(),
        crashes.len()
    );
}
