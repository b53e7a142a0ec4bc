//! The house the host library keeps, checked on its own sources:
//! - its layers, drawn from its imports: every `crate::…` path in a module's code
//!   (comments and its tests left out) names a module of a lower layer, so there is no
//!   circle and no import that runs up. The layers are declared here, where a change that
//!   breaks them fails with the file and the path it names;
//! - no function longer than [`MAX_FN_LINES`] lines (tests included): a longer one is
//!   steps that want names of their own.
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The library's top-level modules, bottom first (`cli` is the binary's, apart).
const TOP: &[&[&str]] = &[
    // With them, lib.rs's own items: the command line's usage error (exit 2), which any
    // layer that checks a value given on the command line returns.
    &["schema", "text", "UsageError", "usage_bail"],
    &["analysis"],
    &["instrument"],
    &["session"],
    &["output"],
    &["measure"],
    // A campaign may run the whole job as a user does (the interruption campaign resumes
    // sheets through `measure`); nothing below calls a study.
    &["study"],
];

/// `output/`'s modules, bottom first: the session or sheet folder (its own layers are
/// [`FOLDER`]); what writes beside it; rendering; what reads finished folders.
const OUTPUT: &[&[&str]] = &[
    &["folder", "chromium"],
    &["dataset", "export", "plots", "shared_errors"],
    &["report"],
    &[
        "comparison",
        "catalogue",
        "reanalysis",
        "library",
        "characterization",
    ],
    // A QA batch: sheet folders read back and a master read from the library.
    &["batch"],
];

/// `output/folder/`'s modules, bottom first: its names, documents and reading (`mod`, the
/// folder's own page, where a path names no module of the folder); its store, manifest,
/// lock and typed documents; the signatures; the writers and the sheet's reader;
/// verification.
const FOLDER: &[&[&str]] = &[
    &["mod"],
    &["store", "manifest", "lock", "documents"],
    &["signature"],
    &["record", "sheet"],
    &["verify"],
];

/// The folder's module a path's segment after `folder` names: its own page (`mod`) when
/// it names none (an item of the page, or nothing).
fn folder_module(segment: Option<&String>) -> &str {
    match segment {
        Some(name) if rank(FOLDER, name).is_some() => name,
        _ => "mod",
    }
}

/// The longest a function may be, in lines from its `fn` to its closing brace.
const MAX_FN_LINES: usize = 120;

fn src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

/// Every `.rs` file under `dir`.
fn files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).expect("a source folder") {
        let path = entry.expect("an entry").path();
        if path.is_dir() {
            out.extend(files(&path));
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
    out
}

/// The code of a file without its comments and its `#[cfg(test)]` module (tests may
/// reach anywhere).
fn code(path: &Path) -> String {
    code_of(&std::fs::read_to_string(path).expect("a source file"))
}

/// [`code`] of a file's text: a comment is a line's rest from `//` at its start or after
/// a space (a URL's `://` is not one).
fn code_of(text: &str) -> String {
    let text = text.split("#[cfg(test)]").next().unwrap_or("");
    text.lines()
        .map(|l| {
            let cut = if l.trim_start().starts_with("//") {
                Some(0)
            } else {
                l.find(" //")
            };
            cut.map_or(l, |at| &l[..at])
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// The `crate::a::b…` paths of `code`, as their segments.
fn crate_paths(code: &str) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    let mut rest = code;
    while let Some(at) = rest.find("crate::") {
        let preceded = rest[..at]
            .chars()
            .next_back()
            .is_some_and(|c| c.is_alphanumeric() || c == '_');
        rest = &rest[at + "crate::".len()..];
        if preceded {
            continue;
        }
        let end = rest
            .find(|c: char| !(c.is_alphanumeric() || c == '_' || c == ':'))
            .unwrap_or(rest.len());
        let segments: Vec<String> = rest[..end]
            .split("::")
            .filter(|s| !s.is_empty())
            .map(str::to_string)
            .collect();
        if !segments.is_empty() {
            out.push(segments);
        }
    }
    out
}

/// The layer of `name` in `layers`.
fn rank(layers: &[&[&str]], name: &str) -> Option<usize> {
    layers.iter().position(|layer| layer.contains(&name))
}

/// Each import that does not run down a layer: "file: path (why)".
fn violations() -> Vec<String> {
    let mut out = Vec::new();
    for path in files(&src()) {
        let relative = path.strip_prefix(src()).expect("under src").to_path_buf();
        let parts: Vec<String> = relative
            .with_extension("")
            .iter()
            .map(|p| p.to_string_lossy().into_owned())
            .collect();
        let (top, sub) = (parts[0].as_str(), parts.get(1).map(String::as_str));
        if matches!(top, "lib" | "main" | "cli") {
            continue;
        }
        let Some(own) = rank(TOP, top) else {
            out.push(format!("{}: a module of no layer", relative.display()));
            continue;
        };
        for target in crate_paths(&code(&path)) {
            let name = target.join("::");
            let Some(theirs) = rank(TOP, &target[0]) else {
                out.push(format!(
                    "{}: crate::{name} (a module of no layer)",
                    relative.display()
                ));
                continue;
            };
            if target[0] == top {
                // Within output/, its own order; elsewhere a top-level module is one.
                let (Some(sub), Some(to)) = (sub, target.get(1)) else {
                    continue;
                };
                if top == "output" && sub == "folder" && to == "folder" {
                    // Within output/folder/, its own order.
                    let own = parts.get(2).map(String::as_str).unwrap_or("mod");
                    let to = folder_module(target.get(2));
                    match (rank(FOLDER, own), rank(FOLDER, to)) {
                        _ if to == own => {}
                        (Some(a), Some(b)) if b < a => {}
                        (Some(_), Some(_)) => out.push(format!(
                            "{}: crate::{name} (not below output::folder::{own})",
                            relative.display()
                        )),
                        _ => out.push(format!(
                            "{}: crate::{name} (a module of output/folder/ of no layer)",
                            relative.display()
                        )),
                    }
                    continue;
                }
                if top != "output" || to == sub || sub == "mod" {
                    continue;
                }
                match (rank(OUTPUT, sub), rank(OUTPUT, to)) {
                    (Some(a), Some(b)) if b < a => {}
                    (Some(_), Some(_)) => out.push(format!(
                        "{}: crate::{name} (output::{to} is not below output::{sub})",
                        relative.display()
                    )),
                    _ => out.push(format!(
                        "{}: crate::{name} (a module of output/ of no layer)",
                        relative.display()
                    )),
                }
            } else if theirs >= own {
                out.push(format!(
                    "{}: crate::{name} ({} is not below {top})",
                    relative.display(),
                    target[0]
                ));
            }
        }
    }
    out
}

#[test]
fn every_import_runs_down_a_layer() {
    let found = violations();
    assert!(
        found.is_empty(),
        "imports that do not run down a layer:\n{}",
        found.join("\n")
    );
}

/// The check sees what it must: the paths of a `use` group and of inline paths, not
/// those in comments or words that only end in `crate`; and every module is in a layer.
#[test]
fn the_check_reads_paths_and_knows_every_module() {
    let paths = crate_paths(&code_of(
        "//! crate::study\nuse crate::output::folder::{A, B};\nlet x = crate::analysis::fit::f(); // crate::cli\nnot_a_crate::x\n#[cfg(test)]\nuse crate::cli;",
    ));
    assert_eq!(
        paths,
        [vec!["output", "folder"], vec!["analysis", "fit", "f"]]
            .map(|p| p.iter().map(|s| s.to_string()).collect::<Vec<_>>())
    );
    assert!(code(&src().join("lib.rs")).contains("pub mod output"));
    let mut outputs: BTreeMap<String, bool> = BTreeMap::new();
    for entry in std::fs::read_dir(src().join("output")).expect("output/") {
        let path = entry.expect("an entry").path();
        let name = path
            .file_stem()
            .expect("a name")
            .to_string_lossy()
            .into_owned();
        if name != "mod" {
            outputs.insert(name.clone(), rank(OUTPUT, &name).is_some());
        }
    }
    assert!(outputs.values().all(|&known| known), "{outputs:?}");
    let mut folders: BTreeMap<String, bool> = BTreeMap::new();
    for entry in std::fs::read_dir(src().join("output/folder")).expect("output/folder/") {
        let path = entry.expect("an entry").path();
        let name = path
            .file_stem()
            .expect("a name")
            .to_string_lossy()
            .into_owned();
        folders.insert(name.clone(), rank(FOLDER, &name).is_some());
    }
    assert!(folders.values().all(|&known| known), "{folders:?}");
}

/// Each function of `text` as (its name, its first line, its length in lines). rustfmt
/// puts a body's closing brace alone on a line at the `fn`'s indentation; a declaration
/// without a body (a trait's) ends with `;` before any `{`.
fn functions(text: &str) -> Vec<(String, usize, usize)> {
    let lines: Vec<&str> = text.lines().collect();
    let mut out = Vec::new();
    for (k, line) in lines.iter().enumerate() {
        let trimmed = line.trim_start();
        let indent = &line[..line.len() - trimmed.len()];
        let mut words = trimmed.split_whitespace().peekable();
        // Qualifiers before `fn`: pub, pub(crate), const, async, unsafe, extern "C".
        while let Some(w) = words.peek() {
            if w.starts_with("pub") || ["const", "async", "unsafe", "extern", "\"C\""].contains(w) {
                words.next();
            } else {
                break;
            }
        }
        if words.next() != Some("fn") {
            continue;
        }
        let name: String = words
            .next()
            .unwrap_or("")
            .chars()
            .take_while(|c| c.is_alphanumeric() || *c == '_')
            .collect();
        let closing = format!("{indent}}}");
        let mut end = None;
        for (j, l) in lines.iter().enumerate().skip(k) {
            let code = l.split(" //").next().unwrap_or("").trim_end();
            if j == k && code.ends_with('}') && code.contains('{') {
                end = Some(j);
                break;
            }
            if *l == closing {
                end = Some(j);
                break;
            }
            if code.ends_with(';') && !lines[k..j].iter().any(|p| p.trim_end().ends_with('{')) {
                break;
            }
        }
        if let Some(end) = end {
            out.push((name, k + 1, end - k + 1));
        }
    }
    out
}

#[test]
fn no_function_is_longer_than_its_limit() {
    let mut long = Vec::new();
    for path in files(&src()) {
        let text = std::fs::read_to_string(&path).expect("a source file");
        for (name, line, length) in functions(&text) {
            if length > MAX_FN_LINES {
                long.push(format!("{}:{line}: {name}, {length} lines", path.display()));
            }
        }
    }
    assert!(
        long.is_empty(),
        "functions longer than {MAX_FN_LINES} lines:\n{}",
        long.join("\n")
    );
}

/// The measure finds bodies, one-line functions and declarations as they are.
#[test]
fn functions_are_measured_from_fn_to_their_brace() {
    let text = "impl A {\n    pub(crate) fn one(&self) -> u8 { 1 }\n\n    fn three() {\n        let x = 1; // }\n    }\n}\ntrait T {\n    fn declared(&self);\n    fn given(&self) {\n    }\n}\npub const unsafe fn top(\n    a: u8,\n) -> u8 {\n    a\n}\n";
    assert_eq!(
        functions(text),
        [
            ("one".to_string(), 2, 1),
            ("three".to_string(), 4, 3),
            ("given".to_string(), 10, 2),
            ("top".to_string(), 13, 5),
        ]
    );
}
