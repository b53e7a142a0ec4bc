//! The documentation a new user reads points only at what the project holds: every
//! relative link of the README and of `docs/` names a file or folder that exists, and
//! none names the specifications the project was built from (they are not shipped).
use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The Markdown files a user reads: the README, docs/, the board's README.
fn documents() -> Vec<PathBuf> {
    let mut out = vec![
        root().join("README.md"),
        root().join("firmware/board/README.md"),
    ];
    for entry in std::fs::read_dir(root().join("docs")).expect("docs/") {
        let path = entry.expect("entry").path();
        if path.extension().is_some_and(|e| e == "md") {
            out.push(path);
        }
    }
    out
}

/// The targets of `[text](target)` links, without `#anchors`, that are not URLs.
fn relative_links(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut rest = text;
    while let Some(start) = rest.find("](") {
        rest = &rest[start + 2..];
        let Some(end) = rest.find(')') else { break };
        let target = rest[..end].split('#').next().unwrap_or("").trim();
        if !target.is_empty() && !target.contains("://") && !target.starts_with("mailto:") {
            out.push(target.to_string());
        }
        rest = &rest[end..];
    }
    out
}

#[test]
fn every_relative_link_names_a_file_of_the_project() {
    let mut broken = Vec::new();
    let mut links = 0;
    for doc in documents() {
        let text = std::fs::read_to_string(&doc).expect("read");
        for target in relative_links(&text) {
            links += 1;
            if !doc.parent().unwrap().join(&target).exists() {
                broken.push(format!("{}: {target}", doc.display()));
            }
        }
    }
    assert!(links > 20, "only {links} links found: the parser is wrong");
    assert!(
        broken.is_empty(),
        "links to nothing:\n  {}",
        broken.join("\n  ")
    );
}

#[test]
fn no_document_names_the_unshipped_specifications() {
    for doc in documents() {
        let text = std::fs::read_to_string(&doc).expect("read");
        for name in [
            "INSTRUMENT.md",
            "METHOD.md",
            "shared/spec",
            "../shared",
            "akao-tsl-paper.txt",
        ] {
            assert!(
                !text.contains(name),
                "{} names {name}, which the project does not hold",
                doc.display()
            );
        }
    }
}

#[test]
fn the_link_parser_finds_what_it_must() {
    assert_eq!(
        relative_links("see [a](docs/A.md#x), [b](https://x.org/b) and [c](c.svg)"),
        ["docs/A.md", "c.svg"]
    );
}
