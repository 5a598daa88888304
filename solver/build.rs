//! Detects hypre (the `amg` preconditioner of the implicit integrator) at build time.
//!
//! hypre is used when its headers are found (`HYPRE_DIR/include`, else `/usr/include/hypre`,
//! Debian's libhypre-dev) and its integer type is 32 bits (the declarations in
//! `src/linalg/amg.rs` use C `int`); `EPROP_HYPRE=0` builds without it. Without
//! hypre, `[integrator] preconditioner = "amg"` is refused with a message that says so.

use std::path::PathBuf;

fn main() {
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
