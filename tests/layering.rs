//! The layers of `src/` import only downwards (DESIGN.md, "Layout"): every `use crate::…`, `use
//! super::…` and inline `crate::…` path of every file is read, resolved to the file it names, and
//! checked against the table of what each top-level module may use; and the file graph has no cycle.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// What each top-level module of `src/` may use (besides itself), layer by layer.
const MAY_USE: &[(&str, &[&str])] = &[
    // vocabulary
    ("error", &[]),
    ("util", &["error"]),
    ("config", &["util", "error"]),
    // state and scenes
    ("physics", &["util", "error", "config"]),
    ("scenes", &["util", "error", "config", "physics"]),
    // mechanics and models
    ("metrics", &["util", "error", "config", "physics"]),
    ("estimator", &["util", "error", "config", "physics"]),
    ("serialise", &["util", "error", "config", "physics"]),
    ("ranks", &["util", "error", "config", "physics", "serialise"]),
    (
        "pipeline",
        &["util", "error", "config", "physics", "metrics", "serialise", "ranks"],
    ),
    (
        "balance",
        &["util", "error", "config", "physics", "metrics", "estimator"],
    ),
    ("io", &["util", "error", "config", "physics", "scenes", "metrics"]),
    // a run
    (
        "timeloop",
        &[
            "util",
            "ranks",
            "error",
            "config",
            "physics",
            "scenes",
            "pipeline",
            "metrics",
            "estimator",
            "balance",
        ],
    ),
    (
        "study",
        &[
            "util",
            "ranks",
            "error",
            "config",
            "physics",
            "scenes",
            "pipeline",
            "metrics",
            "estimator",
            "balance",
            "serialise",
            "timeloop",
        ],
    ),
    (
        "checkpoint",
        &[
            "util",
            "ranks",
            "error",
            "config",
            "physics",
            "scenes",
            "metrics",
            "balance",
            "serialise",
            "timeloop",
        ],
    ),
    // the commands
    (
        "app",
        &[
            "util",
            "ranks",
            "error",
            "config",
            "physics",
            "scenes",
            "pipeline",
            "metrics",
            "estimator",
            "balance",
            "serialise",
            "io",
            "timeloop",
            "study",
            "checkpoint",
        ],
    ),
];

fn src() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("src")
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).expect("src readable").flatten() {
        let p = e.path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The module path of a file (`physics/coupling/mod.rs` → [physics, coupling]).
fn module_of(rel: &Path) -> Vec<String> {
    let mut parts: Vec<String> = rel.iter().map(|s| s.to_string_lossy().to_string()).collect();
    let last = parts.pop().expect("a file name");
    let stem = last.trim_end_matches(".rs").to_string();
    if stem != "mod" && stem != "lib" && stem != "main" {
        parts.push(stem);
    }
    parts
}

/// The paths of a `use` tree (`crate::{a::b, c::{d, e}}` → crate::a::b, crate::c::d, crate::c::e).
fn expand(tree: &str) -> Vec<String> {
    let t = tree.trim();
    let Some(open) = t.find('{') else {
        return vec![t.split(" as ").next().unwrap_or(t).trim().to_string()];
    };
    let (prefix, inner) = (&t[..open], &t[open + 1..t.rfind('}').unwrap_or(t.len())]);
    let (mut parts, mut depth, mut cur) = (Vec::new(), 0, String::new());
    for ch in inner.chars() {
        match ch {
            '{' => depth += 1,
            '}' => depth -= 1,
            _ => {}
        }
        if ch == ',' && depth == 0 {
            parts.push(std::mem::take(&mut cur));
        } else {
            cur.push(ch);
        }
    }
    parts.push(cur);
    parts
        .iter()
        .filter(|p| !p.trim().is_empty())
        .flat_map(|p| expand(&format!("{prefix}{}", p.trim())))
        .collect()
}

/// The text without its `#[cfg(test)]` items (the item after the attribute, to its matching brace or
/// its semicolon).
fn without_tests(text: &str) -> String {
    let mut out = String::new();
    let mut lines = text.lines();
    while let Some(l) = lines.next() {
        if !l.trim().starts_with("#[cfg(test)]") {
            out.push_str(l);
            out.push('\n');
            continue;
        }
        let (mut depth, mut started) = (0i64, false);
        for l in lines.by_ref() {
            depth += l.matches('{').count() as i64 - l.matches('}').count() as i64;
            started |= l.contains('{');
            if (started && depth <= 0) || (!started && l.trim_end().ends_with(';')) {
                break;
            }
        }
    }
    out
}

/// Every module path a file's code names through `crate::` or `super::` (test modules excluded), made
/// absolute.
fn references(text: &str, me: &[String]) -> Vec<Vec<String>> {
    let code = without_tests(text);
    let mut out = Vec::new();
    let resolve = |path: &str| -> Option<Vec<String>> {
        let segs: Vec<&str> = path.split("::").map(str::trim).collect();
        match segs.first() {
            Some(&"crate") => Some(segs[1..].iter().map(|s| s.to_string()).collect()),
            Some(&"super") => {
                // `super` of module m is m's parent, whether m is a file or a folder's mod.rs.
                let ups = segs.iter().take_while(|s| **s == "super").count();
                let base = &me[..me.len().saturating_sub(ups)];
                let mut p: Vec<String> = base.to_vec();
                p.extend(segs[ups..].iter().map(|s| s.to_string()));
                Some(p)
            }
            _ => None,
        }
    };
    let mut stmt = String::new();
    for line in code.lines() {
        let l = line.trim();
        if l.starts_with("//") {
            continue;
        }
        if !stmt.is_empty() || l.starts_with("use ") || l.starts_with("pub use ") || l.starts_with("pub(crate) use ") {
            stmt.push_str(l);
            stmt.push(' ');
            if l.contains(';') {
                let body = stmt
                    .trim_start_matches("pub(crate) ")
                    .trim_start_matches("pub ")
                    .trim_start_matches("use ");
                for p in expand(body.trim().trim_end_matches(';')) {
                    out.extend(resolve(&p));
                }
                stmt.clear();
            }
            continue;
        }
        for (i, _) in l.match_indices("crate::") {
            if i > 0 && l[..i].ends_with(|c: char| c.is_alphanumeric() || c == '_' || c == ':') {
                continue;
            }
            let rest: String = l[i..]
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_' || *c == ':')
                .collect();
            out.extend(resolve(rest.trim_end_matches(':')));
        }
        for (i, _) in l.match_indices("super::") {
            if i > 0 && l[..i].ends_with(|c: char| c.is_alphanumeric() || c == '_' || c == ':') {
                continue;
            }
            let rest: String = l[i..]
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_' || *c == ':')
                .collect();
            out.extend(resolve(rest.trim_end_matches(':')));
        }
    }
    out
}

struct Graph {
    /// File (relative to src/) → the files it names.
    edges: BTreeMap<String, BTreeSet<String>>,
}

fn graph() -> Graph {
    let root = src();
    let mut files = Vec::new();
    rust_files(&root, &mut files);
    let modules: BTreeMap<Vec<String>, String> = files
        .iter()
        .map(|f| {
            let rel = f.strip_prefix(&root).expect("under src");
            (module_of(rel), rel.to_string_lossy().to_string())
        })
        .collect();
    let mut edges = BTreeMap::new();
    for f in &files {
        let rel = f.strip_prefix(&root).expect("under src");
        let me = module_of(rel);
        let name = rel.to_string_lossy().to_string();
        let text = std::fs::read_to_string(f).expect("readable");
        let mut to = BTreeSet::new();
        for path in references(&text, &me) {
            // The longest prefix of the path that is a module file.
            if let Some(file) = (1..=path.len()).rev().find_map(|k| modules.get(&path[..k])) {
                if *file != name {
                    to.insert(file.clone());
                }
            }
        }
        edges.insert(name, to);
    }
    Graph { edges }
}

fn top(file: &str) -> &str {
    file.split('/').next().unwrap_or(file).trim_end_matches(".rs")
}

#[test]
fn every_module_imports_only_what_its_layer_may_use() {
    let g = graph();
    let allowed: BTreeMap<&str, &[&str]> = MAY_USE.iter().copied().collect();
    let mut bad = Vec::new();
    for (from, to) in &g.edges {
        let m = top(from);
        if m == "lib" || m == "main" {
            continue;
        }
        let may = allowed
            .get(m)
            .unwrap_or_else(|| panic!("top-level module {m} ({from}) is not in the layer table"));
        for t in to {
            let n = top(t);
            if n != m && !may.contains(&n) {
                bad.push(format!("{from} -> {t}"));
            }
        }
    }
    assert!(bad.is_empty(), "imports against the layering:\n{}", bad.join("\n"));
}

#[test]
fn nothing_imports_the_commands() {
    let g = graph();
    let into_app: Vec<String> = g
        .edges
        .iter()
        .filter(|(from, _)| top(from) != "app")
        .flat_map(|(from, to)| {
            to.iter()
                .filter(|t| top(t) == "app")
                .map(move |t| format!("{from} -> {t}"))
        })
        .filter(|e| !e.starts_with("main.rs"))
        .collect();
    assert!(into_app.is_empty(), "{into_app:?}");
}

/// Strongly connected components of the file graph (Tarjan), those with more than one file.
fn cycles(g: &Graph) -> Vec<Vec<String>> {
    struct S<'a> {
        g: &'a Graph,
        index: BTreeMap<&'a str, usize>,
        low: BTreeMap<&'a str, usize>,
        stack: Vec<&'a str>,
        on: BTreeSet<&'a str>,
        next: usize,
        out: Vec<Vec<String>>,
    }
    fn visit<'a>(s: &mut S<'a>, v: &'a str) {
        s.index.insert(v, s.next);
        s.low.insert(v, s.next);
        s.next += 1;
        s.stack.push(v);
        s.on.insert(v);
        if let Some(to) = s.g.edges.get(v) {
            for w in to {
                let w = w.as_str();
                if !s.index.contains_key(w) {
                    visit(s, w);
                    let lw = s.low[w];
                    let lv = s.low.get_mut(v).expect("visited");
                    *lv = (*lv).min(lw);
                } else if s.on.contains(w) {
                    let iw = s.index[w];
                    let lv = s.low.get_mut(v).expect("visited");
                    *lv = (*lv).min(iw);
                }
            }
        }
        if s.low[v] == s.index[v] {
            let mut comp = Vec::new();
            while let Some(w) = s.stack.pop() {
                s.on.remove(w);
                comp.push(w.to_string());
                if w == v {
                    break;
                }
            }
            if comp.len() > 1 {
                comp.sort();
                s.out.push(comp);
            }
        }
    }
    let mut s = S {
        g,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on: BTreeSet::new(),
        next: 0,
        out: Vec::new(),
    };
    for v in g.edges.keys() {
        if !s.index.contains_key(v.as_str()) {
            visit(&mut s, v);
        }
    }
    s.out
}

#[test]
fn no_file_cycle() {
    let c = cycles(&graph());
    assert!(c.is_empty(), "import cycles between files: {c:?}");
}

#[test]
fn the_reader_resolves_use_trees_and_inline_paths() {
    let me = vec!["physics".to_string(), "coupling".to_string(), "mapping".to_string()];
    let text = "use super::{cell_offset, min_image};\nuse crate::config::{self, SurfaceBoundary};\n\
                fn f() { crate::util::hash::mix(1); }\n#[cfg(test)]\nmod tests { use crate::app::run; }\n";
    let r = references(text, &me);
    let as_str: Vec<String> = r.iter().map(|p| p.join("::")).collect();
    assert!(
        as_str.contains(&"physics::coupling::cell_offset".to_string()),
        "{as_str:?}"
    );
    assert!(as_str.contains(&"config::SurfaceBoundary".to_string()), "{as_str:?}");
    assert!(as_str.contains(&"util::hash::mix".to_string()), "{as_str:?}");
    assert!(
        !as_str.iter().any(|p| p.starts_with("app")),
        "test code is not counted: {as_str:?}"
    );
}
