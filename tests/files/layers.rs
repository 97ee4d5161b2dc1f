//! The layer check: no module uses a module it may not (the "Layers" table of ARCHITECTURE.md,
//! `../shared/design/ARCHITECTURE.md`, kept here as [`LAYERS`]), and no circle of files that
//! use each other.
//!
//! Every `src/**/*.rs` but `src/main.rs` (the binary, which reaches the library as `rig::`) is
//! read as text. Comments, doc comments, string and character literals are blanked first, and
//! every item marked `#[cfg(test)]` (the unit-test modules) is left out: tests may reach
//! further than the code they test (the Magician client's tests drive `sim::magician` over a
//! pseudo-terminal). What counts as a use: every path of a `use` declaration, and every path
//! in code that starts with `crate::`, `super::`, `self::`, a child module's name or a name a
//! `use` brought in. Paths are resolved to absolute module paths (`crate::a::b::Item`).
//!
//! - **Layers**: each file belongs to the [`LAYERS`] row whose path prefix is the longest
//!   match of its module path, and so does each path it uses. A use is allowed within the
//!   same row and towards every row the table lets it use, read transitively (a row may use
//!   what the rows it may use may use). Anything else is reported as
//!   `file:line: <row> may not use <row> (<path>)`, unless [`EXCEPTIONS`] names it with a
//!   reason. An exception no violation needs any more is reported too, so the list only
//!   shrinks when the code is fixed.
//! - **Circles**: file A uses file B when a use of A resolves to an item of B. A path through
//!   a re-export (`pub use`) resolves to the file that defines the item; the `pub use` itself
//!   is not a use of its own file. A strongly connected set of two or more files is a circle,
//!   reported with the uses that close it, unless [`KNOWN_CIRCLES`] lists it with a reason.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Marks a row that may use every row before it in [`LAYERS`].
const EVERYTHING_BELOW: &str = "*";

/// One row of the layer table: a part of the crate (the modules under `prefixes`) and the rows
/// it may use directly.
struct Layer {
    name: &'static str,
    prefixes: &'static [&'static str],
    may_use: &'static [&'static str],
}

/// The "Layers" table of ARCHITECTURE.md (`../shared/design/ARCHITECTURE.md`), from the ground
/// up, with the modules it does not name placed and the places where rig differs from it
/// marked "differs:" with the reason. Keep the two in step.
const LAYERS: &[Layer] = &[
    // Not in the table: the trust boundaries' helpers, under everything. `untrusted` (bounded
    // reads of files a user or a request names, parse errors without file contents) is in
    // [`FOUNDATION`]: every row reads files through it. `roots` (the folders a daemon job may
    // touch) is used by the jobs that confine their paths.
    // `confine` (the one opener for paths that requests, datasets, manifests, packages and
    // recordings name, and for the files the operator types) is in [`FOUNDATION`] too: every
    // row that reads such a path uses it, and `untrusted`'s bounded reads are made through it.
    Layer { name: "confine", prefixes: &["confine"], may_use: &[] },
    Layer { name: "untrusted", prefixes: &["untrusted"], may_use: &["confine"] },
    Layer { name: "roots", prefixes: &["roots"], may_use: &[] },
    // `bounds` (the range of every number a configuration holds, and the most pixels rig
    // decodes) is in [`FOUNDATION`]: the configuration, the firmware profiles, the Modbus
    // settings and the dataset readers check against it.
    Layer { name: "bounds", prefixes: &["bounds"], may_use: &[] },
    // `features` (the Cargo features of the build and the error of a command that needs one
    // left out) is in [`FOUNDATION`]: `synth` refuses to load a model without `synth`, the
    // CLI and the daemon refuse commands and jobs.
    Layer { name: "features", prefixes: &["features"], may_use: &[] },
    Layer { name: "pose", prefixes: &["pose"], may_use: &[] },
    // Time as a value (STYLE.md 5): the bottom row with `pose`.
    Layer { name: "clock", prefixes: &["clock"], may_use: &[] },
    Layer { name: "sensor", prefixes: &["sensor"], may_use: &[] },
    Layer { name: "imaging", prefixes: &["imaging"], may_use: &[] },
    Layer { name: "plan", prefixes: &["plan"], may_use: &["pose"] },
    Layer { name: "metrics", prefixes: &["metrics"], may_use: &["imaging"] },
    // The sans-io wire formats: the MG400's, and the Magician's (the same kind of codec).
    Layer { name: "arm::proto", prefixes: &["arm::dobot::proto", "arm::magician::proto"], may_use: &["pose"] },
    // differs: `clock`, which the clients take (STYLE.md 5).
    Layer { name: "arm", prefixes: &["arm"], may_use: &["arm::proto", "pose", "clock"] },
    // differs: `clock` (a frame carries its capture time on the rig clock) and `imaging` (a
    // settled capture may average its frames).
    Layer { name: "camera", prefixes: &["camera"], may_use: &["clock", "imaging"] },
    // Same row as `camera`; uses it: a serial port's USB identity and the device inventory
    // (`rig devices`) read `camera::usb`.
    Layer { name: "io", prefixes: &["io"], may_use: &["camera", "clock"] },
    // Not in the table: the rig TOML, raw then resolved (STYLE.md 13). It holds the settings of
    // the arm, the cameras, the Modbus peripherals and the collection, so it sits on them; its
    // `[sensors.<name>]` sections name sensors through `sensor`'s one parser.
    Layer { name: "config", prefixes: &["config"], may_use: &["pose", "sensor", "camera", "io"] },
    // Not in the table: the fence in front of the arm ("Trust boundaries": every pose that
    // reaches an arm checked against the firmware profile's workspace and the sensor's press
    // limit, in one place). It sits on the arm (the profile), the work frame, the plan's poses
    // and the configuration (the press limits); the calibration and the collection use it.
    Layer { name: "fence", prefixes: &["fence"], may_use: &["arm", "pose", "plan", "sensor", "config"] },
    // The calibration model (px/mm map, store): the bottom of `calibration`, under geometry.
    Layer { name: "calibration::model", prefixes: &["calibration::model"], may_use: &[] },
    Layer { name: "geometry", prefixes: &["geometry"], may_use: &["pose", "calibration::model"] },
    // differs: `sensor` (the detector and the contact fit's target are chosen per sensor kind)
    // and `config` (a press captures as the collection does: `CollectConfig`); `fence` (each
    // press is checked against the workspace and the press limit before the arm moves).
    Layer {
        name: "calibration",
        prefixes: &["calibration"],
        may_use: &["calibration::model", "geometry", "imaging", "arm", "camera", "sensor", "config", "fence"],
    },
    // differs: `camera` and `io` (the simulated sensors implement `Camera`; the simulated
    // Modbus devices are of an `io::modbus::SimPeripheralKind`) and `clock` (the simulated
    // controller runs on one). The firmware profile and kinematics: see EXCEPTIONS.
    Layer { name: "sim", prefixes: &["sim"], may_use: &["arm::proto", "geometry", "sensor", "imaging", "camera", "io", "clock"] },
    // differs: `plan`: the manifest records the plan (ARCHITECTURE.md, "Dataset on disk").
    Layer { name: "dataset", prefixes: &["dataset"], may_use: &["pose", "sensor", "plan"] },
    // differs: `config` (its settings), `io` (the Modbus peripherals around each capture, the
    // same row as `camera`) and `clock`.
    Layer { name: "collect", prefixes: &["collect"], may_use: &["arm", "camera", "io", "dataset", "plan", "config", "clock"] },
    Layer { name: "synth", prefixes: &["synth"], may_use: &["geometry", "dataset", "sensor"] },
    // differs: `geometry` (and through it the calibration model): pose recoverability measures
    // against the contact the mesh makes at the commanded pose, rendered through the
    // calibration.
    Layer { name: "eval", prefixes: &["eval"], may_use: &["metrics", "imaging", "dataset", "geometry"] },
    Layer { name: "record", prefixes: &["record"], may_use: &["arm", "camera", "collect"] },
    // Not in the table: a job's progress as a person reads it (a bar in a terminal, plain lines
    // in a log), named by object and sensor; the jobs and the CLI report through it.
    Layer { name: "progress", prefixes: &["progress"], may_use: &["sensor"] },
    Layer { name: "jobs", prefixes: &["jobs"], may_use: &[EVERYTHING_BELOW] },
    Layer { name: "rigs", prefixes: &["rigs"], may_use: &[EVERYTHING_BELOW] },
    // Not in the table: the exit code and message of a failed command, shared by the CLI and
    // the daemon; it classifies the errors of every module.
    Layer { name: "report", prefixes: &["report"], may_use: &[EVERYTHING_BELOW] },
    Layer { name: "daemon", prefixes: &["daemon"], may_use: &["jobs", "rigs", "report"] },
    Layer { name: "bench", prefixes: &["bench"], may_use: &["jobs", "rigs", "report"] },
    Layer { name: "cli", prefixes: &["cli"], may_use: &[EVERYTHING_BELOW] },
];

/// A use the table does not allow, allowed here with its reason: files under `file_prefix`
/// may use paths under `uses` (a module path without `crate::`).
struct Exception {
    file_prefix: &'static str,
    uses: &'static str,
    reason: &'static str,
}

const EXCEPTIONS: &[Exception] = &[
    Exception {
        file_prefix: "src/sim/mg400/",
        uses: "arm::profile",
        reason: "the simulated controller moves under the firmware profile the client checks against (workspace, speeds, trapezoids)",
    },
    Exception {
        file_prefix: "src/sim/mg400/",
        uses: "arm::kinematics",
        reason: "the simulated controller moves in joint space with the profile's kinematics",
    },
    Exception {
        file_prefix: "src/sim/mg400/",
        uses: "arm::dobot::alarms",
        reason: "the simulated controller raises the alarm ids the client resolves through the same table",
    },
];

/// A circle of files the check excuses: the files (sorted) and the reason.
struct KnownCircle {
    files: &'static [&'static str],
    reason: &'static str,
}

/// None now; a circle left for later goes here with its reason.
const KNOWN_CIRCLES: &[KnownCircle] = &[];

// ---------------------------------------------------------------------------------------------
// Reading the sources.

/// A token of the blanked source: an identifier or keyword, `::`, or one other character.
#[derive(Debug, Clone, PartialEq)]
enum Tok {
    Ident(String),
    PathSep,
    Punct(char),
}

/// One source file, read.
struct SourceFile {
    /// `src/...`, with `/` separators.
    rel: String,
    /// Its module path (`["dataset", "writer"]`; empty for `src/lib.rs`).
    module: Vec<String>,
    /// Modules declared in it (`mod x;`).
    children: BTreeSet<String>,
    /// Names its `use` declarations bring in: name -> absolute path.
    imports: BTreeMap<String, Vec<String>>,
    /// Every use: (line, absolute path, from a `pub use`).
    uses: Vec<Use>,
}

#[derive(Debug, Clone)]
struct Use {
    line: usize,
    path: Vec<String>,
    reexport: bool,
}

/// The source with comments, string and character literals replaced by spaces (newlines kept).
fn blank_non_code(src: &str) -> String {
    let c: Vec<char> = src.chars().collect();
    let mut out = String::with_capacity(src.len());
    let blank = |ch: char| if ch == '\n' { '\n' } else { ' ' };
    let mut i = 0;
    while i < c.len() {
        let next = c.get(i + 1).copied();
        if c[i] == '/' && next == Some('/') {
            while i < c.len() && c[i] != '\n' {
                out.push(' ');
                i += 1;
            }
        } else if c[i] == '/' && next == Some('*') {
            let mut depth = 0;
            while i < c.len() {
                if c[i] == '/' && c.get(i + 1) == Some(&'*') {
                    depth += 1;
                    out.push_str("  ");
                    i += 2;
                } else if c[i] == '*' && c.get(i + 1) == Some(&'/') {
                    depth -= 1;
                    out.push_str("  ");
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    out.push(blank(c[i]));
                    i += 1;
                }
            }
        } else if let Some(len) = raw_string_start(&c, i) {
            // r"..." / r#"..."# / br#"..."#: ends at a quote followed by as many hashes.
            let hashes = len - if c[i] == 'b' { 3 } else { 2 };
            for _ in 0..len {
                out.push(' ');
            }
            i += len;
            while i < c.len() {
                if c[i] == '"' && (0..hashes).all(|k| c.get(i + 1 + k) == Some(&'#')) {
                    for _ in 0..=hashes {
                        out.push(' ');
                    }
                    i += 1 + hashes;
                    break;
                }
                out.push(blank(c[i]));
                i += 1;
            }
        } else if c[i] == '"' || (c[i] == 'b' && next == Some('"') && !ident_char_before(&c, i)) {
            if c[i] == 'b' {
                out.push(' ');
                i += 1;
            }
            out.push(' ');
            i += 1;
            while i < c.len() && c[i] != '"' {
                if c[i] == '\\' {
                    out.push(' ');
                    i += 1;
                }
                if i < c.len() {
                    out.push(blank(c[i]));
                    i += 1;
                }
            }
            out.push(' ');
            i += 1;
        } else if c[i] == '\'' && (next == Some('\\') || c.get(i + 2) == Some(&'\'')) {
            // A character literal ('x', '\n', '\u{1F600}'); a lifetime ('a) has no closing quote.
            out.push(' ');
            i += 1;
            if c.get(i) == Some(&'\\') {
                out.push(' ');
                i += 1;
            }
            while i < c.len() && c[i] != '\'' {
                out.push(blank(c[i]));
                i += 1;
            }
            out.push(' ');
            i += 1;
        } else {
            out.push(c[i]);
            i += 1;
        }
    }
    out
}

fn ident_char_before(c: &[char], i: usize) -> bool {
    i > 0 && (c[i - 1].is_alphanumeric() || c[i - 1] == '_')
}

/// Length of the opening of a raw string at `i` (`r"`, `r#"`, `br##"`, ...), if one starts there.
fn raw_string_start(c: &[char], i: usize) -> Option<usize> {
    if ident_char_before(c, i) {
        return None;
    }
    let mut j = i;
    if c.get(j) == Some(&'b') {
        j += 1;
    }
    if c.get(j) != Some(&'r') {
        return None;
    }
    j += 1;
    while c.get(j) == Some(&'#') {
        j += 1;
    }
    (c.get(j) == Some(&'"')).then(|| j + 1 - i)
}

/// Tokens with their 1-based line.
fn tokenize(code: &str) -> Vec<(Tok, usize)> {
    let c: Vec<char> = code.chars().collect();
    let mut out = Vec::new();
    let (mut i, mut line) = (0, 1);
    while i < c.len() {
        let ch = c[i];
        if ch == '\n' {
            line += 1;
            i += 1;
        } else if ch.is_whitespace() {
            i += 1;
        } else if ch.is_alphabetic() || ch == '_' {
            let start = i;
            while i < c.len() && (c[i].is_alphanumeric() || c[i] == '_') {
                i += 1;
            }
            out.push((Tok::Ident(c[start..i].iter().collect()), line));
        } else if ch.is_ascii_digit() {
            while i < c.len() && (c[i].is_alphanumeric() || c[i] == '_' || c[i] == '.') {
                i += 1;
            }
        } else if ch == ':' && c.get(i + 1) == Some(&':') {
            out.push((Tok::PathSep, line));
            i += 2;
        } else {
            out.push((Tok::Punct(ch), line));
            i += 1;
        }
    }
    out
}

fn is_ident(t: Option<&(Tok, usize)>, name: &str) -> bool {
    matches!(t, Some((Tok::Ident(s), _)) if s == name)
}

fn is_punct(t: Option<&(Tok, usize)>, ch: char) -> bool {
    matches!(t, Some((Tok::Punct(p), _)) if *p == ch)
}

/// Index after the bracket group opening at `i` (`(`, `[` or `{`), or the end.
fn skip_group(toks: &[(Tok, usize)], i: usize) -> usize {
    let mut depth = 0i32;
    let mut j = i;
    while j < toks.len() {
        if let Tok::Punct(p) = &toks[j].0 {
            match p {
                '(' | '[' | '{' => depth += 1,
                ')' | ']' | '}' => {
                    depth -= 1;
                    if depth == 0 {
                        return j + 1;
                    }
                }
                _ => {}
            }
        }
        j += 1;
    }
    toks.len()
}

/// The tokens without the items marked `#[cfg(test)]`.
fn without_test_items(toks: Vec<(Tok, usize)>) -> Vec<(Tok, usize)> {
    let mut out = Vec::with_capacity(toks.len());
    let mut i = 0;
    while i < toks.len() {
        // `#[cfg(test)]`, `#[cfg(all(test, unix))]`: a predicate naming `test` without `not`
        // or `any` holds only in test builds.
        let cfg_end = (is_punct(toks.get(i), '#') && is_punct(toks.get(i + 1), '[') && is_ident(toks.get(i + 2), "cfg"))
            .then(|| skip_group(&toks, i + 1));
        let test_only = cfg_end.is_some_and(|end| {
            let predicate = &toks[i + 3..end];
            let has = |name: &str| predicate.iter().any(|t| matches!(&t.0, Tok::Ident(s) if s == name));
            has("test") && !has("not") && !has("any")
        });
        let Some(end) = cfg_end.filter(|_| test_only) else {
            out.push(toks[i].clone());
            i += 1;
            continue;
        };
        i = end;
        // Further attributes, then the item: up to its `;`, or through its `{ ... }`.
        while is_punct(toks.get(i), '#') && is_punct(toks.get(i + 1), '[') {
            i = skip_group(&toks, i + 1);
        }
        while i < toks.len() {
            if is_punct(toks.get(i), ';') {
                i += 1;
                break;
            }
            if is_punct(toks.get(i), '{') {
                i = skip_group(&toks, i);
                break;
            }
            if is_punct(toks.get(i), '(') || is_punct(toks.get(i), '[') {
                i = skip_group(&toks, i);
            } else {
                i += 1;
            }
        }
    }
    out
}

/// One leaf of a `use` tree: the path as written, and the name it brings in (`None` for a glob).
struct UseLeaf {
    path: Vec<String>,
    name: Option<String>,
}

/// Parses the `use` tree starting at `i` (after `use`); returns the leaves and the index after
/// the closing `;`.
fn parse_use_tree(toks: &[(Tok, usize)], mut i: usize, prefix: &[String], leaves: &mut Vec<UseLeaf>) -> usize {
    let mut path = prefix.to_vec();
    if matches!(toks.get(i), Some((Tok::PathSep, _))) {
        i += 1;
    }
    loop {
        match toks.get(i) {
            Some((Tok::Ident(s), _)) => {
                path.push(s.clone());
                i += 1;
                if matches!(toks.get(i), Some((Tok::PathSep, _))) {
                    i += 1;
                    continue;
                }
                let mut name = path.last().cloned();
                if is_ident(toks.get(i), "as") {
                    name = match toks.get(i + 1) {
                        Some((Tok::Ident(alias), _)) if alias != "_" => Some(alias.clone()),
                        _ => None,
                    };
                    i += 2;
                }
                if name.as_deref() == Some("self") {
                    path.pop();
                    name = path.last().cloned();
                }
                leaves.push(UseLeaf { path, name });
                return i;
            }
            Some((Tok::Punct('*'), _)) => {
                leaves.push(UseLeaf { path, name: None });
                return i + 1;
            }
            Some((Tok::Punct('{'), _)) => {
                i += 1;
                loop {
                    if is_punct(toks.get(i), '}') {
                        return i + 1;
                    }
                    if i >= toks.len() {
                        return i;
                    }
                    i = parse_use_tree(toks, i, &path, leaves);
                    if is_punct(toks.get(i), ',') {
                        i += 1;
                    }
                }
            }
            _ => return i,
        }
    }
}

/// The module path of a file under `src/` (`None` for `main.rs`).
fn module_of(rel: &Path) -> Option<Vec<String>> {
    let parts: Vec<String> = rel.iter().map(|p| p.to_string_lossy().into_owned()).collect();
    let (last, dirs) = parts.split_last()?;
    let stem = last.strip_suffix(".rs")?;
    let mut module = dirs.to_vec();
    match (dirs.is_empty(), stem) {
        (true, "main") => return None,
        (true, "lib") | (_, "mod") => {}
        _ => module.push(stem.to_string()),
    }
    Some(module)
}

fn rs_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<PathBuf> = std::fs::read_dir(dir).expect("read src").map(|e| e.expect("dir entry").path()).collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            rs_files(&p, out);
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p);
        }
    }
}

/// Resolves the first segment of a path written in `file` to an absolute module path; `None`
/// for a path into another crate.
fn absolute(file: &SourceFile, path: &[String]) -> Option<Vec<String>> {
    let (first, rest) = path.split_first()?;
    let mut base = match first.as_str() {
        "crate" => Vec::new(),
        "self" => file.module.clone(),
        "super" => {
            let mut m = file.module.clone();
            m.pop()?;
            let mut rest = rest;
            while rest.first().is_some_and(|s| s == "super") {
                m.pop()?;
                rest = &rest[1..];
            }
            m.extend(rest.iter().cloned());
            return Some(m);
        }
        name if file.children.contains(name) => {
            let mut m = file.module.clone();
            m.push(name.to_string());
            m
        }
        name => {
            let mut m = file.imports.get(name)?.clone();
            m.extend(rest.iter().cloned());
            return Some(m);
        }
    };
    base.extend(rest.iter().cloned());
    Some(base)
}

fn read_file(root: &Path, path: &Path) -> Option<(SourceFile, Vec<(Tok, usize)>)> {
    let rel = path.strip_prefix(root.join("src")).expect("under src");
    let module = module_of(rel)?;
    let text = std::fs::read_to_string(path).expect("read source");
    let toks = without_test_items(tokenize(&blank_non_code(&text)));
    let mut children = BTreeSet::new();
    for (k, t) in toks.iter().enumerate() {
        if matches!(t, (Tok::Ident(s), _) if s == "mod")
            && let Some((Tok::Ident(name), _)) = toks.get(k + 1)
            && is_punct(toks.get(k + 2), ';')
        {
            children.insert(name.clone());
        }
    }
    let rel = format!("src/{}", rel.iter().map(|p| p.to_string_lossy()).collect::<Vec<_>>().join("/"));
    Some((SourceFile { rel, module, children, imports: BTreeMap::new(), uses: Vec::new() }, toks))
}

/// Fills in the imports and the uses of `file` from its tokens.
fn scan_uses(file: &mut SourceFile, toks: &[(Tok, usize)]) {
    // `use` declarations first: their names resolve the paths in code.
    let mut declared: Vec<(usize, Vec<String>, bool)> = Vec::new();
    let mut in_use = vec![false; toks.len()];
    for k in 0..toks.len() {
        if !matches!(&toks[k], (Tok::Ident(s), _) if s == "use") || matches!(toks.get(k.wrapping_sub(1)), Some((Tok::PathSep, _))) {
            continue;
        }
        // `pub use` and `pub(crate) use` re-export.
        let reexport = is_ident(toks.get(k.wrapping_sub(1)), "pub")
            || (is_punct(toks.get(k.wrapping_sub(1)), ')') && (2..6).any(|b| is_ident(toks.get(k.wrapping_sub(b)), "pub")));
        let mut leaves = Vec::new();
        let end = parse_use_tree(toks, k + 1, &[], &mut leaves);
        for t in in_use.iter_mut().take(end.min(toks.len())).skip(k) {
            *t = true;
        }
        for leaf in leaves {
            declared.push((toks[k].1, leaf.path.clone(), reexport));
            if let Some(name) = leaf.name
                && let Some(abs) = absolute(file, &leaf.path)
            {
                file.imports.insert(name, abs);
            }
        }
    }
    for (line, path, reexport) in declared {
        if let Some(abs) = absolute(file, &path) {
            file.uses.push(Use { line, path: abs, reexport });
        }
    }
    // Paths in code: `a::b::c` not preceded by `::`.
    let mut k = 0;
    while k < toks.len() {
        let starts = !in_use[k]
            && matches!(&toks[k].0, Tok::Ident(_))
            && matches!(toks.get(k + 1), Some((Tok::PathSep, _)))
            && !matches!(toks.get(k.wrapping_sub(1)), Some((Tok::PathSep, _)));
        if !starts {
            k += 1;
            continue;
        }
        let line = toks[k].1;
        let mut path = Vec::new();
        while let Some((Tok::Ident(s), _)) = toks.get(k) {
            path.push(s.clone());
            k += 1;
            if !matches!(toks.get(k), Some((Tok::PathSep, _))) {
                break;
            }
            k += 1;
        }
        if let Some(abs) = absolute(file, &path) {
            file.uses.push(Use { line, path: abs, reexport: false });
        }
    }
}

fn read_sources() -> Vec<SourceFile> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut paths = Vec::new();
    rs_files(&root.join("src"), &mut paths);
    let mut files = Vec::new();
    for p in paths {
        if let Some((mut file, toks)) = read_file(&root, &p) {
            scan_uses(&mut file, &toks);
            files.push(file);
        }
    }
    files
}

// ---------------------------------------------------------------------------------------------
// The checks.

/// The row of a module path: the longest matching prefix (`None`: the crate root's own items).
fn row_of(path: &[String]) -> Option<&'static Layer> {
    let joined = path.join("::");
    LAYERS
        .iter()
        .flat_map(|l| l.prefixes.iter().map(move |p| (l, *p)))
        .filter(|(_, p)| joined == *p || joined.starts_with(&format!("{p}::")))
        .max_by_key(|(_, p)| p.len())
        .map(|(l, _)| l)
}

/// Rows every row may use (below them all in [`LAYERS`]).
const FOUNDATION: &[&str] = &["untrusted", "confine", "features", "bounds"];

/// Row name -> every row it may use (transitively), itself included.
fn allowed_rows() -> BTreeMap<&'static str, BTreeSet<&'static str>> {
    let index = |name: &str| LAYERS.iter().position(|l| l.name == name).unwrap_or_else(|| panic!("LAYERS names no row {name:?}"));
    let mut allowed: BTreeMap<&str, BTreeSet<&str>> = BTreeMap::new();
    for (i, layer) in LAYERS.iter().enumerate() {
        let mut set = BTreeSet::from([layer.name]);
        set.extend(FOUNDATION.iter().copied().filter(|f| index(f) < i));
        for used in layer.may_use {
            if *used == EVERYTHING_BELOW {
                set.extend(LAYERS[..i].iter().map(|l| l.name));
                continue;
            }
            assert!(index(used) < i, "LAYERS: {} may use {used}, which is not below it", layer.name);
            set.extend(allowed[used].iter().copied());
        }
        allowed.insert(layer.name, set);
    }
    allowed
}

#[test]
fn no_module_uses_one_above_it() {
    let files = read_sources();
    assert!(files.len() > 50, "read only {} files", files.len());
    let allowed = allowed_rows();
    let mut violations = Vec::new();
    let mut needed = vec![false; EXCEPTIONS.len()];
    for file in &files {
        if file.module.is_empty() {
            continue; // lib.rs: module declarations and `version()`
        }
        let Some(from) = row_of(&file.module) else {
            violations.push(format!("{}: module {} is not in LAYERS", file.rel, file.module.join("::")));
            continue;
        };
        for u in &file.uses {
            let Some(to) = row_of(&u.path) else { continue };
            if allowed[from.name].contains(to.name) {
                continue;
            }
            let used = u.path.join("::");
            let excused = EXCEPTIONS
                .iter()
                .position(|e| file.rel.starts_with(e.file_prefix) && (used == e.uses || used.starts_with(&format!("{}::", e.uses))));
            match excused {
                Some(i) => needed[i] = true,
                None => {
                    let line = format!("{}:{}: {} may not use {}", file.rel, u.line, from.name, to.name);
                    // One report per line and row, naming the first path.
                    if !violations.iter().any(|v: &String| v.starts_with(&format!("{line} ("))) {
                        violations.push(format!("{line} (crate::{used})"));
                    }
                }
            }
        }
    }
    for (e, needed) in EXCEPTIONS.iter().zip(needed) {
        if !needed {
            violations.push(format!("stale exception: nothing under {} uses {} any more ({})", e.file_prefix, e.uses, e.reason));
        }
    }
    assert!(violations.is_empty(), "{} layer violations:\n{}", violations.len(), violations.join("\n"));
}

/// The file that defines what `path` names: the deepest file module on it, then through that
/// file's imports (re-exports) as long as the rest of the path starts with one.
fn defining_file<'a>(files: &'a [SourceFile], by_module: &BTreeMap<Vec<String>, usize>, path: &[String]) -> Option<&'a SourceFile> {
    let mut path = path.to_vec();
    for _ in 0..16 {
        let depth = (0..=path.len()).rev().find(|&d| by_module.contains_key(&path[..d]))?;
        let file = &files[by_module[&path[..depth]]];
        match path.get(depth).and_then(|name| file.imports.get(name)) {
            Some(target) if path.len() > depth => {
                let mut next = target.clone();
                next.extend(path[depth + 1..].iter().cloned());
                if next == path {
                    return Some(file);
                }
                path = next;
            }
            _ => return Some(file),
        }
    }
    None
}

#[test]
fn no_circle_of_files() {
    let files = read_sources();
    let by_module: BTreeMap<Vec<String>, usize> = files.iter().enumerate().map(|(i, f)| (f.module.clone(), i)).collect();
    // File -> used file -> the first line of that use.
    let mut edges: Vec<BTreeMap<usize, usize>> = vec![BTreeMap::new(); files.len()];
    for (i, file) in files.iter().enumerate() {
        for u in file.uses.iter().filter(|u| !u.reexport) {
            if let Some(target) = defining_file(&files, &by_module, &u.path) {
                let j = by_module[&target.module];
                if j != i {
                    edges[i].entry(j).or_insert(u.line);
                }
            }
        }
    }
    let mut problems = Vec::new();
    let mut known = vec![false; KNOWN_CIRCLES.len()];
    for component in strongly_connected(&edges).into_iter().filter(|c| c.len() > 1) {
        let mut names: Vec<&str> = component.iter().map(|&i| files[i].rel.as_str()).collect();
        names.sort_unstable();
        if let Some(k) = KNOWN_CIRCLES.iter().position(|c| c.files == names.as_slice()) {
            known[k] = true;
            continue;
        }
        let mut lines = Vec::new();
        for &i in &component {
            for (&j, &line) in &edges[i] {
                if component.contains(&j) {
                    lines.push(format!("  {}:{line}: uses {}", files[i].rel, files[j].rel));
                }
            }
        }
        problems.push(format!("circle of {}:\n{}", names.join(", "), lines.join("\n")));
    }
    for (c, seen) in KNOWN_CIRCLES.iter().zip(known) {
        if !seen {
            problems.push(format!("stale known circle {:?} ({})", c.files, c.reason));
        }
    }
    assert!(problems.is_empty(), "{} import circles:\n{}", problems.len(), problems.join("\n"));
}

/// Tarjan's strongly connected components.
fn strongly_connected(edges: &[BTreeMap<usize, usize>]) -> Vec<Vec<usize>> {
    struct State<'a> {
        edges: &'a [BTreeMap<usize, usize>],
        index: Vec<Option<usize>>,
        low: Vec<usize>,
        on_stack: Vec<bool>,
        stack: Vec<usize>,
        next: usize,
        out: Vec<Vec<usize>>,
    }
    fn visit(s: &mut State, v: usize) {
        s.index[v] = Some(s.next);
        s.low[v] = s.next;
        s.next += 1;
        s.stack.push(v);
        s.on_stack[v] = true;
        for &w in s.edges[v].keys() {
            match s.index[w] {
                None => {
                    visit(s, w);
                    s.low[v] = s.low[v].min(s.low[w]);
                }
                Some(iw) if s.on_stack[w] => s.low[v] = s.low[v].min(iw),
                Some(_) => {}
            }
        }
        if Some(s.low[v]) == s.index[v] {
            let mut component = Vec::new();
            while let Some(w) = s.stack.pop() {
                s.on_stack[w] = false;
                component.push(w);
                if w == v {
                    break;
                }
            }
            s.out.push(component);
        }
    }
    let n = edges.len();
    let mut s =
        State { edges, index: vec![None; n], low: vec![0; n], on_stack: vec![false; n], stack: Vec::new(), next: 0, out: Vec::new() };
    for v in 0..n {
        if s.index[v].is_none() {
            visit(&mut s, v);
        }
    }
    s.out
}

#[test]
fn the_reader_sees_what_the_checks_rely_on() {
    // Comments, strings and test modules are not code; `use` trees expand; `super` resolves.
    let text = "//! crate::a in a doc\nuse super::{b::{self, C as D}, e::*};\nfn f() { let s = \"crate::g\"; let c = '\\''; \
                crate::h::i(); D::new(); }\n#[cfg(test)]\nmod tests { use crate::j; }\n";
    let toks = without_test_items(tokenize(&blank_non_code(text)));
    let mut file = SourceFile {
        rel: "src/x/y.rs".into(),
        module: vec!["x".into(), "y".into()],
        children: BTreeSet::new(),
        imports: BTreeMap::new(),
        uses: Vec::new(),
    };
    scan_uses(&mut file, &toks);
    let got: Vec<(usize, String)> = file.uses.iter().map(|u| (u.line, u.path.join("::"))).collect();
    let want = [(2, "x::b"), (2, "x::b::C"), (2, "x::e"), (3, "h::i"), (3, "x::b::C::new")];
    assert_eq!(got, want.map(|(l, p)| (l, p.to_string())));
    assert_eq!(module_of(Path::new("a/mod.rs")), Some(vec!["a".to_string()]));
    assert_eq!(module_of(Path::new("main.rs")), None);
    assert_eq!(row_of(&["arm".into(), "dobot".into(), "proto".into(), "Reply".into()]).map(|l| l.name), Some("arm::proto"));
    assert_eq!(row_of(&["arm".into(), "dobot".into(), "client".into()]).map(|l| l.name), Some("arm"));
}
