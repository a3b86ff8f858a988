//! `cargo xtask layers`: the top-level modules of each crate of the
//! workspace must not import each other in a circle, so that the code
//! stays layered: each module imports only modules below it.
//!
//! Read from the sources alone (no build, no cargo): the crate root
//! (`src/lib.rs`, `src/main.rs`; each its own module tree) declares the
//! top-level modules; the files of each are followed through its `mod`
//! declarations, and every path to a sibling (`crate::y`, `super::y`,
//! `crate::{y, z::w}`, `pub(in crate::y)`, `$crate::y`, and `crate::y` in
//! doc comments, which rustdoc resolves) is an edge. Names the root
//! re-exports (`pub use error::Error;` makes `crate::Error` mean `error`)
//! and `#[macro_export]` macros are followed to their module. Test-only
//! code (`#[cfg(test)]` items and modules) does not count.

use std::collections::BTreeMap;
use std::path::Path;

/// Checks every crate root of the workspace at `root`: prints a line per
/// crate, and the circles found with an example of each import in them.
pub fn check(root: &Path) -> Result<(), String> {
    let manifest = root.join("Cargo.toml");
    let manifest =
        std::fs::read_to_string(&manifest).map_err(|e| format!("cannot read {}: {e}", manifest.display()))?;
    let read = |path: &str| std::fs::read_to_string(root.join(path)).ok();
    let mut failing = Vec::new();
    for member in expand_members(root, &workspace_members(&manifest)) {
        let name = std::fs::read_to_string(root.join(&member).join("Cargo.toml"))
            .ok()
            .and_then(|m| package_name(&m))
            .unwrap_or_else(|| member.clone());
        for (file, kind) in [("src/lib.rs", ""), ("src/main.rs", " (bin)")] {
            let root_file = join(&member, file);
            if !root.join(&root_file).is_file() {
                continue;
            }
            let label = format!("{name}{kind}");
            let graph = Graph::scan(&root_file, &read);
            let (text, ok) = graph.report(&label);
            print!("{text}");
            if !ok {
                failing.push(label);
            }
        }
    }
    if failing.is_empty() {
        Ok(())
    } else {
        Err(format!(
            "layers: the top-level modules of {} import each other in circles (above); \
             each module should import only modules below it",
            failing.join(", ")
        ))
    }
}

/// `a/b`, or `b` when `a` is the workspace's root.
fn join(dir: &str, path: &str) -> String {
    match dir.trim_end_matches('/') {
        "" | "." => path.to_string(),
        dir => format!("{dir}/{path}"),
    }
}

/// The `members` of the root manifest's `[workspace]` table.
fn workspace_members(manifest: &str) -> Vec<String> {
    let mut in_workspace = false;
    let mut array: Option<String> = None;
    for line in manifest.lines() {
        // No `#` in the paths: what follows one is a comment.
        let line = line.split('#').next().unwrap_or("").trim();
        if let Some(array) = &mut array {
            array.push_str(line);
            if line.contains(']') {
                break;
            }
            continue;
        }
        if line.starts_with('[') {
            in_workspace = line == "[workspace]";
        } else if let Some((key, value)) = line.split_once('=') {
            if in_workspace && key.trim() == "members" {
                array = Some(value.to_string());
                if value.contains(']') {
                    break;
                }
            }
        }
    }
    let array = array.unwrap_or_default();
    let array = array.split(']').next().unwrap_or("");
    array.split('"').skip(1).step_by(2).map(|m| m.trim_end_matches('/').to_string()).collect()
}

/// Members as folders: `dir/*` is every folder in `dir` with a manifest.
fn expand_members(root: &Path, members: &[String]) -> Vec<String> {
    let mut out = Vec::new();
    for member in members {
        match member.strip_suffix("/*") {
            Some(dir) => {
                let mut found: Vec<String> = std::fs::read_dir(root.join(dir))
                    .into_iter()
                    .flatten()
                    .flatten()
                    .filter(|e| e.path().join("Cargo.toml").is_file())
                    .map(|e| join(dir, &e.file_name().to_string_lossy()))
                    .collect();
                found.sort();
                out.extend(found);
            }
            None => out.push(member.clone()),
        }
    }
    out
}

/// `name` in a manifest's `[package]` table.
fn package_name(manifest: &str) -> Option<String> {
    let mut in_package = false;
    for line in manifest.lines() {
        let line = line.trim();
        if line.starts_with('[') {
            in_package = line == "[package]";
        } else if let Some((key, value)) = line.split_once('=') {
            if in_package && key.trim() == "name" {
                return value.split('"').nth(1).map(str::to_string);
            }
        }
    }
    None
}

// ---------------------------------------------------------------- tokens

#[derive(Debug, Clone, PartialEq)]
enum Tok {
    Ident(String),
    /// `::`
    PathSep,
    Punct(char),
    /// A doc comment: the `crate::`/`super::`/`self::` paths in it, each
    /// with its line.
    Doc {
        inner: bool,
        paths: Vec<(Vec<String>, usize)>,
    },
}

#[derive(Debug, Clone)]
struct Token {
    tok: Tok,
    line: usize,
}

fn is_ident_start(c: char) -> bool {
    c.is_alphabetic() || c == '_'
}

fn is_ident_char(c: char) -> bool {
    c.is_alphanumeric() || c == '_'
}

/// The tokens of Rust source, enough to find paths: comments, string and
/// char literals, lifetimes and numbers are dropped; doc comments are kept
/// as the paths they mention.
fn tokenize(src: &str) -> Vec<Token> {
    let c: Vec<char> = src.chars().collect();
    let at = |i: usize| c.get(i).copied().unwrap_or('\0');
    let mut out = Vec::new();
    let mut line = 1;
    let mut i = 0;
    while i < c.len() {
        let ch = c[i];
        if ch == '\n' {
            line += 1;
            i += 1;
        } else if ch.is_whitespace() {
            i += 1;
        } else if ch == '/' && at(i + 1) == '/' {
            let end = (i..c.len()).find(|&j| c[j] == '\n').unwrap_or(c.len());
            let outer = at(i + 2) == '/' && at(i + 3) != '/';
            let inner = at(i + 2) == '!';
            if outer || inner {
                out.push(Token { tok: Tok::Doc { inner, paths: doc_paths(&c[i + 3..end], line) }, line });
            }
            i = end;
        } else if ch == '/' && at(i + 1) == '*' {
            let outer = at(i + 2) == '*' && at(i + 3) != '*' && at(i + 3) != '/';
            let inner = at(i + 2) == '!';
            let (start, start_line) = (i, line);
            let mut depth = 0;
            while i < c.len() {
                if c[i] == '/' && at(i + 1) == '*' {
                    depth += 1;
                    i += 2;
                } else if c[i] == '*' && at(i + 1) == '/' {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    if c[i] == '\n' {
                        line += 1;
                    }
                    i += 1;
                }
            }
            if outer || inner {
                let text = &c[(start + 3).min(i)..i.saturating_sub(2).max(start + 3).min(c.len())];
                out.push(Token { tok: Tok::Doc { inner, paths: doc_paths(text, start_line) }, line: start_line });
            }
        } else if ch == '"' {
            i = skip_string(&c, i + 1, &mut line);
        } else if ch == '\'' {
            if at(i + 1) == '\\' {
                // '\n', '\'', '\u{..}'
                i += 3;
                while i < c.len() && c[i] != '\'' {
                    i += 1;
                }
                i += 1;
            } else if at(i + 2) == '\'' {
                i += 3;
            } else {
                // A lifetime or a label.
                i += 1;
                while i < c.len() && is_ident_char(c[i]) {
                    i += 1;
                }
            }
        } else if is_ident_start(ch) {
            let start = i;
            while i < c.len() && is_ident_char(c[i]) {
                i += 1;
            }
            let ident: String = c[start..i].iter().collect();
            if matches!(ident.as_str(), "r" | "br" | "cr") && matches!(at(i), '"' | '#') {
                let hashes = (i..c.len()).take_while(|&j| c[j] == '#').count();
                if at(i + hashes) == '"' {
                    i = skip_raw_string(&c, i + hashes + 1, hashes, &mut line);
                    continue;
                }
                if ident == "r" && hashes == 1 && is_ident_start(at(i + 1)) {
                    // A raw identifier: r#type.
                    let start = i + 1;
                    i = start;
                    while i < c.len() && is_ident_char(c[i]) {
                        i += 1;
                    }
                    out.push(Token { tok: Tok::Ident(c[start..i].iter().collect()), line });
                    continue;
                }
            }
            // b"..", c"..": the string is skipped next; b'x' likewise.
            out.push(Token { tok: Tok::Ident(ident), line });
        } else if ch.is_ascii_digit() {
            while i < c.len() && is_ident_char(c[i]) {
                i += 1;
            }
        } else if ch == ':' && at(i + 1) == ':' {
            out.push(Token { tok: Tok::PathSep, line });
            i += 2;
        } else {
            out.push(Token { tok: Tok::Punct(ch), line });
            i += 1;
        }
    }
    out
}

/// Past the end of a string whose text starts at `i`.
fn skip_string(c: &[char], mut i: usize, line: &mut usize) -> usize {
    while i < c.len() {
        match c[i] {
            '\\' => {
                if c.get(i + 1) == Some(&'\n') {
                    *line += 1;
                }
                i += 2;
            }
            '"' => return i + 1,
            ch => {
                if ch == '\n' {
                    *line += 1;
                }
                i += 1;
            }
        }
    }
    i
}

/// Past the end of a raw string with `hashes` #s whose text starts at `i`.
fn skip_raw_string(c: &[char], mut i: usize, hashes: usize, line: &mut usize) -> usize {
    while i < c.len() {
        if c[i] == '"' && (1..=hashes).all(|k| c.get(i + k) == Some(&'#')) {
            return i + 1 + hashes;
        }
        if c[i] == '\n' {
            *line += 1;
        }
        i += 1;
    }
    i
}

/// The `crate::a::b`, `super::a`, `self::a` paths in the text of a doc
/// comment starting on `line`, each with its line.
fn doc_paths(text: &[char], mut line: usize) -> Vec<(Vec<String>, usize)> {
    let mut out = Vec::new();
    let mut i = 0;
    let ident_at = |i: usize| {
        let end = (i..text.len()).find(|&j| !is_ident_char(text[j])).unwrap_or(text.len());
        text[i..end].iter().collect::<String>()
    };
    let sep_at = |i: usize| text.get(i) == Some(&':') && text.get(i + 1) == Some(&':');
    while i < text.len() {
        if text[i] == '\n' {
            line += 1;
        }
        let boundary = i == 0 || !(is_ident_char(text[i - 1]) || text[i - 1] == ':');
        if boundary && is_ident_start(text[i]) {
            let first = ident_at(i);
            let mut j = i + first.chars().count();
            if matches!(first.as_str(), "crate" | "super" | "self") && sep_at(j) {
                let mut path = vec![first];
                while sep_at(j) && text.get(j + 2).is_some_and(|&c| is_ident_start(c)) {
                    let segment = ident_at(j + 2);
                    j += 2 + segment.chars().count();
                    path.push(segment);
                }
                out.push((path, line));
            }
            i = j.max(i + 1);
            continue;
        }
        i += 1;
    }
    out
}

// ------------------------------------------------------------- use trees

/// A path a use tree or a path in code names: `crate::{a::b, c}` has two.
#[derive(Debug, Clone, PartialEq)]
struct Leaf {
    path: Vec<String>,
    /// `as name`.
    rename: Option<String>,
    /// `path::*`.
    glob: bool,
    line: usize,
}

fn tok(toks: &[Token], i: usize) -> Option<&Tok> {
    toks.get(i).map(|t| &t.tok)
}

fn is_ident(toks: &[Token], i: usize, name: &str) -> bool {
    matches!(tok(toks, i), Some(Tok::Ident(s)) if s == name)
}

/// Reads the use tree (or path) at `i`, under `prefix`, into `out`;
/// returns where it ends.
fn use_tree(toks: &[Token], mut i: usize, prefix: &[String], out: &mut Vec<Leaf>) -> usize {
    let mut path = prefix.to_vec();
    let mut line = toks.get(i).map_or(0, |t| t.line);
    if tok(toks, i) == Some(&Tok::PathSep) {
        i += 1;
    }
    loop {
        match tok(toks, i) {
            Some(Tok::Ident(s)) => {
                path.push(s.clone());
                line = toks[i].line;
                i += 1;
                if tok(toks, i) == Some(&Tok::PathSep) {
                    i += 1;
                    continue;
                }
                let mut rename = None;
                if is_ident(toks, i, "as") {
                    if let Some(Tok::Ident(name)) = tok(toks, i + 1) {
                        rename = Some(name.clone());
                        i += 2;
                    }
                }
                out.push(Leaf { path, rename, glob: false, line });
                return i;
            }
            Some(Tok::Punct('{')) => {
                i += 1;
                loop {
                    match tok(toks, i) {
                        None => return i,
                        Some(Tok::Punct('}')) => return i + 1,
                        Some(Tok::Punct(',')) => i += 1,
                        Some(_) => {
                            let next = use_tree(toks, i, &path, out);
                            i = if next == i { i + 1 } else { next };
                        }
                    }
                }
            }
            Some(Tok::Punct('*')) => {
                out.push(Leaf { path, rename: None, glob: true, line });
                return i + 1;
            }
            _ => {
                // `crate::a::B::<T>`: the path ends at `<`.
                if path.len() > prefix.len() {
                    out.push(Leaf { path, rename: None, glob: false, line });
                }
                return i;
            }
        }
    }
}

/// The absolute path (from the crate root) of `path` named in module
/// `module`, for paths that start at `crate`, `super` or `self`.
fn resolve(path: &[String], module: &[String]) -> Option<Vec<String>> {
    let (mut abs, mut rest) = match path.first()?.as_str() {
        "crate" => (Vec::new(), &path[1..]),
        "super" | "self" => (module.to_vec(), path),
        _ => return None,
    };
    while let Some(segment) = rest.first() {
        match segment.as_str() {
            "self" => {}
            "super" => {
                abs.pop()?;
            }
            _ => break,
        }
        rest = &rest[1..];
    }
    abs.extend(rest.iter().filter(|s| *s != "self").cloned());
    Some(abs)
}

// ------------------------------------------------------------ attributes

/// Whether the attribute (the tokens inside `#[...]`) is `cfg(test)`, or
/// a `cfg(all(...))` with `test` in it: the item exists only in tests.
fn is_test_only(attr: &[Token]) -> bool {
    fn predicate(toks: &[Token], i: &mut usize) -> bool {
        let Some(Tok::Ident(name)) = tok(toks, *i) else {
            *i += 1;
            return false;
        };
        *i += 1;
        match tok(toks, *i) {
            Some(Tok::Punct('(')) => {
                *i += 1;
                let mut any_test_only = false;
                loop {
                    match tok(toks, *i) {
                        None => break,
                        Some(Tok::Punct(')')) => {
                            *i += 1;
                            break;
                        }
                        Some(Tok::Punct(',')) => *i += 1,
                        Some(_) => any_test_only |= predicate(toks, i),
                    }
                }
                name == "all" && any_test_only
            }
            Some(Tok::Punct('=')) => {
                // `feature = "x"`: the string is not a token.
                *i += 1;
                false
            }
            _ => name == "test",
        }
    }
    is_ident(attr, 0, "cfg") && tok(attr, 1) == Some(&Tok::Punct('(')) && predicate(attr, &mut 2)
}

/// Where the attribute `#[...]` / `#![...]` at `i` ends, and its inside.
fn attribute(toks: &[Token], i: usize) -> Option<(usize, &[Token], bool)> {
    let inner = tok(toks, i + 1) == Some(&Tok::Punct('!'));
    let open = if inner { i + 2 } else { i + 1 };
    if tok(toks, open) != Some(&Tok::Punct('[')) {
        return None;
    }
    let mut depth = 0;
    for j in open..toks.len() {
        match tok(toks, j) {
            Some(Tok::Punct('[')) => depth += 1,
            Some(Tok::Punct(']')) => {
                depth -= 1;
                if depth == 0 {
                    return Some((j + 1, &toks[open + 1..j], inner));
                }
            }
            _ => {}
        }
    }
    None
}

/// Whether an item keyword (after a visibility) starts at `i`.
fn starts_item(toks: &[Token], mut i: usize) -> bool {
    if is_ident(toks, i, "pub") {
        i += 1;
        if tok(toks, i) == Some(&Tok::Punct('(')) {
            while i < toks.len() && tok(toks, i) != Some(&Tok::Punct(')')) {
                i += 1;
            }
            i += 1;
        }
    }
    const ITEMS: &[&str] = &[
        "fn",
        "impl",
        "struct",
        "enum",
        "union",
        "const",
        "static",
        "type",
        "trait",
        "use",
        "mod",
        "unsafe",
        "extern",
        "macro_rules",
        "async",
        "let",
    ];
    matches!(tok(toks, i), Some(Tok::Ident(s)) if ITEMS.contains(&s.as_str()))
}

/// Past the end of the item (or field, match arm, statement) at `i`: a
/// `;` or a `{...}` block at its level; in a list (not at an item's
/// start), also a `,`. Stops before a bracket that closes its container.
fn skip_item(toks: &[Token], mut i: usize, item: bool) -> usize {
    let mut depth = 0usize;
    while i < toks.len() {
        match tok(toks, i) {
            Some(Tok::Punct('(' | '[' | '{')) => depth += 1,
            Some(Tok::Punct(close @ (')' | ']' | '}'))) => {
                if depth == 0 {
                    return i;
                }
                depth -= 1;
                if depth == 0 && *close == '}' {
                    i += 1;
                    if tok(toks, i) == Some(&Tok::Punct(';')) {
                        i += 1;
                    }
                    return i;
                }
            }
            Some(Tok::Punct(';')) if depth == 0 => return i + 1,
            Some(Tok::Punct(',')) if depth == 0 && !item => return i + 1,
            _ => {}
        }
        i += 1;
    }
    i
}

// ----------------------------------------------------------------- scan

/// A use of top-level module `to` (or of a name the root re-exports) in
/// top-level module `from`.
#[derive(Debug)]
struct Ref {
    from: String,
    to: String,
    file: String,
    line: usize,
}

/// A module open in the file being read.
struct Frame {
    /// Its path from the crate root.
    module: Vec<String>,
    /// The folder of its `mod x;` files.
    dir: String,
    /// The brace depth of its body.
    body: usize,
}

struct Scanner<'a> {
    read: &'a dyn Fn(&str) -> Option<String>,
    modules: Vec<String>,
    /// Names in the root (re-exports, `#[macro_export]` macros) -> the
    /// first segment of what they name.
    aliases: BTreeMap<String, String>,
    refs: Vec<Ref>,
    warnings: Vec<String>,
}

/// The folder of the `mod x;` files of the module in `path`: the file's
/// folder for a crate root or `mod.rs`, else the folder named as the file.
fn child_dir(path: &str) -> String {
    let (dir, file) = path.rsplit_once('/').unwrap_or(("", path));
    match file {
        "lib.rs" | "main.rs" | "mod.rs" => dir.to_string(),
        _ => join(dir, file.trim_end_matches(".rs")),
    }
}

impl Scanner<'_> {
    fn file(&mut self, path: &str, module: Vec<String>) {
        let Some(text) = (self.read)(path) else {
            self.warnings.push(format!("cannot read {path}"));
            return;
        };
        let toks = tokenize(&text);
        self.tokens(path, &toks, Frame { module, dir: child_dir(path), body: 0 });
    }

    fn record(&mut self, leaf_path: &[String], module: &[String], file: &str, line: usize) {
        let (Some(from), Some(abs)) = (module.first(), resolve(leaf_path, module)) else { return };
        if let Some(to) = abs.first() {
            self.refs.push(Ref { from: from.clone(), to: to.clone(), file: file.to_string(), line });
        }
    }

    fn docs(&mut self, paths: &[(Vec<String>, usize)], module: &[String], file: &str) {
        for (path, line) in paths {
            self.record(path, module, file, *line);
        }
    }

    fn tokens(&mut self, file: &str, toks: &[Token], top: Frame) {
        let mut stack = vec![top];
        let mut depth = 0usize;
        let mut i = 0;
        while i < toks.len() {
            let frame = stack.last().expect("the file's module");
            let at_item = depth == frame.body;
            match &toks[i].tok {
                Tok::Doc { inner: true, paths } => {
                    let module = frame.module.clone();
                    self.docs(paths, &module, file);
                    i += 1;
                }
                Tok::Punct('#') | Tok::Doc { inner: false, .. } => {
                    let inner = if tok(toks, i) == Some(&Tok::Punct('#')) { attribute(toks, i) } else { None };
                    if let Some((end, attr, true)) = inner {
                        if is_test_only(attr) && at_item {
                            // `#![cfg(test)]`: the whole module is for tests.
                            if stack.len() == 1 {
                                return;
                            }
                            i = end;
                            while i < toks.len() && tok(toks, i) != Some(&Tok::Punct('}')) {
                                i = skip_item(toks, i, true).max(i + 1);
                            }
                        } else {
                            i = end;
                        }
                        continue;
                    }
                    // The outer attributes and doc comments of one item.
                    let mut j = i;
                    let mut test_only = false;
                    let mut macro_export = false;
                    let mut docs = Vec::new();
                    loop {
                        match tok(toks, j) {
                            Some(Tok::Doc { inner: false, paths }) => {
                                docs.extend(paths.iter().cloned());
                                j += 1;
                            }
                            Some(Tok::Punct('#')) => match attribute(toks, j) {
                                Some((end, attr, false)) => {
                                    test_only |= is_test_only(attr);
                                    macro_export |= is_ident(attr, 0, "macro_export");
                                    j = end;
                                }
                                _ => break,
                            },
                            _ => break,
                        }
                    }
                    if j == i {
                        i += 1;
                        continue;
                    }
                    if test_only {
                        i = skip_item(toks, j, at_item || starts_item(toks, j));
                        continue;
                    }
                    let module = frame.module.clone();
                    self.docs(&docs, &module, file);
                    if macro_export && is_ident(toks, j, "macro_rules") {
                        if let (Some(Tok::Ident(name)), Some(from)) = (tok(toks, j + 2), module.first()) {
                            self.aliases.insert(name.clone(), from.clone());
                        }
                    }
                    i = j;
                }
                Tok::Ident(kw) if kw == "mod" => {
                    let Some(Tok::Ident(name)) = tok(toks, i + 1) else {
                        i += 1;
                        continue;
                    };
                    let mut module = frame.module.clone();
                    module.push(name.clone());
                    let is_root = frame.module.is_empty();
                    match tok(toks, i + 2) {
                        Some(Tok::Punct(';')) => {
                            if is_root && !self.modules.contains(name) {
                                self.modules.push(name.clone());
                            }
                            let candidates =
                                [join(&frame.dir, &format!("{name}.rs")), join(&frame.dir, &format!("{name}/mod.rs"))];
                            match candidates.iter().find(|p| (self.read)(p).is_some()) {
                                Some(path) => self.file(&path.clone(), module),
                                None => self.warnings.push(format!(
                                    "{file}:{}: `mod {name};` but neither {} nor {} exists",
                                    toks[i].line, candidates[0], candidates[1]
                                )),
                            }
                            i += 3;
                        }
                        Some(Tok::Punct('{')) => {
                            if is_root && !self.modules.contains(name) {
                                self.modules.push(name.clone());
                            }
                            let dir = join(&frame.dir, name);
                            depth += 1;
                            stack.push(Frame { module, dir, body: depth });
                            i += 3;
                        }
                        _ => i += 1,
                    }
                }
                Tok::Ident(kw) if kw == "use" && at_item && stack.len() == 1 && frame.module.is_empty() => {
                    // A name in the crate root: `crate::Name` means its module.
                    let mut leaves = Vec::new();
                    i = use_tree(toks, i + 1, &[], &mut leaves);
                    for leaf in leaves.iter().filter(|l| !l.glob) {
                        let path: Vec<&String> = leaf.path.iter().filter(|s| *s != "self").collect();
                        let start = usize::from(leaf.path.first().is_some_and(|s| s == "crate"));
                        let (Some(first), Some(last)) = (path.get(start), path.last()) else { continue };
                        let name = leaf.rename.as_ref().unwrap_or(last);
                        if name != "_" && name != *first {
                            self.aliases.insert(name.clone(), (*first).clone());
                        }
                    }
                }
                Tok::Ident(kw)
                    if matches!(kw.as_str(), "crate" | "super" | "self")
                        && tok(toks, i + 1) == Some(&Tok::PathSep)
                        && (i == 0 || tok(toks, i - 1) != Some(&Tok::PathSep)) =>
                {
                    let mut leaves = Vec::new();
                    i = use_tree(toks, i, &[], &mut leaves);
                    let module = frame.module.clone();
                    for leaf in leaves {
                        self.record(&leaf.path, &module, file, leaf.line);
                    }
                }
                Tok::Punct('{') => {
                    depth += 1;
                    i += 1;
                }
                Tok::Punct('}') => {
                    if depth == frame.body && stack.len() > 1 {
                        stack.pop();
                    }
                    depth = depth.saturating_sub(1);
                    i += 1;
                }
                _ => i += 1,
            }
        }
    }
}

// ---------------------------------------------------------------- graph

/// An import of one top-level module by another.
#[derive(Debug, Clone, PartialEq)]
pub struct Edge {
    /// Where the first use is, `path:line`.
    pub at: String,
    /// How many uses there are.
    pub count: usize,
}

/// The top-level modules of one crate root and their imports.
#[derive(Debug)]
pub struct Graph {
    /// In the order the root declares them.
    pub modules: Vec<String>,
    /// (importer, imported) -> the import, by index in `modules`.
    pub edges: BTreeMap<(usize, usize), Edge>,
    /// Modules whose files are missing, and the like.
    pub warnings: Vec<String>,
}

impl Graph {
    /// Reads the crate whose root file is `root` (a path `read` takes).
    pub fn scan(root: &str, read: &dyn Fn(&str) -> Option<String>) -> Graph {
        let mut scanner =
            Scanner { read, modules: Vec::new(), aliases: BTreeMap::new(), refs: Vec::new(), warnings: Vec::new() };
        scanner.file(root, Vec::new());
        let index = |name: &str| scanner.modules.iter().position(|m| m == name);
        let mut edges = BTreeMap::new();
        for r in &scanner.refs {
            let to = index(&r.to).or_else(|| scanner.aliases.get(&r.to).and_then(|m| index(m)));
            let (Some(from), Some(to)) = (index(&r.from), to) else { continue };
            if from != to {
                edges
                    .entry((from, to))
                    .or_insert_with(|| Edge { at: format!("{}:{}", r.file, r.line), count: 0 })
                    .count += 1;
            }
        }
        Graph { modules: scanner.modules, edges, warnings: scanner.warnings }
    }

    fn imports(&self) -> Vec<Vec<usize>> {
        let mut adj = vec![Vec::new(); self.modules.len()];
        for &(from, to) in self.edges.keys() {
            adj[from].push(to);
        }
        adj
    }

    /// The strongly connected components (Tarjan), each imported module's
    /// before its importers': bottom-up.
    pub fn components(&self) -> Vec<Vec<usize>> {
        struct Tarjan<'a> {
            adj: &'a [Vec<usize>],
            index: Vec<Option<usize>>,
            low: Vec<usize>,
            on_stack: Vec<bool>,
            stack: Vec<usize>,
            next: usize,
            out: Vec<Vec<usize>>,
        }
        impl Tarjan<'_> {
            fn visit(&mut self, v: usize) {
                self.index[v] = Some(self.next);
                self.low[v] = self.next;
                self.next += 1;
                self.stack.push(v);
                self.on_stack[v] = true;
                for &w in &self.adj[v] {
                    match self.index[w] {
                        None => {
                            self.visit(w);
                            self.low[v] = self.low[v].min(self.low[w]);
                        }
                        Some(iw) if self.on_stack[w] => self.low[v] = self.low[v].min(iw),
                        Some(_) => {}
                    }
                }
                if Some(self.low[v]) == self.index[v] {
                    let mut component = Vec::new();
                    while let Some(w) = self.stack.pop() {
                        self.on_stack[w] = false;
                        component.push(w);
                        if w == v {
                            break;
                        }
                    }
                    component.sort_unstable();
                    self.out.push(component);
                }
            }
        }
        let adj = self.imports();
        let n = adj.len();
        let mut t = Tarjan {
            adj: &adj,
            index: vec![None; n],
            low: vec![0; n],
            on_stack: vec![false; n],
            stack: Vec::new(),
            next: 0,
            out: Vec::new(),
        };
        for v in 0..n {
            if t.index[v].is_none() {
                t.visit(v);
            }
        }
        t.out
    }

    /// The circles: the components of more than one module.
    pub fn circles(&self) -> Vec<Vec<usize>> {
        self.components().into_iter().filter(|c| c.len() > 1).collect()
    }

    /// The components in layers, bottom-up: each imports only from the
    /// layers below it.
    pub fn layers(&self) -> Vec<Vec<Vec<usize>>> {
        let components = self.components();
        let mut component_of = vec![0; self.modules.len()];
        for (k, c) in components.iter().enumerate() {
            for &v in c {
                component_of[v] = k;
            }
        }
        let mut level = vec![0usize; components.len()];
        // Components come bottom-up: the levels of what one imports are known.
        for (k, c) in components.iter().enumerate() {
            level[k] = self
                .edges
                .keys()
                .filter(|(from, to)| c.contains(from) && component_of[*to] != k)
                .map(|&(_, to)| level[component_of[to]] + 1)
                .max()
                .unwrap_or(0);
        }
        let mut layers = vec![Vec::new(); level.iter().max().map_or(0, |l| l + 1)];
        for (k, c) in components.into_iter().enumerate() {
            layers[level[k]].push(c);
        }
        for layer in &mut layers {
            layer.sort();
        }
        layers
    }

    /// What `cargo xtask layers` prints for the crate `label`, and whether
    /// it has no circles.
    pub fn report(&self, label: &str) -> (String, bool) {
        let mut out = String::new();
        for w in &self.warnings {
            out += &format!("layers: warning: {w}\n");
        }
        let n = self.modules.len();
        let modules = if n == 1 { "module" } else { "modules" };
        let name = |v: &usize| self.modules[*v].as_str();
        let circles = self.circles();
        if circles.is_empty() {
            out += &format!("layers: {label}: {n} {modules}, no circles");
            if n > 1 {
                let layers: Vec<String> = self
                    .layers()
                    .iter()
                    .map(|layer| layer.iter().flatten().map(name).collect::<Vec<_>>().join(" "))
                    .collect();
                out += &format!("; bottom-up: {}", layers.join(" < "));
            }
            out += "\n";
            return (out, true);
        }
        let s = if circles.len() == 1 { "" } else { "s" };
        out += &format!("layers: {label}: {n} {modules}, {} circle{s}:\n", circles.len());
        for circle in &circles {
            let inside: Vec<(&(usize, usize), &Edge)> =
                self.edges.iter().filter(|((a, b), _)| circle.contains(a) && circle.contains(b)).collect();
            out += &format!(
                "  circle of {} modules, {} imports: {}\n",
                circle.len(),
                inside.len(),
                circle.iter().map(name).collect::<Vec<_>>().join(" ")
            );
            let width = inside.iter().map(|((a, b), _)| name(a).len() + name(b).len() + 4).max().unwrap_or(0);
            for ((a, b), edge) in inside {
                let arrow = format!("{} -> {}", name(a), name(b));
                let more = if edge.count > 1 { format!(" (and {} more)", edge.count - 1) } else { String::new() };
                out += &format!("    {arrow:width$}  {}{more}\n", edge.at);
            }
        }
        let layers: Vec<String> = self
            .layers()
            .iter()
            .map(|layer| {
                layer
                    .iter()
                    .map(|c| match c.as_slice() {
                        [v] => name(v).to_string(),
                        _ => format!("{{{}}}", c.iter().map(name).collect::<Vec<_>>().join(" ")),
                    })
                    .collect::<Vec<_>>()
                    .join(" ")
            })
            .collect();
        out += &format!("  bottom-up, circles in braces: {}\n", layers.join(" < "));
        (out, false)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The graph of a crate given as (path, text) pairs, `src/lib.rs` first.
    fn graph(files: &[(&str, &str)]) -> Graph {
        let files: BTreeMap<String, String> = files.iter().map(|(p, t)| (p.to_string(), t.to_string())).collect();
        Graph::scan("src/lib.rs", &|p| files.get(p).cloned())
    }

    /// The edges as `from->to` strings.
    fn edges(g: &Graph) -> Vec<String> {
        g.edges.keys().map(|(a, b)| format!("{}->{}", g.modules[*a], g.modules[*b])).collect()
    }

    const ROOT: &str = "mod a; mod b; mod c; mod d; mod e; mod f; mod g; mod x;";

    fn empty_modules() -> Vec<(&'static str, &'static str)> {
        ["a", "b", "c", "d", "e", "f", "g"]
            .iter()
            .map(|m| (Box::leak(format!("src/{m}.rs").into_boxed_str()) as &str, ""))
            .collect()
    }

    fn with_x(x: &'static str) -> Graph {
        let mut files = vec![("src/lib.rs", ROOT), ("src/x.rs", x)];
        files.extend(empty_modules());
        graph(&files)
    }

    #[test]
    fn groups_give_their_first_segments() {
        let toks = tokenize("crate::{a::b, c::{d, e}, f}");
        let mut leaves = Vec::new();
        let end = use_tree(&toks, 0, &[], &mut leaves);
        assert_eq!(end, toks.len());
        let firsts: Vec<&str> = leaves.iter().map(|l| l.path[1].as_str()).collect();
        assert_eq!(firsts, ["a", "c", "c", "f"]);

        let g = with_x("use crate::{\n    a::b,\n    c::{d, e},\n    f,\n};\nfn h() { crate::g::run(); }");
        assert_eq!(edges(&g), ["x->a", "x->c", "x->f", "x->g"]);
        let line = |m: &str| &g.edges[&(7, g.modules.iter().position(|n| n == m).unwrap())].at;
        assert_eq!(line("a"), "src/x.rs:2");
        assert_eq!(line("f"), "src/x.rs:4");
        assert_eq!(line("g"), "src/x.rs:6");
    }

    #[test]
    fn paths_in_visibilities_macros_and_generics() {
        let g = with_x(
            "pub(in crate::a) fn f() {}\n\
             pub(crate) fn g() -> crate::b::B::<u8> { $crate::c::m!() }\n\
             impl<'a> crate::d::T<'a> for X {}\n\
             use crate::e as renamed;\n\
             pub(super) fn h() {}",
        );
        assert_eq!(edges(&g), ["x->a", "x->b", "x->c", "x->d", "x->e"]);
    }

    #[test]
    fn super_resolves_by_module_depth() {
        let g = graph(&[
            ("src/lib.rs", "mod p; mod q; mod r; mod s; mod t; mod u; mod w;"),
            ("src/p.rs", "use super::q::Q;\nmod inner { use super::super::r; use super::Local; }\nmod deep;"),
            ("src/p/deep.rs", "use super::super::s::S; use super::super::super::t::Invalid; use super::Sibling;"),
            ("src/q/mod.rs", "use super::{r, u::U};\nmod z;"),
            ("src/q/z.rs", "fn f() { super::super::w::f(); self::g(); }"),
            ("src/r.rs", ""),
            ("src/s.rs", ""),
            ("src/t.rs", ""),
            ("src/u.rs", ""),
            ("src/w.rs", "mod inner { mod leaf; }"),
            ("src/w/inner/leaf.rs", "use super::super::super::p;"),
        ]);
        assert!(g.warnings.is_empty(), "{:?}", g.warnings);
        assert_eq!(edges(&g), ["p->q", "p->r", "p->s", "q->r", "q->u", "q->w", "w->p"]);
    }

    #[test]
    fn comments_strings_and_chars_are_not_code() {
        let g = with_x(
            r####"
            // crate::a::x
            /* crate::b /* nested crate::b */ still crate::b */
            const S: &str = "crate::c \" crate::c";
            const R: &str = r#"crate::d " crate::d"#;
            const B: &[u8] = b"crate::c";
            const Q: char = '"'; fn f() { crate::e::f() }
            const E: char = '\''; fn g<'a>(x: &'a str) { crate::f::f() }
            //// not a doc comment: crate::a
            /// A doc link is a dependency: [`crate::g::Thing`]; so is crate::x.
            fn h() {}
            "####,
        );
        assert_eq!(edges(&g), ["x->e", "x->f", "x->g"]);
    }

    #[test]
    fn test_only_code_does_not_count() {
        let mut files = vec![
            ("src/lib.rs", ROOT),
            (
                "src/x.rs",
                "#[cfg(test)]\nmod tests {\n    use crate::a;\n    fn f() { if true { crate::a::f() } }\n}\n\
                 #[cfg(test)] mod t;\n\
                 #[cfg(all(test, feature = \"x\"))] use crate::b;\n\
                 /// [`crate::c`]\n#[cfg(test)]\nfn helper() -> [u8; 2] { crate::c::f() }\n\
                 struct S { #[cfg(test)] field: crate::c::C, other: u8 }\n\
                 #[cfg(not(test))] use crate::d;\n\
                 #[cfg(any(test, unix))] use crate::e;\n\
                 #[cfg(feature = \"test\")] use crate::f;",
            ),
            ("src/x/t.rs", "use crate::g;"),
        ];
        files.extend(empty_modules());
        let g = graph(&files);
        assert_eq!(edges(&g), ["x->d", "x->e", "x->f"]);
        let g =
            graph(&[("src/lib.rs", "mod a; mod b;"), ("src/a.rs", "#![cfg(test)]\nuse crate::b;"), ("src/b.rs", "")]);
        assert!(g.edges.is_empty());
    }

    #[test]
    fn root_reexports_and_exported_macros_lead_to_their_module() {
        let g = graph(&[
            ("src/lib.rs", "mod error; mod m; mod x;\npub use error::{Error, Result as Res};\npub use std::fmt;"),
            ("src/error.rs", ""),
            ("src/m.rs", "#[macro_export]\nmacro_rules! shout { () => {} }"),
            ("src/x.rs", "use crate::{Error, fmt};\nfn f() -> crate::Res<()> { crate::shout!(); Ok(()) }"),
        ]);
        assert_eq!(edges(&g), ["x->error", "x->m"]);
        assert_eq!(g.edges[&(2, 0)].count, 2);
    }

    #[test]
    fn a_circle_is_found_and_reported() {
        let g = graph(&[
            ("src/lib.rs", "pub mod a;\npub mod b;\npub mod c;\npub mod d;\nmod inline { use crate::d; }"),
            ("src/a.rs", "use crate::b::B;"),
            ("src/b/mod.rs", "mod more;"),
            ("src/b/more.rs", "\n\nuse crate::c::C;\nfn f() { crate::c::g() }"),
            ("src/c.rs", "use crate::{a::A, d};"),
            ("src/d.rs", ""),
        ]);
        assert_eq!(g.modules, ["a", "b", "c", "d", "inline"]);
        assert_eq!(g.circles(), [vec![0, 1, 2]]);
        let (text, ok) = g.report("demo");
        assert!(!ok);
        assert!(text.contains("demo: 5 modules, 1 circle:"), "{text}");
        assert!(text.contains("circle of 3 modules, 3 imports: a b c"), "{text}");
        assert!(text.contains("a -> b  src/a.rs:1\n"), "{text}");
        assert!(text.contains("b -> c  src/b/more.rs:3 (and 1 more)\n"), "{text}");
        assert!(text.contains("c -> a  src/c.rs:1\n"), "{text}");
        assert!(!text.contains("c -> d"), "{text}");
        assert!(text.contains("bottom-up, circles in braces: d < {a b c} inline"), "{text}");
    }

    #[test]
    fn an_acyclic_crate_passes_with_its_layers() {
        let g = graph(&[
            ("src/lib.rs", "mod top; mod mid; mod base; mod other;"),
            ("src/top.rs", "use crate::mid; use crate::base;"),
            ("src/mid.rs", "use super::base::*;"),
            ("src/base.rs", "pub fn f() {}"),
            ("src/other.rs", "use crate::base;"),
        ]);
        assert!(g.circles().is_empty());
        let (text, ok) = g.report("demo");
        assert!(ok);
        assert_eq!(text, "layers: demo: 4 modules, no circles; bottom-up: base < mid other < top\n");
        let (text, ok) = graph(&[("src/lib.rs", "use cvd::x;")]).report("bin");
        assert!(ok);
        assert_eq!(text, "layers: bin: 0 modules, no circles\n");
    }

    #[test]
    fn a_missing_module_file_is_a_warning() {
        let g = graph(&[("src/lib.rs", "mod gone;")]);
        assert_eq!(g.warnings, ["src/lib.rs:1: `mod gone;` but neither src/gone.rs nor src/gone/mod.rs exists"]);
    }

    #[test]
    fn raw_identifiers_and_lifetimes() {
        let toks: Vec<Tok> =
            tokenize("r#type 'a 'b' b'c' br#\"x\"# '\\u{1F600}' 'é' '\\\\' x").into_iter().map(|t| t.tok).collect();
        assert_eq!(toks, [Tok::Ident("type".into()), Tok::Ident("b".into()), Tok::Ident("x".into())]);
    }

    #[test]
    fn workspace_members_are_read() {
        let manifest = "[package]\nmembers = [\"no\"]\n[workspace]\nresolver = \"2\"\nmembers = [\n  \"kernels\", # GPU\n  \"io/\",\n  \"crates/*\",\n]\ndefault-members = [\"host\"]\n";
        assert_eq!(workspace_members(manifest), ["kernels", "io", "crates/*"]);
        assert_eq!(workspace_members("[workspace]\nmembers = [\"a\", \"b\"]\n"), ["a", "b"]);
        assert_eq!(
            package_name("[package]\nname = \"cvd-kernels\"\n[dependencies]\nname = \"x\""),
            Some("cvd-kernels".into())
        );
        assert_eq!(child_dir("host/src/lib.rs"), "host/src");
        assert_eq!(child_dir("host/src/a.rs"), "host/src/a");
        assert_eq!(child_dir("host/src/a/mod.rs"), "host/src/a");
    }
}
