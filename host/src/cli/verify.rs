//! `gonio verify DIR…`: is each session folder whole and as its session left it, and who
//! signed it?
//!
//! Checks every file against `MANIFEST.sha256` (no file missing, changed or added), and
//! that `points.jsonl`, `readings.csv`, `calibration.json` and `session.json` agree; then
//! the signature (`signature.json`) over the manifest, and whether its key is one of yours
//! or one you trust (`gonio keys`). A signed file (a library export, a compare report:
//! `F` with `F.sig.json`) is checked against its signature. Prints one line per folder that
//! passes, naming the signer, and every problem as `file:line: message` on stderr.
//!
//! Exit codes: 0 when every folder passes; 1 when any does not (damaged, changed, a
//! signature that does not hold or a signer not trusted, unsigned with --require-signed,
//! or a session that never finished); 2 for a wrong command line.
use host::output::folder::Finding;
use host::output::folder::signature::{Keys, Signed, Trust, check_detached, untrusted};
use host::output::folder::verify::verify;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Arguments of `gonio verify`.
#[derive(clap::Args)]
#[command(
    after_help = "Exit codes: 0 every folder passes; 1 any does not (a file missing, changed or added since the session finished, records that disagree, a signature that does not hold, a signer whose key is neither yours nor trusted, an unsigned folder with --require-signed, a session not finished); 2 a wrong command line.\nAn unsigned folder passes on its hashes alone (said plainly): whoever can write a folder can recompute them, and remove a signature; where custody matters, give --require-signed."
)]
pub struct Args {
    /// Print one JSON object per folder instead of text.
    #[arg(long)]
    pub json: bool,
    /// Fail a folder (or file) that is not signed: without it an unsigned folder passes on
    /// its hashes, marked unsigned.
    #[arg(long)]
    pub require_signed: bool,
    /// Session or sheet folders, or signed files (a library export, a compare report).
    #[arg(required = true, value_name = "DIR|FILE")]
    pub dirs: Vec<PathBuf>,
}

/// Who signed, as the outputs say it.
struct Custody {
    /// The text for a person.
    text: String,
    /// The JSON of the signature (null when unsigned).
    json: serde_json::Value,
    /// Problems: a signer not trusted, or unsigned under --require-signed.
    problems: Vec<Finding>,
}

/// The custody of a folder or file `at` (its signature file `signature_file`) signed by
/// `signed`, with the trust of `keys`.
fn custody(
    signature_file: &Path,
    signed: Option<&Signed>,
    keys: Option<&Keys>,
    require_signed: bool,
) -> Custody {
    let Some(signed) = signed else {
        let problems = if require_signed {
            vec![Finding {
                file: signature_file.to_path_buf(),
                line: None,
                message: "missing: not signed (--require-signed)".into(),
            }]
        } else {
            Vec::new()
        };
        return Custody {
            text: "UNSIGNED: its hashes alone, which anyone who can write the folder could have recomputed".into(),
            json: serde_json::Value::Null,
            problems,
        };
    };
    let trust = keys.map_or(Trust::Unknown, |k| {
        k.trust_of(&signed.public_key).unwrap_or(Trust::Unknown)
    });
    let (trust_word, trusted_as) = match &trust {
        Trust::Own(name) => ("own", Some(name.clone())),
        Trust::Trusted(name) => ("trusted", Some(name.clone())),
        Trust::Unknown => ("untrusted", None),
    };
    Custody {
        text: format!(
            "signed by '{}' ({}) at {} by the signer's clock, {trust}",
            host::text::shown(&signed.signer),
            signed.fingerprint,
            host::text::shown(&signed.signed_at)
        ),
        json: serde_json::json!({"signer": signed.signer, "public_key": signed.public_key, "fingerprint": signed.fingerprint, "signed_at": signed.signed_at, "trust": trust_word, "trusted_as": trusted_as}),
        problems: untrusted(signature_file, signed, keys)
            .into_iter()
            .collect(),
    }
}

/// Run `gonio verify`.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let keys = Keys::from_env().ok();
    let mut failed = false;
    for dir in &args.dirs {
        let passed = if dir.is_file() {
            verify_file(dir, &args, keys.as_ref())
        } else if host::output::folder::is_sheet_folder(dir) {
            verify_sheet(dir, &args, keys.as_ref())
        } else {
            verify_session(dir, &args, keys.as_ref())
        };
        failed |= !passed;
    }
    Ok(ExitCode::from(if failed {
        crate::cli::exit::FAILED
    } else {
        crate::cli::exit::OK
    }))
}

/// Print the problems of `dir` of kind `kind`: it did not verify.
fn not_verified(dir: &Path, kind: &str, problems: &[Finding], json: bool) -> bool {
    for p in problems {
        eprintln!("error: {p}");
    }
    if json {
        println!(
            "{}",
            serde_json::json!({"schema": host::schema::VERIFY, "kind": kind, "dir": dir.display().to_string(), "ok": false, "problems": problems.iter().map(ToString::to_string).collect::<Vec<_>>()})
        );
    } else {
        eprintln!(
            "{}: NOT verified ({} problem{})",
            dir.display(),
            problems.len(),
            if problems.len() == 1 { "" } else { "s" }
        );
    }
    false
}

/// Check a session folder and print the result; whether it verified.
fn verify_session(dir: &Path, args: &Args, keys: Option<&Keys>) -> bool {
    let v = match verify(dir, host::output::report::draw) {
        Ok(v) => v,
        Err(problems) => return not_verified(dir, "session", &problems, args.json),
    };
    let signature = dir.join(host::output::folder::signature::SIGNATURE);
    let custody = custody(&signature, v.signed.as_ref(), keys, args.require_signed);
    if !custody.problems.is_empty() {
        return not_verified(dir, "session", &custody.problems, args.json);
    }
    if args.json {
        println!(
            "{}",
            serde_json::json!({"schema": host::schema::VERIFY, "kind": "session", "dir": dir.display().to_string(), "ok": true, "files": v.files, "readings": v.readings, "sample": v.doc.sample, "serial_number": v.doc.instrument.serial_number, "runs": v.doc.runs.len(), "signature": custody.json, "problems": []})
        );
    } else {
        println!(
            "{}: verified: {} files match MANIFEST.sha256; {} readings agree in points.jsonl, readings.csv and session.json; sample '{}' on instrument {}, {} run{}; {}",
            dir.display(),
            v.files,
            v.readings,
            host::text::shown(&v.doc.sample),
            host::text::shown(&v.doc.instrument.serial_number),
            v.doc.runs.len(),
            if v.doc.runs.len() == 1 { "" } else { "s" },
            custody.text
        );
    }
    true
}

/// Check a sheet folder and print the result; whether it verified.
fn verify_sheet(dir: &Path, args: &Args, keys: Option<&Keys>) -> bool {
    let v = match host::output::folder::verify::verify_sheet(dir, host::output::report::draw) {
        Ok(v) => v,
        Err(problems) => return not_verified(dir, "sheet", &problems, args.json),
    };
    let sig = host::output::folder::signature::SIGNATURE;
    let sheet = custody(&dir.join(sig), v.signed.as_ref(), keys, args.require_signed);
    let spots: Vec<Custody> = v
        .spots
        .iter()
        .map(|s| {
            custody(
                &s.dir.join(sig),
                s.signed.as_ref(),
                keys,
                args.require_signed,
            )
        })
        .collect();
    let problems: Vec<Finding> = std::iter::once(&sheet)
        .chain(&spots)
        .flat_map(|c| c.problems.iter().cloned())
        .collect();
    if !problems.is_empty() {
        return not_verified(dir, "sheet", &problems, args.json);
    }
    let readings: usize = v.spots.iter().map(|s| s.readings).sum();
    if args.json {
        println!(
            "{}",
            serde_json::json!({"schema": host::schema::VERIFY, "kind": "sheet", "dir": dir.display().to_string(), "ok": true, "spots": v.spots.len(), "readings": readings, "sample": v.sheet.doc.sample, "signature": sheet.json, "spot_signatures": spots.iter().map(|c| c.json.clone()).collect::<Vec<_>>(), "problems": []})
        );
    } else {
        // The spots' signers, when one differs from the sheet's.
        let differing: Vec<String> = v
            .spots
            .iter()
            .zip(&spots)
            .filter(|(s, _)| {
                let key = |signed: &Option<Signed>| signed.as_ref().map(|x| x.public_key.clone());
                key(&s.signed) != key(&v.signed)
            })
            .map(|(s, c)| format!("{}: {}", s.dir.display(), c.text))
            .collect();
        println!(
            "{}: verified: a sheet of {} spots of '{}'; MANIFEST.sha256 matches sheet.json and every spot's manifest; every spot folder verifies ({readings} readings); the sheet's result is the one its spots give; {}{}",
            dir.display(),
            v.spots.len(),
            host::text::shown(&v.sheet.doc.sample),
            sheet.text,
            if differing.is_empty() {
                "; every spot signed alike".to_string()
            } else {
                format!("; spots signed otherwise: {}", differing.join("; "))
            }
        );
    }
    true
}

/// Check a signed file (`F` and `F.sig.json`) and print the result; whether it verified.
/// A file has no manifest: unsigned, there is nothing to check, and it does not verify.
fn verify_file(file: &Path, args: &Args, keys: Option<&Keys>) -> bool {
    let signed = match check_detached(file) {
        Ok(Some(signed)) => signed,
        Ok(None) => {
            let problem = Finding {
                file: host::output::folder::signature::detached_path(file),
                line: None,
                message: "missing: a file alone has no manifest, only its signature could say it is as written".into(),
            };
            return not_verified(file, "file", &[problem], args.json);
        }
        Err(problem) => return not_verified(file, "file", &[problem], args.json),
    };
    let signature = host::output::folder::signature::detached_path(file);
    let custody = custody(&signature, Some(&signed), keys, args.require_signed);
    if !custody.problems.is_empty() {
        return not_verified(file, "file", &custody.problems, args.json);
    }
    if args.json {
        println!(
            "{}",
            serde_json::json!({"schema": host::schema::VERIFY, "kind": "file", "dir": file.display().to_string(), "ok": true, "signature": custody.json, "problems": []})
        );
    } else {
        println!(
            "{}: verified: as signed in {}; {}",
            file.display(),
            signature.display(),
            custody.text
        );
    }
    true
}
