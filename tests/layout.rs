//! The crates' module layout: imports point one way, no file imports another that imports
//! it back (directly or round a longer loop), in the std crate and in the core; and in the
//! std crate's library the lab (`lab`) is imported by no other module, the jobs (`jobs`)
//! by none but the applications, the device drivers (`rig`) import none of the estimator,
//! the sources, the jobs or the line, and `anyhow` is the binary's only (`src/main.rs` and
//! `src/cli/`, which reach the library by its name).
//!
//! A file's imports are the `crate::`, `super::` and `self::` paths in its code (test
//! modules and comments left out), each resolved to the deepest file module it names.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The binary's files under `src/`: `main.rs` and the command line (`cli/`).
fn is_binary(rel: &Path) -> bool {
    rel == Path::new("main.rs") || rel.starts_with("cli")
}

/// Module path (e.g. `["solve", "sweep"]`) -> its file, the binary's files left out.
fn modules(root: &Path) -> BTreeMap<Vec<String>, PathBuf> {
    let mut out = BTreeMap::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).expect("source folder") {
            let path = entry.expect("entry").path();
            if path.is_dir() {
                stack.push(path);
                continue;
            }
            if path.extension().is_none_or(|e| e != "rs") {
                continue;
            }
            let rel = path.strip_prefix(root).expect("under root");
            if is_binary(rel) {
                continue;
            }
            let rel = rel.with_extension("");
            let mut parts: Vec<String> = rel
                .components()
                .map(|c| c.as_os_str().to_string_lossy().into_owned())
                .collect();
            match parts.last().map(String::as_str) {
                Some("mod") => {
                    parts.pop();
                }
                Some("lib" | "main") if parts.len() == 1 => parts.clear(),
                _ => {}
            }
            out.insert(parts, path);
        }
    }
    out
}

/// The code of a file without comments and without its `#[cfg(test)]` module.
fn code(text: &str) -> String {
    let mut out = String::new();
    for line in text.lines() {
        let line = match line.find("//") {
            Some(i) => &line[..i],
            None => line,
        };
        out.push_str(line);
        out.push('\n');
    }
    // A test module runs to the end of its file by convention here.
    if let Some(i) = out.find("#[cfg(test)]\nmod ") {
        out.truncate(i);
    }
    out
}

/// The paths a file names: `crate::a::b`, `super::c`, and each member of a `{...}` group.
fn paths(code: &str) -> Vec<Vec<String>> {
    let bytes = code.as_bytes();
    let mut out = Vec::new();
    let is_ident = |b: u8| b.is_ascii_alphanumeric() || b == b'_';
    let mut i = 0;
    while i < bytes.len() {
        let start_ok = i == 0 || !is_ident(bytes[i - 1]) && bytes[i - 1] != b':';
        let head = ["crate::", "super::", "self::"]
            .into_iter()
            .find(|h| bytes[i..].starts_with(h.as_bytes()));
        match head {
            Some(h) if start_ok => {
                let (ps, end) = parse_path(code, i, vec![h.trim_end_matches("::").to_owned()]);
                out.extend(ps);
                i = end.max(i + h.len());
            }
            _ => i += 1,
        }
    }
    out
}

/// Parses the path starting at `i` (its first segment already in `prefix`, still to be
/// skipped in the text); returns every full path and where it ended.
fn parse_path(code: &str, i: usize, prefix: Vec<String>) -> (Vec<Vec<String>>, usize) {
    let bytes = code.as_bytes();
    let mut j = i + prefix[0].len() + 2;
    let mut segs = prefix;
    loop {
        if bytes.get(j) == Some(&b'{') {
            // A group: split at top-level commas and parse each member.
            let mut depth = 0;
            let mut k = j;
            let mut members = Vec::new();
            let mut last = j + 1;
            while k < bytes.len() {
                match bytes[k] {
                    b'{' => depth += 1,
                    b'}' => {
                        depth -= 1;
                        if depth == 0 {
                            members.push(&code[last..k]);
                            break;
                        }
                    }
                    b',' if depth == 1 => {
                        members.push(&code[last..k]);
                        last = k + 1;
                    }
                    _ => {}
                }
                k += 1;
            }
            let mut out = Vec::new();
            for m in members {
                let m = m.trim();
                let name: String = m
                    .chars()
                    .take_while(|c| {
                        c.is_ascii_alphanumeric()
                            || *c == '_'
                            || *c == ':'
                            || *c == '{'
                            || *c == '}'
                            || *c == ','
                            || c.is_whitespace()
                    })
                    .collect();
                let mut p = segs.clone();
                for s in name.split("::").map(str::trim) {
                    let s: String = s
                        .chars()
                        .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                        .collect();
                    if s.is_empty() || s == "self" {
                        break;
                    }
                    p.push(s);
                }
                out.push(p);
            }
            return (out, k + 1);
        }
        let ident: String = code[j..]
            .chars()
            .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
            .collect();
        if ident.is_empty() {
            break;
        }
        j += ident.len();
        segs.push(ident);
        if code[j..].starts_with("::") {
            j += 2;
        } else {
            break;
        }
    }
    (vec![segs], j)
}

/// The file module a path names from module `from`: its deepest prefix that is a file.
fn resolve(
    files: &BTreeMap<Vec<String>, PathBuf>,
    from: &[String],
    path: &[String],
) -> Option<Vec<String>> {
    let mut abs: Vec<String> = match path.first().map(String::as_str) {
        Some("crate") => Vec::new(),
        Some("self") => from.to_vec(),
        _ => from.to_vec(),
    };
    let mut rest = &path[1..];
    if path.first().map(String::as_str) == Some("super") {
        abs.pop();
        while rest.first().map(String::as_str) == Some("super") {
            abs.pop();
            rest = &rest[1..];
        }
    }
    abs.extend(rest.iter().cloned());
    (0..=abs.len())
        .rev()
        .map(|n| abs[..n].to_vec())
        .find(|p| files.contains_key(p))
}

/// Every cycle's files (strongly connected components larger than one), by Tarjan.
fn cycles(edges: &BTreeMap<Vec<String>, BTreeSet<Vec<String>>>) -> Vec<Vec<String>> {
    struct T<'a> {
        edges: &'a BTreeMap<Vec<String>, BTreeSet<Vec<String>>>,
        index: BTreeMap<Vec<String>, usize>,
        low: BTreeMap<Vec<String>, usize>,
        stack: Vec<Vec<String>>,
        on: BTreeSet<Vec<String>>,
        out: Vec<Vec<String>>,
    }
    fn visit(t: &mut T<'_>, v: &Vec<String>) {
        let n = t.index.len();
        t.index.insert(v.clone(), n);
        t.low.insert(v.clone(), n);
        t.stack.push(v.clone());
        t.on.insert(v.clone());
        for w in t.edges.get(v).into_iter().flatten() {
            if !t.index.contains_key(w) {
                visit(t, w);
                let lw = t.low[w];
                let lv = t.low.get_mut(v).expect("visited");
                *lv = (*lv).min(lw);
            } else if t.on.contains(w) {
                let iw = t.index[w];
                let lv = t.low.get_mut(v).expect("visited");
                *lv = (*lv).min(iw);
            }
        }
        if t.low[v] == t.index[v] {
            let mut comp = Vec::new();
            while let Some(w) = t.stack.pop() {
                t.on.remove(&w);
                let done = &w == v;
                comp.push(w.join("::"));
                if done {
                    break;
                }
            }
            if comp.len() > 1 {
                comp.sort();
                t.out.push(comp);
            }
        }
    }
    let mut t = T {
        edges,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on: BTreeSet::new(),
        out: Vec::new(),
    };
    for v in edges.keys() {
        if !t.index.contains_key(v) {
            visit(&mut t, v);
        }
    }
    t.out
}

/// Each file's imports of other files of the crate at `root`.
fn graph(root: &Path) -> BTreeMap<Vec<String>, BTreeSet<Vec<String>>> {
    let files = modules(root);
    let mut edges: BTreeMap<Vec<String>, BTreeSet<Vec<String>>> = BTreeMap::new();
    for (module, path) in &files {
        let text = std::fs::read_to_string(path).expect("source");
        let targets = edges.entry(module.clone()).or_default();
        for p in paths(&code(&text)) {
            if let Some(t) = resolve(&files, module, &p) {
                // A module's own file and its parent's `mod.rs` (which only declares it)
                // are not imports.
                if &t != module && !t.is_empty() {
                    targets.insert(t);
                }
            }
        }
    }
    edges
}

/// Top-level modules of the std crate's library and the only other top-level modules that
/// may import them: nothing in the library imports the lab (the binary calls it by the
/// library's name), and only the applications (the lab and the production line; the
/// binary) import the jobs.
const ONLY_IMPORTED_BY: [(&str, &[&str]); 2] = [("lab", &[]), ("jobs", &["lab", "line"])];

/// Top-level modules of the std crate and the only other top-level modules they may
/// import: the device drivers (`rig`) stand below the estimator, its sources and the jobs,
/// using only the files, limits and records every layer shares.
const ONLY_IMPORTS: [(&str, &[&str]); 1] = [("rig", &["io", "limits", "record"])];

/// Each import in `edges` that breaks [`ONLY_IMPORTED_BY`] or [`ONLY_IMPORTS`], as
/// `importer -> imported`.
fn forbidden(edges: &BTreeMap<Vec<String>, BTreeSet<Vec<String>>>) -> Vec<String> {
    let top = |m: &[String]| m.first().cloned().unwrap_or_default();
    let mut out = Vec::new();
    for (from, targets) in edges {
        for to in targets {
            let (f, t) = (top(from), top(to));
            if f == t {
                continue;
            }
            let importer_barred = ONLY_IMPORTED_BY
                .iter()
                .any(|(g, allowed)| *g == t && !allowed.contains(&f.as_str()));
            let import_barred = ONLY_IMPORTS
                .iter()
                .any(|(g, allowed)| *g == f && !allowed.contains(&t.as_str()));
            if importer_barred || import_barred {
                out.push(format!("{} -> {}", from.join("::"), to.join("::")));
            }
        }
    }
    out
}

fn check(crate_dir: &str) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join(crate_dir);
    let edges = graph(&root);
    assert!(
        edges.len() > 10,
        "{}: found only {} files",
        root.display(),
        edges.len()
    );
    let found = cycles(&edges);
    assert!(
        found.is_empty(),
        "{}: import cycles between files: {found:?}",
        root.display()
    );
}

#[test]
fn the_std_crate_has_no_import_cycle() {
    check("src");
}

#[test]
fn the_layers_import_only_what_they_may() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let edges = graph(&root);
    for module in ONLY_IMPORTED_BY
        .iter()
        .chain(&ONLY_IMPORTS)
        .map(|(m, _)| *m)
    {
        assert!(
            edges.keys().any(|m| m.first().is_some_and(|t| t == module)),
            "{}: no module {module}",
            root.display()
        );
    }
    let found = forbidden(&edges);
    assert!(
        found.is_empty(),
        "{}: imports across the layers' rules (ONLY_IMPORTED_BY, ONLY_IMPORTS): {found:?}",
        root.display()
    );
}

/// The library's errors are typed: `anyhow` appears in no file of it, only in the binary's.
#[test]
fn anyhow_is_the_binarys_only() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let files = modules(&root);
    let using: Vec<&PathBuf> = files
        .values()
        .filter(|path| code(&std::fs::read_to_string(path).expect("source")).contains("anyhow"))
        .collect();
    assert!(
        files.len() > 10,
        "{}: found only {} files",
        root.display(),
        files.len()
    );
    assert!(using.is_empty(), "the library uses anyhow in {using:?}");
    let cli = std::fs::read_to_string(root.join("cli/commands.rs")).expect("the binary's code");
    assert!(
        cli.contains("anyhow"),
        "the check reads the binary's code apart"
    );
}

#[test]
fn the_core_has_no_import_cycle() {
    check("core/src");
}

/// The checker finds a cycle where there is one, and a group's members.
#[test]
fn a_cycle_is_found() {
    let p = |s: &str| s.split("::").map(str::to_owned).collect::<Vec<_>>();
    let files: BTreeMap<Vec<String>, PathBuf> = [p("a"), p("b"), p("c"), p("c::d")]
        .into_iter()
        .map(|m| (m, PathBuf::new()))
        .collect();
    let code = "use crate::{b::X, c::d::{self, Y}};\nfn f() { super::a::g() }";
    let named: Vec<Vec<String>> = paths(code)
        .iter()
        .filter_map(|x| resolve(&files, &p("c::d"), x))
        .collect();
    assert!(
        named.contains(&p("b")) && named.contains(&p("c::d")) && named.contains(&p("c")),
        "{named:?}"
    );
    let mut edges = BTreeMap::new();
    edges.insert(p("a"), BTreeSet::from([p("b")]));
    edges.insert(p("b"), BTreeSet::from([p("c")]));
    edges.insert(p("c"), BTreeSet::from([p("a")]));
    edges.insert(p("d"), BTreeSet::from([p("a")]));
    assert_eq!(
        cycles(&edges),
        vec![vec!["a".to_owned(), "b".into(), "c".into()]]
    );
}

/// The checker names an import of the lab or the jobs from where it is not allowed and an
/// import by the drivers of what they may not use, and lets the applications import the
/// jobs and each module import its own files.
#[test]
fn a_forbidden_import_is_found() {
    let p = |s: &str| s.split("::").map(str::to_owned).collect::<Vec<_>>();
    let mut edges = BTreeMap::new();
    edges.insert(
        p("lab::bench"),
        BTreeSet::from([p("lab::chart"), p("line::inspect"), p("jobs::estimate")]),
    );
    edges.insert(p("estimate"), BTreeSet::from([p("lab::eval"), p("io")]));
    edges.insert(p("line::inspect"), BTreeSet::from([p("lab"), p("jobs")]));
    edges.insert(p("report"), BTreeSet::from([p("jobs")]));
    edges.insert(p("source::live"), BTreeSet::from([p("jobs::estimate")]));
    edges.insert(
        p("rig::camlink"),
        BTreeSet::from([p("rig::error"), p("record::acquisition"), p("source")]),
    );
    assert_eq!(
        forbidden(&edges),
        vec![
            "estimate -> lab::eval".to_owned(),
            "line::inspect -> lab".into(),
            "report -> jobs".into(),
            "rig::camlink -> source".into(),
            "source::live -> jobs::estimate".into(),
        ]
    );
}
