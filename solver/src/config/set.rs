//! `--set KEY=VALUE`: a scenario key overridden on the command line.
//!
//! KEY is the key's TOML path, its tables joined by dots (`material.conductivity`,
//! `time.steps`); a table of an array of tables (`[[load]]`, `[[tool]]`, `[[fixed]]`,
//! `[[material.region]]`) is named by its 1-based index: `load.1.normal`. VALUE is a TOML
//! value (a number, `true`, a quoted string, an array); a bare word is taken as a string
//! (`model.scheme=paper`). The override edits the parsed document before the scenario is
//! checked, so every check of the file applies. The edited text, with one closing comment
//! line `# eprop --set KEY=VALUE` per override, is the scenario's text: it is what the series
//! stores and hashes (a --restart with other overrides is refused as a changed scenario), and
//! errors at an overridden value name `--set KEY` instead of a line.

use anyhow::{anyhow, bail, Result};
use std::ops::Range;
use toml_edit::{DocumentMut, ImDocument, Item, Table, TableLike, Value};

/// The comment line that records an override in the scenario text.
const MARK: &str = "# eprop --set ";

/// The scenario text with the overrides applied (the text itself when there are none, or when
/// it does not parse: the parser then reports the file's error at its line).
pub fn apply(text: &str, sets: &[String]) -> Result<String> {
    if sets.is_empty() {
        return Ok(text.to_string());
    }
    let Ok(mut doc) = text.parse::<DocumentMut>() else {
        return Ok(text.to_string());
    };
    for s in sets {
        let (key, raw) = split(s)?;
        let segs = segments(s, key)?;
        let value = value_of(key, raw)?;
        put(doc.as_table_mut(), &segs, value, key)?;
    }
    let mut out = doc.to_string();
    if !out.ends_with('\n') {
        out.push('\n');
    }
    for s in sets {
        let (key, raw) = split(s)?;
        out.push_str(&format!("{MARK}{key}={}\n", raw.trim().replace('\n', " ")));
    }
    Ok(out)
}

fn split(s: &str) -> Result<(&str, &str)> {
    let (key, raw) = s.split_once('=').ok_or_else(|| {
        anyhow!("--set {s}: not KEY=VALUE; fix: give the key's TOML path and a value, e.g. --set time.steps=50 or --set load.1.normal=2.0")
    })?;
    Ok((key.trim(), raw))
}

fn segments<'a>(s: &str, key: &'a str) -> Result<Vec<&'a str>> {
    let segs: Vec<&str> = key.split('.').map(str::trim).collect();
    if segs
        .iter()
        .any(|g| g.is_empty() || !g.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-'))
    {
        bail!("--set {s}: `{key}` is not a key path; fix: tables and keys joined by dots, an array of tables by its 1-based index, e.g. material.conductivity or load.1.normal");
    }
    Ok(segs)
}

/// VALUE as a TOML value; a bare word is a string.
fn value_of(key: &str, raw: &str) -> Result<Value> {
    let raw = raw.trim();
    if let Ok(v) = raw.parse::<Value>() {
        return Ok(v.decorated(" ", ""));
    }
    let word = !raw.is_empty() && raw.chars().all(|c| c.is_ascii_alphanumeric() || "_-.+".contains(c));
    if word && !raw.starts_with(|c: char| c.is_ascii_digit() || c == '-' || c == '+' || c == '.') {
        return Ok(Value::from(raw).decorated(" ", ""));
    }
    bail!(
        "--set {key}: `{raw}` is not a TOML value; fix: a number (2.0, 1e-4), true or false, a quoted string ('\"paper\"') or an array ([0.1, 0.05, 0.05])"
    )
}

fn put(cur: &mut dyn TableLike, segs: &[&str], value: Value, key: &str) -> Result<()> {
    let (first, rest) = (segs[0], &segs[1..]);
    if rest.is_empty() {
        match cur.get_mut(first) {
            Some(Item::Value(old)) => {
                let decor = old.decor().clone();
                *old = value;
                *old.decor_mut() = decor;
            }
            Some(Item::Table(_)) | Some(Item::ArrayOfTables(_)) => bail!(
                "--set {key}: `{first}` is a table, not a key; fix: name one of its keys, e.g. {key}.KEY{}",
                if matches!(cur.get(first), Some(Item::ArrayOfTables(_))) {
                    " after its 1-based index (load.1.normal)"
                } else {
                    ""
                }
            ),
            _ => {
                cur.insert(first, Item::Value(value));
            }
        }
        return Ok(());
    }
    if !cur.contains_key(first) {
        if rest[0].chars().all(|c| c.is_ascii_digit()) {
            // an entry of an array of tables the scenario does not have: a table made here
            // would be refused as a map where a sequence is expected, at a line past the end
            let table = key
                .split('.')
                .take_while(|g| *g != rest[0])
                .collect::<Vec<_>>()
                .join(".");
            bail!(
                "--set {key}: the scenario has no [[{table}]] table, so it has no entry {} to change; fix: add a [[{table}]] table with its keys to the scenario file (--set changes a key of an entry that exists)",
                rest[0]
            );
        }
        let mut t = Table::new();
        t.set_implicit(true);
        cur.insert(first, Item::Table(t));
    }
    match cur.get_mut(first) {
        Some(Item::ArrayOfTables(a)) => {
            let n = a.len();
            let k = rest[0].parse::<usize>().ok().filter(|&k| (1..=n).contains(&k)).ok_or_else(|| {
                anyhow!(
                    "--set {key}: `{first}` is an array of {n} tables [[{first}]]; fix: name one by its 1-based index 1..={n}, e.g. {first}.1.{}",
                    rest.last().filter(|_| rest.len() > 1).unwrap_or(&"KEY")
                )
            })?;
            if rest.len() < 2 {
                bail!("--set {key}: names a table, not a key; fix: add the key, e.g. {key}.KEY");
            }
            put(a.get_mut(k - 1).expect("index checked"), &rest[1..], value, key)
        }
        Some(item) => match item.as_table_like_mut() {
            Some(t) => put(t, rest, value, key),
            None => bail!("--set {key}: `{first}` is a value, not a table; fix: --set {first}=VALUE"),
        },
        None => bail!("--set {key}: `{first}` cannot be set"),
    }
}

/// The overrides recorded in a scenario text: each key and the byte range of its line (key
/// and value) in the text; empty for a file as written.
pub(crate) fn recorded(text: &str) -> Vec<(String, Range<usize>)> {
    let keys: Vec<String> = text
        .lines()
        .filter_map(|l| l.strip_prefix(MARK))
        .filter_map(|l| l.split_once('=').map(|(k, _)| k.trim().to_string()))
        .collect();
    if keys.is_empty() {
        return vec![];
    }
    let Ok(doc) = ImDocument::parse(text) else {
        return vec![];
    };
    keys.into_iter()
        .filter_map(|k| {
            let segs: Vec<&str> = k.split('.').collect();
            let span = locate(doc.as_table(), &segs)?;
            Some((k.clone(), span))
        })
        .collect()
}

/// The override that made the table whose header line holds byte `at`: a table the file does
/// not have, which `--set` adds at the end of the text (`--set time.dt=0.1` without [time]).
/// An error at its header (a table unknown, a key it lacks) would otherwise name a line past
/// the end of the file. A table is taken as made when every key it holds is an override.
pub(crate) fn made_by(text: &str, at: usize) -> Option<String> {
    let line_start = text.get(..at)?.rfind('\n').map_or(0, |i| i + 1);
    let line = text[line_start..].lines().next()?.trim();
    let name = line.strip_prefix('[')?.trim_start_matches('[');
    let name = name.split(']').next()?.trim();
    let keys: Vec<String> = recorded(text).into_iter().map(|(k, _)| k).collect();
    let doc = ImDocument::parse(text).ok()?;
    let mut cur: &dyn TableLike = doc.as_table();
    let mut segs: Vec<String> = Vec::new();
    for seg in name.split('.').map(str::trim) {
        segs.push(seg.to_string());
        cur = match cur.get(seg)? {
            // the entry whose header is this line: the last one above `at`
            Item::ArrayOfTables(a) => {
                let k = a
                    .iter()
                    .filter(|t| t.span().is_some_and(|s| s.start <= at))
                    .count()
                    .checked_sub(1)?;
                segs.push((k + 1).to_string());
                a.get(k)?
            }
            item => item.as_table_like()?,
        };
    }
    let prefix = segs.join(".");
    let own: Vec<String> = cur
        .iter()
        .filter(|(_, v)| v.is_value())
        .map(|(k, _)| format!("{prefix}.{k}"))
        .collect();
    (!own.is_empty() && own.iter().all(|k| keys.contains(k))).then(|| own[0].clone())
}

fn locate(cur: &dyn TableLike, segs: &[&str]) -> Option<Range<usize>> {
    let (first, rest) = (segs[0], &segs[1..]);
    if rest.is_empty() {
        let k = cur.key(first)?.span()?;
        let v = cur.get(first)?.span().unwrap_or(k.clone());
        return Some(k.start..v.end.max(k.end));
    }
    match cur.get(first)? {
        Item::ArrayOfTables(a) => {
            let k: usize = rest[0].parse().ok()?;
            locate(a.get(k.checked_sub(1)?)?, rest.get(1..).filter(|r| !r.is_empty())?)
        }
        item => locate(item.as_table_like()?, rest),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TEXT: &str = "[mesh]\nfile = \"cyl.msh\" # the mesh\n[[load]]\nnode = 3\nnormal = 1.0\n[[load]]\nnode = 4\n[time]\nsteps = 6\n";

    fn set(s: &[&str]) -> Result<String, String> {
        apply(TEXT, &s.iter().map(|s| s.to_string()).collect::<Vec<_>>()).map_err(|e| format!("{e:#}"))
    }

    #[test]
    fn a_set_edits_the_key_in_place_and_is_recorded() {
        let t = set(&[
            "time.steps=50",
            "load.2.normal=2.0",
            "material.conductivity=[0.1, 0.05, 0.05]",
            "model.scheme=paper",
        ])
        .unwrap();
        assert!(t.contains("steps = 50\n") && !t.contains("steps = 6"), "{t}");
        assert!(t.contains("node = 4\nnormal = 2.0\n"), "{t}");
        assert!(t.contains("[material]\nconductivity = [0.1, 0.05, 0.05]\n"), "{t}");
        assert!(t.contains("scheme = \"paper\""), "{t}");
        assert!(t.contains("file = \"cyl.msh\" # the mesh"), "{t}");
        assert!(t.ends_with("# eprop --set time.steps=50\n# eprop --set load.2.normal=2.0\n# eprop --set material.conductivity=[0.1, 0.05, 0.05]\n# eprop --set model.scheme=paper\n"), "{t}");
        let r = recorded(&t);
        assert_eq!(r.len(), 4);
        assert_eq!(&t[r[0].1.clone()], "steps = 50");
        assert_eq!(&t[r[1].1.clone()], "normal = 2.0");
        assert!(recorded(TEXT).is_empty());
        assert_eq!(set(&[]).unwrap(), TEXT);
    }

    #[test]
    fn a_bad_set_is_named_with_its_fix() {
        let e = set(&["time.steps"]).unwrap_err();
        assert!(e.starts_with("--set time.steps: not KEY=VALUE; fix:"), "{e}");
        let e = set(&["load.3.normal=1"]).unwrap_err();
        assert!(
            e.contains("array of 2 tables [[load]]; fix: name one by its 1-based index 1..=2"),
            "{e}"
        );
        let e = set(&["load.normal=1"]).unwrap_err();
        assert!(e.contains("1-based index"), "{e}");
        let e = set(&["time=1"]).unwrap_err();
        assert!(e.contains("`time` is a table, not a key"), "{e}");
        let e = set(&["time.steps=[1,"]).unwrap_err();
        assert!(
            e.starts_with("--set time.steps: `[1,` is not a TOML value; fix:"),
            "{e}"
        );
        let e = set(&["time..steps=1"]).unwrap_err();
        assert!(e.contains("is not a key path"), "{e}");
        // an entry of an array of tables the file does not have (it was refused at a line past
        // the end of the file)
        let e = set(&["tool.1.radius=1"]).unwrap_err();
        assert!(
            e.starts_with("--set tool.1.radius: the scenario has no [[tool]] table, so it has no entry 1 to change; fix: add a [[tool]] table"),
            "{e}"
        );
        let e = set(&["material.region.2.young=1"]).unwrap_err();
        assert!(e.contains("no [[material.region]] table, so it has no entry 2"), "{e}");
        // a table the overrides made: its header names the override, not a line
        let t = set(&["integrator.tolerance=0.1", "load.2.normal=3"]).unwrap();
        let at = |s: &str| t.rfind(s).unwrap() + 1;
        assert_eq!(made_by(&t, at("[integrator]")).as_deref(), Some("integrator.tolerance"));
        assert_eq!(made_by(&t, at("[[load]]")), None, "load 2 holds a key of the file");
        assert_eq!(made_by(&t, at("[mesh]")), None);
        let e = set(&["mesh.file.x=1"]).unwrap_err();
        assert!(e.contains("`file` is a value, not a table"), "{e}");
    }
}
