//! `MANIFEST.sha256`: the SHA-256 of every file of a finished session folder, one
//! `HEX  NAME` line each in name order, as `sha256sum` writes them, so that
//! `sha256sum -c MANIFEST.sha256` in the folder checks it as well as `gonio verify` does.
use crate::output::folder::{FilesRead, Finding, MANIFEST, REPORT, SIGNATURE, entries, temp_name};
use sha2::{Digest, Sha256};
use std::path::Path;

/// The SHA-256 of `bytes`, as lowercase hex.
pub fn sha256_hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// The manifest text of every file in `dir` but the manifest itself.
pub fn manifest_text(dir: &Path) -> std::io::Result<String> {
    let mut text = String::new();
    for name in entries(dir)? {
        let path = dir.join(&name);
        // The report is drawn from the files the manifest lists (it shows their hashes), so
        // it cannot be among them; `gonio verify` checks it against them instead.
        // The signature signs the manifest, so it cannot be among what the manifest lists.
        if name == MANIFEST || name == REPORT || name == SIGNATURE || !path.is_file() {
            continue;
        }
        text += &format!("{}  {name}\n", sha256_hex(&std::fs::read(&path)?));
    }
    Ok(text)
}

/// A folder that matches its manifest.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Matched {
    /// Files the manifest lists (all of them but itself).
    pub files: usize,
    /// The folder's identity: the SHA-256 (hex) of its manifest.
    pub identity: String,
    /// The manifest as read (what a signature signs).
    pub(crate) text: String,
}

/// Check `dir` against its manifest: every file listed, present and unchanged, and no other
/// file. Returns what matched, or every problem found.
pub fn check(dir: &Path) -> Result<Matched, Vec<Finding>> {
    check_read(dir, &FilesRead::new())
}

/// [`check`], on the bytes of the files already read (`read`, by name) as they were read:
/// only the others are read here.
pub(crate) fn check_read(dir: &Path, read: &FilesRead) -> Result<Matched, Vec<Finding>> {
    let path = dir.join(MANIFEST);
    let problem = |line: Option<usize>, message: String| Finding {
        file: path.clone(),
        line,
        message,
    };
    let text = match std::fs::read_to_string(&path) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(vec![problem(
                None,
                "missing: the session never finished (or the file was removed)".into(),
            )]);
        }
        Err(e) => return Err(vec![problem(None, format!("cannot read: {e}"))]),
    };
    let mut problems = Vec::new();
    let mut listed = std::collections::BTreeSet::new();
    for (k, line) in text.lines().enumerate() {
        let line_no = Some(k + 1);
        // sha256sum writes "HEX  NAME" (text mode) or "HEX *NAME" (binary mode).
        let Some((hex, name)) = line.split_once("  ").or_else(|| line.split_once(" *")) else {
            problems.push(problem(line_no, format!("'{line}' is not 'SHA256  NAME'")));
            continue;
        };
        if hex.len() != 64 || !hex.bytes().all(|b| b.is_ascii_hexdigit()) {
            problems.push(problem(line_no, format!("'{hex}' is not a SHA-256 in hex")));
            continue;
        }
        if name.contains('/') || name == MANIFEST || name == SIGNATURE || name.is_empty() {
            problems.push(problem(
                line_no,
                format!("'{name}' is not a file of the folder"),
            ));
            continue;
        }
        if !listed.insert(name.to_string()) {
            problems.push(problem(line_no, format!("{name} is listed twice")));
            continue;
        }
        let file = dir.join(name);
        let bytes = match read.get(name) {
            Some(bytes) => Ok(std::borrow::Cow::Borrowed(bytes)),
            None => std::fs::read(&file).map(std::borrow::Cow::Owned),
        };
        match bytes {
            Ok(bytes) if sha256_hex(&bytes).eq_ignore_ascii_case(hex) => {}
            Ok(_) => problems.push(Finding { file, line: None, message: format!("changed since the session finished: its SHA-256 is not the one in {MANIFEST}:{}", k + 1) }),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => problems.push(Finding { file, line: None, message: format!("missing (listed in {MANIFEST}:{})", k + 1) }),
            Err(e) => problems.push(Finding { file, line: None, message: format!("cannot read: {e}") }),
        }
    }
    match entries(dir) {
        Ok(names) => {
            // The report is drawn from the record, not part of it (nor is a report a kill cut
            // short, which the next `gonio report` replaces).
            // Nor is the signature, which signs the manifest (nor one a kill cut short, which
            // the next resume replaces).
            let report = |n: &str| {
                n == REPORT || n == temp_name(REPORT) || n == SIGNATURE || n == temp_name(SIGNATURE)
            };
            for name in names
                .into_iter()
                .filter(|n| n != MANIFEST && !report(n) && !listed.contains(n))
            {
                problems.push(Finding {
                    file: dir.join(&name),
                    line: None,
                    message: format!("not in {MANIFEST}: added after the session finished"),
                });
            }
        }
        Err(e) => problems.push(Finding {
            file: dir.to_path_buf(),
            line: None,
            message: format!("cannot list: {e}"),
        }),
    }
    if problems.is_empty() {
        Ok(Matched {
            files: listed.len(),
            identity: sha256_hex(text.as_bytes()),
            text,
        })
    } else {
        Err(problems)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sha256_of_known_strings() {
        // FIPS 180-2 test vectors.
        assert_eq!(
            sha256_hex(b"abc"),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        assert_eq!(
            sha256_hex(b""),
            "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855"
        );
    }

    /// The check hashes the bytes handed to it as read, not the file again: what was
    /// parsed is what is checked (and each file read once).
    #[test]
    fn the_check_hashes_the_bytes_already_read() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("a.txt"), b"as written\n").unwrap();
        std::fs::write(dir.path().join("b.txt"), b"other\n").unwrap();
        let text = manifest_text(dir.path()).unwrap();
        std::fs::write(dir.path().join(MANIFEST), &text).unwrap();
        let matched = check(dir.path()).unwrap();
        assert_eq!((matched.files, matched.text.as_str()), (2, text.as_str()));
        let same: FilesRead = [("a.txt".to_string(), b"as written\n".to_vec())].into();
        assert_eq!(check_read(dir.path(), &same), Ok(matched));
        let other: FilesRead = [("a.txt".to_string(), b"as parsed\n".to_vec())].into();
        let found = check_read(dir.path(), &other).unwrap_err();
        assert_eq!(found.len(), 1, "{found:?}");
        assert_eq!(found[0].file, dir.path().join("a.txt"));
        assert!(
            found[0].message.starts_with("changed since"),
            "{}",
            found[0]
        );
    }
}
