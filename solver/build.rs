//! Detects hypre (the `amg` preconditioner of the implicit integrator) and PT-Scotch (the
//! `ptscotch` partitioner) at build time.
//!
//! hypre is used when its headers are found (`HYPRE_DIR/include`, else `/usr/include/hypre`,
//! Debian's libhypre-dev) and its integer type is 32 bits (the declarations in
//! `src/linalg/amg.rs` use C `int`); `EPROP_HYPRE=0` builds without it. Without
//! hypre, `[integrator] preconditioner = "amg"` is refused with a message that says so.
//!
//! PT-Scotch is used when its header `scotch.h` is found (`SCOTCH_DIR/include`, else
//! `/usr/include/scotch`, Debian's libptscotch-dev) with 32-bit `SCOTCH_Num`, and its ParMETIS
//! V3 layer `libptscotchparmetisv3` beside it (`SCOTCH_DIR/lib`, else the system's library
//! directories); `EPROP_PTSCOTCH=0` builds without it. It is linked with plain `-l` flags
//! (`ptscotchparmetisv3`, `ptscotch`; the declarations are in `src/distribute/ptscotch.rs`).
//! Without it, `[performance] partitioner = "ptscotch"` falls back to METIS and says so.
//!
//! CHOLMOD (SuiteSparse; the real-time mode's direct solver, `src/linalg/direct.rs`) is used
//! when its header `cholmod.h` is found (`CHOLMOD_DIR/include`, else `/usr/include/suitesparse`,
//! Debian's libsuitesparse-dev); `EPROP_CHOLMOD=0` builds without it. The thin C layer
//! `src/linalg/cholmod.c` is compiled here and linked with `-lcholmod`. Without it, the
//! real-time mode solves with its fixed multigrid-preconditioned iterations.

use std::path::PathBuf;

fn main() {
    ptscotch();
    hypre();
    cholmod();
}

/// Sets `eprop_cholmod`, compiles `src/linalg/cholmod.c` and links CHOLMOD when its header is
/// found.
fn cholmod() {
    println!("cargo::rustc-check-cfg=cfg(eprop_cholmod)");
    println!("cargo::rerun-if-env-changed=EPROP_CHOLMOD");
    println!("cargo::rerun-if-env-changed=CHOLMOD_DIR");
    println!("cargo::rerun-if-changed=src/linalg/cholmod.c");
    if std::env::var("EPROP_CHOLMOD").is_ok_and(|v| v == "0") {
        return;
    }
    let dir = std::env::var_os("CHOLMOD_DIR").map(PathBuf::from);
    let includes: Vec<PathBuf> = match &dir {
        Some(d) => vec![d.join("include"), d.join("include/suitesparse")],
        None => vec![
            PathBuf::from("/usr/include/suitesparse"),
            PathBuf::from("/usr/local/include/suitesparse"),
            PathBuf::from("/usr/local/include"),
        ],
    };
    let Some(include) = includes.iter().find(|d| d.join("cholmod.h").is_file()) else {
        if dir.is_some() {
            panic!("CHOLMOD_DIR is set but no cholmod.h is under its include/; fix: point CHOLMOD_DIR at SuiteSparse's install prefix, or unset it");
        }
        return;
    };
    cc::Build::new()
        .file("src/linalg/cholmod.c")
        .include(include)
        .opt_level(2)
        .warnings(false)
        .compile("eprop_cholmod");
    if let Some(d) = &dir {
        println!("cargo::rustc-link-search=native={}", d.join("lib").display());
    }
    println!("cargo::rustc-link-lib=cholmod");
    println!("cargo::rustc-cfg=eprop_cholmod");
}

/// Sets `eprop_ptscotch` and the link flags when PT-Scotch's ParMETIS V3 layer is found.
fn ptscotch() {
    println!("cargo::rustc-check-cfg=cfg(eprop_ptscotch)");
    println!("cargo::rerun-if-env-changed=EPROP_PTSCOTCH");
    println!("cargo::rerun-if-env-changed=SCOTCH_DIR");
    if std::env::var("EPROP_PTSCOTCH").is_ok_and(|v| v == "0") {
        return;
    }
    let dir = std::env::var_os("SCOTCH_DIR").map(PathBuf::from);
    let (includes, libs): (Vec<PathBuf>, Vec<PathBuf>) = match &dir {
        Some(d) => (vec![d.join("include"), d.join("include/scotch")], vec![d.join("lib")]),
        None => (
            vec![
                PathBuf::from("/usr/include/scotch"),
                PathBuf::from("/usr/local/include"),
            ],
            [
                "/usr/lib/x86_64-linux-gnu",
                "/usr/lib/aarch64-linux-gnu",
                "/usr/lib64",
                "/usr/lib",
                "/usr/local/lib",
            ]
            .iter()
            .map(PathBuf::from)
            .collect(),
        ),
    };
    let Some(header) = includes.iter().map(|d| d.join("scotch.h")).find(|p| p.is_file()) else {
        if dir.is_some() {
            panic!("SCOTCH_DIR is set but no scotch.h is under its include/; fix: point SCOTCH_DIR at PT-Scotch's install prefix, or unset it");
        }
        return;
    };
    let Some(lib) = libs
        .iter()
        .find(|d| d.join("libptscotchparmetisv3.so").is_file() || d.join("libptscotchparmetisv3.a").is_file())
    else {
        return;
    };
    println!("cargo::rerun-if-changed={}", header.display());
    let text = std::fs::read_to_string(&header).unwrap_or_default();
    let num = text
        .lines()
        .find_map(|l| {
            l.trim()
                .strip_prefix("typedef ")
                .and_then(|t| t.strip_suffix(" SCOTCH_Num;"))
        })
        .map(str::trim);
    if !matches!(num, Some("int" | "int32_t")) {
        println!(
            "cargo::warning=PT-Scotch at {} has SCOTCH_Num `{}`; eprop's binding needs 32-bit integers, so it is built without the ptscotch partitioner",
            header.display(),
            num.unwrap_or("?")
        );
        return;
    }
    if dir.is_some() {
        println!("cargo::rustc-link-search=native={}", lib.display());
    }
    println!("cargo::rustc-link-lib=ptscotchparmetisv3");
    println!("cargo::rustc-link-lib=ptscotch");
    println!("cargo::rustc-cfg=eprop_ptscotch");
}

/// Sets `eprop_hypre` when hypre with 32-bit integers is found.
fn hypre() {
    println!("cargo::rustc-check-cfg=cfg(eprop_hypre)");
    println!("cargo::rerun-if-env-changed=EPROP_HYPRE");
    println!("cargo::rerun-if-env-changed=HYPRE_DIR");
    if std::env::var("EPROP_HYPRE").is_ok_and(|v| v == "0") {
        return;
    }
    let dir = std::env::var_os("HYPRE_DIR").map(PathBuf::from);
    let candidates: Vec<PathBuf> = match &dir {
        Some(d) => vec![d.join("include"), d.join("include/hypre")],
        None => vec![
            PathBuf::from("/usr/include/hypre"),
            PathBuf::from("/usr/local/include/hypre"),
        ],
    };
    let Some(config) = candidates
        .iter()
        .map(|d| d.join("HYPRE_config.h"))
        .find(|p| p.is_file())
    else {
        if dir.is_some() {
            panic!("HYPRE_DIR is set but no HYPRE_config.h is under its include/; fix: point HYPRE_DIR at hypre's install prefix, or unset it");
        }
        return;
    };
    println!("cargo::rerun-if-changed={}", config.display());
    let text = std::fs::read_to_string(&config).unwrap_or_default();
    let defined = |name: &str| {
        text.lines().any(|l| {
            let mut w = l.split_whitespace();
            w.next() == Some("#define") && w.next() == Some(name)
        })
    };
    if defined("HYPRE_BIGINT") || defined("HYPRE_MIXEDINT") {
        println!(
            "cargo::warning=hypre at {} uses 64-bit integers (HYPRE_BIGINT or HYPRE_MIXEDINT); eprop's binding needs 32-bit HYPRE_Int, so it is built without the amg preconditioner",
            config.display()
        );
        return;
    }
    if let Some(d) = &dir {
        println!("cargo::rustc-link-search=native={}", d.join("lib").display());
    }
    println!("cargo::rustc-cfg=eprop_hypre");
}
