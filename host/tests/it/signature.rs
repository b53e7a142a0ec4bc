//! The chain of custody (issue 30): keys made and listed, session and sheet folders, a
//! library export and a compare report signed as they are written, and `gonio verify`
//! naming the signer and catching a forgery: a folder changed and its manifest recomputed
//! without the key fails on its signature; one re-signed with the forger's own key fails
//! as signed by a key that is not trusted (until it is trusted); a stripped signature
//! leaves a folder plainly unsigned, refused by `--require-signed`.
use crate::cli_support::{stderr, temp_dir};
use crate::common::in_process::ram_dir;
use host::measure::{Measured, measure_with};
use host::output::folder::signature::{Keys, SIGNATURE, Signer};
use host::output::folder::store::StoreOptions;
use host::session::SimulatedOperator;
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

/// `gonio ARGS` with the keys folder `keys` (never the user's) and a library folder of its
/// own.
fn gonio(keys: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_gonio"))
        .args(args)
        .env("GONIO_KEYS_DIR", keys)
        .env("XDG_DATA_HOME", keys.join("data"))
        .stdin(Stdio::null())
        .output()
        .expect("run gonio")
}

fn out(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn s(p: &Path) -> &str {
    p.to_str().expect("a UTF-8 path")
}

/// A keys folder with one key `name`, and that key.
fn keys_with(dir_name: &str, name: &str) -> (PathBuf, Arc<Signer>) {
    let dir = temp_dir("signature", dir_name);
    let keys = Keys::at(&dir);
    keys.create(name, false).expect("a key");
    (dir, Arc::new(keys.load(name).expect("the key")))
}

/// `gonio measure ARGS` in process, its folder signed by `signer`.
fn measure_signed(list: &[&str], signer: Option<Arc<Signer>>) -> Measured {
    let args: Vec<String> = list.iter().map(|s| s.to_string()).collect();
    let args = crate::measure_args::parse_args(&args).expect("arguments");
    measure_with(
        &args,
        &mut SimulatedOperator,
        Arc::new(AtomicBool::new(false)),
        StoreOptions {
            signer: signer.map(|s| s as Arc<dyn host::output::folder::store::SignManifest>),
            ..Default::default()
        },
    )
    .expect("measured")
}

/// A finished session of one spot of G (seed `seed`) in `dir`, signed by `signer`.
fn session(dir: &Path, seed: u64, signer: Option<Arc<Signer>>) {
    let seed = seed.to_string();
    match measure_signed(
        &[
            "--sim",
            "G",
            "--spots",
            "1",
            "--seed",
            &seed,
            "--out",
            s(dir),
        ],
        signer,
    ) {
        Measured::Done { .. } => {}
        _ => panic!("the session did not finish"),
    }
}

/// Recompute the manifest of the session folder `dir`, as a forger who can write the
/// folder would.
fn recompute_manifest(dir: &Path) {
    let text = host::output::folder::manifest::manifest_text(dir).expect("manifest text");
    std::fs::write(dir.join("MANIFEST.sha256"), text).expect("write the manifest");
}

/// Change the readings file `points.jsonl` of `dir` (a digit of its first radiance factor)
/// and its decision log, then recompute every hash.
fn forge(dir: &Path) {
    let points = dir.join("points.jsonl");
    let text = std::fs::read_to_string(&points).expect("points");
    let at = text
        .find("\"radiance_factor\":")
        .expect("a radiance factor")
        + 19;
    let digit = text[at..]
        .find(|c: char| c.is_ascii_digit())
        .expect("a digit")
        + at;
    let mut bytes = text.into_bytes();
    bytes[digit] = if bytes[digit] == b'7' { b'8' } else { b'7' };
    std::fs::write(&points, bytes).expect("write points");
    recompute_manifest(dir);
}

/// Append a line to `session.log` of `dir` (checked by the hashes alone), remove the
/// report and recompute the hashes: what is left to catch it is the signature.
fn forge_log(dir: &Path) {
    let log = dir.join("session.log");
    let mut text = std::fs::read_to_string(&log).expect("log");
    text += "2026-01-01T00:00:00.000+00:00 [run 1] the operator checked the tile twice\n";
    std::fs::write(&log, text).expect("write log");
    // The report lists every file's hash: the forger removes it (a folder need not have one).
    let _ = std::fs::remove_file(dir.join("report.html"));
    recompute_manifest(dir);
}

fn copy_dir(from: &Path, to: &Path) {
    let _ = std::fs::remove_dir_all(to);
    std::fs::create_dir_all(to).expect("mkdir");
    for entry in std::fs::read_dir(from).expect("read dir") {
        let entry = entry.expect("entry");
        let target = to.join(entry.file_name());
        if entry.file_type().expect("type").is_dir() {
            copy_dir(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), target).expect("copy");
        }
    }
}

#[test]
fn keys_new_writes_an_owner_only_key_never_overwritten_and_list_shows_it() {
    let keys = temp_dir("signature", "keys-new");
    let made = gonio(&keys, &["keys", "new", "lab-1"]);
    assert!(made.status.success(), "{}", stderr(&made));
    let path = keys.join("lab-1.key");
    let mode = std::fs::metadata(&path)
        .expect("key file")
        .permissions()
        .mode()
        & 0o777;
    assert_eq!(mode, 0o600, "the private key is the owner's alone");
    let dir_mode = std::fs::metadata(&keys).expect("dir").permissions().mode() & 0o777;
    assert_eq!(dir_mode, 0o700);
    let first = std::fs::read(&path).expect("read key");

    // Never replaced without --force.
    let again = gonio(&keys, &["keys", "new", "lab-1"]);
    assert_eq!(again.status.code(), Some(1));
    assert!(
        stderr(&again).contains("never replaced without --force"),
        "{}",
        stderr(&again)
    );
    assert_eq!(std::fs::read(&path).expect("read key"), first);
    let forced = gonio(&keys, &["keys", "new", "lab-1", "--force"]);
    assert!(forced.status.success(), "{}", stderr(&forced));
    assert_ne!(std::fs::read(&path).expect("read key"), first, "a new key");

    // A name that is not a file name of the folder.
    for bad in ["../x", ".hidden", "a/b", ""] {
        let o = gonio(&keys, &["keys", "new", bad]);
        assert_eq!(o.status.code(), Some(1), "{bad}");
        assert!(
            stderr(&o).contains("is not a key name"),
            "{bad}: {}",
            stderr(&o)
        );
    }

    let second = gonio(&keys, &["keys", "new", "bench-2", "--default"]);
    assert!(second.status.success(), "{}", stderr(&second));
    let listed = gonio(&keys, &["keys", "list"]);
    assert!(listed.status.success(), "{}", stderr(&listed));
    let text = out(&listed);
    let own = Keys::at(&keys).own().expect("own keys");
    assert_eq!(own.len(), 2);
    for k in &own {
        let line = text
            .lines()
            .find(|l| l.trim_start().starts_with(&k.public.name))
            .unwrap_or_else(|| panic!("{} listed: {text}", k.public.name));
        assert!(line.contains(&k.public.fingerprint), "{line}");
        assert!(line.contains(&k.public.created), "{line}");
        assert_eq!(
            line.contains("(default)"),
            k.public.name == "bench-2",
            "{line}"
        );
    }

    // The exported public key is the key file's, and holds no private part.
    let exported = gonio(&keys, &["keys", "export-public", "lab-1"]);
    assert!(exported.status.success(), "{}", stderr(&exported));
    let doc: serde_json::Value = serde_json::from_str(&out(&exported)).expect("JSON");
    assert_eq!(doc["schema"], "gonio-public-key/1");
    assert_eq!(doc["public_key"], own[1].public.public_key.as_str());
    assert!(!out(&exported).contains("PRIVATE"));

    // A key file others can read is not used to sign.
    std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o644)).expect("chmod");
    let refused = Keys::at(&keys).load("lab-1").expect_err("too open");
    assert!(refused.to_string().contains("chmod 600"), "{refused}");
}

#[test]
fn a_signed_session_verifies_and_names_its_signer_and_a_forgery_fails() {
    let (keys, signer) = keys_with("forge-lab", "lab");
    for seed in [5u64, 23] {
        let dir = ram_dir("signature", &format!("signed-{seed}"));
        session(&dir, seed, Some(signer.clone()));
        assert!(dir.join(SIGNATURE).is_file());

        // Untouched: verifies, and says who signed, with the fingerprint, trusted.
        let o = gonio(&keys, &["verify", s(&dir)]);
        assert!(o.status.success(), "{}", stderr(&o));
        let fingerprint = host::output::folder::signature::fingerprint(&signer.public_key());
        assert!(
            out(&o).contains(&format!("signed by 'lab' ({fingerprint})"))
                && out(&o).contains("your own key 'lab'"),
            "{}",
            out(&o)
        );
        let o = gonio(&keys, &["verify", "--json", s(&dir)]);
        let doc: serde_json::Value = serde_json::from_str(out(&o).trim()).expect("JSON");
        assert_eq!(doc["signature"]["signer"], "lab");
        assert_eq!(doc["signature"]["trust"], "own");

        // A forger changes the readings and recomputes every hash, without the key.
        let forged = ram_dir("signature", &format!("forged-{seed}"));
        copy_dir(&dir, &forged);
        forge(&forged);
        assert!(
            host::output::folder::manifest::check(&forged).is_ok(),
            "every hash recomputed"
        );
        let o = gonio(&keys, &["verify", s(&forged)]);
        assert_eq!(o.status.code(), Some(1), "{}", out(&o));
        assert!(
            stderr(&o).contains("signature.json: MANIFEST.sha256 changed after it was signed"),
            "{}",
            stderr(&o)
        );

        // Where only the hashes check a file, the signature alone catches the change.
        let logged = ram_dir("signature", &format!("log-{seed}"));
        copy_dir(&dir, &logged);
        forge_log(&logged);
        let o = gonio(&keys, &["verify", s(&logged)]);
        assert_eq!(o.status.code(), Some(1), "{}", out(&o));
        assert!(stderr(&o).contains("1 problem)"), "{}", stderr(&o));
        assert!(
            stderr(&o).contains("changed after it was signed"),
            "{}",
            stderr(&o)
        );
        // ... and its report is refused as a changed folder's is.
        let o = gonio(&keys, &["report", s(&logged)]);
        assert_eq!(o.status.code(), Some(1), "{}", out(&o));
        assert!(
            stderr(&o).contains("changed after it was signed"),
            "{}",
            stderr(&o)
        );

        // The forger re-signs with a key of their own: a signature that holds, by a key
        // this lab does not trust.
        let (forger_keys, forger) = keys_with(&format!("forger-{seed}"), "lab");
        std::fs::write(
            logged.join(SIGNATURE),
            forger
                .sign_bytes(
                    "MANIFEST.sha256",
                    &std::fs::read(logged.join("MANIFEST.sha256")).unwrap(),
                )
                .unwrap(),
        )
        .unwrap();
        let o = gonio(&keys, &["verify", s(&logged)]);
        assert_eq!(o.status.code(), Some(1), "{}", out(&o));
        assert!(
            stderr(&o).contains("signed by 'lab'")
                && stderr(&o).contains("neither yours nor trusted"),
            "{}",
            stderr(&o)
        );
        let o = gonio(&keys, &["report", s(&logged)]);
        assert_eq!(o.status.code(), Some(1), "{}", out(&o));
        // On the forger's own machine it verifies: a signature says who, not whether to
        // believe them.
        let o = gonio(&forger_keys, &["verify", s(&logged)]);
        assert!(o.status.success(), "{}", stderr(&o));
        // Trusted once this lab trusts that key (as another lab's), under its own name.
        let public = forger_keys.join("forger.pub.json");
        let exported = gonio(&forger_keys, &["keys", "export-public", "lab"]);
        std::fs::write(&public, &exported.stdout).unwrap();
        let trusted = gonio(&keys, &["keys", "trust", s(&public), "--name", "lab-b"]);
        assert!(trusted.status.success(), "{}", stderr(&trusted));
        let o = gonio(&keys, &["verify", s(&logged)]);
        assert!(o.status.success(), "{}", stderr(&o));
        assert!(out(&o).contains("trusted: as 'lab-b'"), "{}", out(&o));
        std::fs::remove_file(keys.join("lab-b.pub")).unwrap();

        // Stripped of its signature: plainly unsigned; refused with --require-signed.
        std::fs::remove_file(logged.join(SIGNATURE)).unwrap();
        let o = gonio(&keys, &["verify", s(&logged)]);
        assert!(o.status.success(), "{}", stderr(&o));
        assert!(out(&o).contains("UNSIGNED"), "{}", out(&o));
        let o = gonio(&keys, &["verify", "--require-signed", s(&logged)]);
        assert_eq!(o.status.code(), Some(1), "{}", out(&o));
        assert!(stderr(&o).contains("not signed"), "{}", stderr(&o));

        // A signature altered by a byte.
        let bent = ram_dir("signature", &format!("bent-{seed}"));
        copy_dir(&dir, &bent);
        let sig = std::fs::read_to_string(bent.join(SIGNATURE)).unwrap();
        let doc: serde_json::Value = serde_json::from_str(&sig).unwrap();
        let value = doc["signature"].as_str().unwrap();
        let flipped = format!(
            "{}{}",
            if value.starts_with('0') { "1" } else { "0" },
            &value[1..]
        );
        std::fs::write(bent.join(SIGNATURE), sig.replace(value, &flipped)).unwrap();
        let o = gonio(&keys, &["verify", s(&bent)]);
        assert_eq!(o.status.code(), Some(1), "{}", out(&o));
        assert!(stderr(&o).contains("altered or forged"), "{}", stderr(&o));
        for d in [dir, forged, logged, bent] {
            let _ = std::fs::remove_dir_all(d);
        }
    }
}

#[test]
fn the_simulated_instrument_makes_its_key_on_first_use() {
    let keys = temp_dir("signature", "sim-first-use");
    let dir = temp_dir("signature", "sim-first-use-session");
    let o = gonio(
        &keys,
        &["measure", "--sim", "G", "--seed", "9", "--out", s(&dir)],
    );
    assert!(
        o.status.success() || o.status.code() == Some(3),
        "{}",
        stderr(&o)
    );
    assert!(stderr(&o).contains("made the key 'sim'"), "{}", stderr(&o));
    assert!(keys.join("sim.key").is_file());
    let o = gonio(&keys, &["verify", s(&dir)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(out(&o).contains("signed by 'sim'"), "{}", out(&o));
    // A --key that does not exist stops before anything is measured.
    let other = temp_dir("signature", "sim-no-such-key");
    let o = gonio(
        &keys,
        &["measure", "--sim", "G", "--key", "nope", "--out", s(&other)],
    );
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("no key named 'nope'"), "{}", stderr(&o));
    assert!(!other.exists());
}

/// `gonio measure ARGS` in process with `crash` injected, its folder signed by `signer`.
fn measure_crashed(
    list: &[String],
    signer: &Arc<Signer>,
    crash: host::output::folder::store::Crash,
) -> anyhow::Result<Measured> {
    let args = crate::measure_args::parse_args(list).expect("arguments");
    measure_with(
        &args,
        &mut SimulatedOperator,
        Arc::new(AtomicBool::new(false)),
        StoreOptions {
            crash: Some(crash),
            signer: Some(signer.clone() as Arc<dyn host::output::folder::store::SignManifest>),
        },
    )
}

#[test]
fn a_session_killed_and_resumed_is_signed_and_so_is_one_killed_before_its_signature() {
    use host::output::folder::store::Crash;
    let (keys, signer) = keys_with("resume", "lab");
    let dir = |name: &str| ram_dir("signature", &format!("resume-{name}"));
    let args = |d: &Path, verb: &str| -> Vec<String> {
        ["--sim", "G", "--seed", "11", verb, s(d)]
            .iter()
            .map(|s| s.to_string())
            .collect()
    };
    // Every write of a whole session, counted: the last is its signature.
    let counted = dir("counted");
    let counting = Crash::counting();
    let mut first = args(&counted, "--out");
    first.splice(2..2, ["--spots".to_string(), "1".to_string()]);
    let done = measure_crashed(&first, &signer, counting.clone()).expect("measured");
    assert!(matches!(done, Measured::Done { .. }));
    let writes = counting.writes();
    for at in [writes / 3, writes / 2, writes - 1] {
        let d = dir(&at.to_string());
        let mut first = args(&d, "--out");
        first.splice(2..2, ["--spots".to_string(), "1".to_string()]);
        let stopped = measure_crashed(&first, &signer, Crash::at(at));
        assert!(
            !matches!(stopped, Ok(Measured::Done { .. })),
            "killed at write {at}"
        );
        assert!(
            !d.join(SIGNATURE).exists(),
            "killed at {at} of {writes}: no signature yet"
        );
        // Resumed (a session killed before its signature was finished: refused as
        // finished, and signed on the way).
        let resumed = measure_crashed(&args(&d, "--resume"), &signer, Crash::counting());
        if at < writes - 1 {
            assert!(
                matches!(resumed, Ok(Measured::Done { .. })),
                "resumed from {at}"
            );
        } else {
            let e = resumed
                .err()
                .expect("a finished session is not measured again");
            assert!(e.to_string().contains("finished"), "{e}");
        }
        let o = gonio(&keys, &["verify", s(&d)]);
        assert!(o.status.success(), "killed at {at}: {}", stderr(&o));
        assert!(out(&o).contains("signed by 'lab'"), "{}", out(&o));
        let _ = std::fs::remove_dir_all(&d);
    }
    let _ = std::fs::remove_dir_all(&counted);
}

#[test]
fn a_sheet_folder_is_signed_with_each_spot_and_a_forged_spot_fails() {
    let (keys, signer) = keys_with("sheet", "lab");
    let dir = ram_dir("signature", "sheet");
    let sheet = measure_signed(
        &[
            "--sim",
            "PPC",
            "--spots",
            "2",
            "--seed",
            "4",
            "--out",
            s(&dir),
        ],
        Some(signer),
    );
    assert!(matches!(sheet, Measured::Sheet { .. }), "a sheet");
    for f in [
        dir.join(SIGNATURE),
        dir.join("spot-1").join(SIGNATURE),
        dir.join("spot-2").join(SIGNATURE),
    ] {
        assert!(f.is_file(), "{}", f.display());
    }
    let o = gonio(&keys, &["verify", s(&dir)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        out(&o).contains("signed by 'lab'") && out(&o).contains("every spot signed alike"),
        "{}",
        out(&o)
    );
    // A spot forged and every manifest recomputed (the spot's, then the sheet's).
    let spot = dir.join("spot-2");
    forge_log(&spot);
    let doc: host::output::folder::sheet::SheetDoc =
        serde_json::from_slice(&std::fs::read(dir.join("sheet.json")).unwrap()).unwrap();
    let text = host::output::folder::sheet::manifest_text(&dir, &doc).unwrap();
    std::fs::write(dir.join("MANIFEST.sha256"), text).unwrap();
    let o = gonio(&keys, &["verify", s(&dir)]);
    assert_eq!(o.status.code(), Some(1), "{}", out(&o));
    let err = stderr(&o);
    assert!(
        err.contains("spot-2/signature.json: MANIFEST.sha256 changed after it was signed")
            && err.contains(&format!(
                "{}/signature.json: MANIFEST.sha256 changed",
                dir.display()
            )),
        "both the spot's and the sheet's signatures: {err}"
    );
    let o = gonio(&keys, &["report", s(&dir)]);
    assert_eq!(o.status.code(), Some(1), "{}", out(&o));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_library_export_and_a_compare_report_are_signed_files_that_verify() {
    let (keys, signer) = keys_with("files", "lab");
    let a = ram_dir("signature", "files-a");
    let b = ram_dir("signature", "files-b");
    session(&a, 31, Some(signer.clone()));
    session(&b, 32, Some(signer));
    let library = keys.join("library.sqlite");
    let o = gonio(
        &keys,
        &[
            "library",
            "add",
            "--library",
            s(&library),
            "--stock",
            "G",
            s(&a),
            s(&b),
        ],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let export = keys.join("export.jsonl");
    let o = gonio(
        &keys,
        &["library", "export", "--library", s(&library), s(&export)],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("signed by 'lab'"), "{}", stderr(&o));

    let report = keys.join("compare.html");
    let o = gonio(
        &keys,
        &[
            "compare",
            "--demo-population",
            "--report",
            s(&report),
            s(&a),
            s(&b),
        ],
    );
    assert!(
        o.status.code() == Some(0) || o.status.code() == Some(3),
        "{}",
        stderr(&o)
    );

    for file in [&export, &report] {
        let o = gonio(&keys, &["verify", s(file)]);
        assert!(o.status.success(), "{}: {}", file.display(), stderr(&o));
        assert!(out(&o).contains("signed by 'lab'"), "{}", out(&o));
        // One byte changed after signing.
        let mut bytes = std::fs::read(file).unwrap();
        let last = bytes.len() - 2;
        bytes[last] ^= 0x01;
        std::fs::write(file, bytes).unwrap();
        let o = gonio(&keys, &["verify", s(file)]);
        assert_eq!(o.status.code(), Some(1), "{}", out(&o));
        assert!(
            stderr(&o).contains("changed after it was signed"),
            "{}",
            stderr(&o)
        );
    }
    // A file with no signature has nothing to verify it.
    std::fs::remove_file(host::output::folder::signature::detached_path(&export)).unwrap();
    let o = gonio(&keys, &["verify", s(&export)]);
    assert_eq!(o.status.code(), Some(1), "{}", out(&o));
    for d in [a, b] {
        let _ = std::fs::remove_dir_all(d);
    }
}

/// The library takes custody as `gonio verify` judges it: a folder or an exchange file
/// signed by a key that is neither yours nor trusted is refused and nothing is added; a
/// file changed after it was signed is refused; an unsigned one is taken unless
/// `--require-signed`, and standard input cannot be signed.
#[test]
fn the_library_adds_and_imports_only_what_a_trusted_key_signed() {
    let (lab_keys, lab) = keys_with("custody-lab", "lab");
    let (other_keys, forger) = keys_with("custody-other", "forger");
    let signed = ram_dir("signature", "custody-signed");
    let forged = ram_dir("signature", "custody-forged");
    let unsigned = ram_dir("signature", "custody-unsigned");
    session(&signed, 41, Some(lab.clone()));
    session(&forged, 42, Some(forger));
    session(&unsigned, 43, None);
    let library = lab_keys.join("custody.sqlite");
    let add = |keys: &Path, extra: &[&str], dir: &Path| {
        let mut args = vec!["library", "add", "--library", s(&library), "--stock", "G"];
        args.extend_from_slice(extra);
        args.push(s(dir));
        gonio(keys, &args)
    };
    let o = add(&lab_keys, &[], &forged);
    assert_eq!(o.status.code(), Some(1), "{}", out(&o));
    assert!(
        stderr(&o).contains("neither yours nor trusted")
            && stderr(&o).contains("nothing was added"),
        "{}",
        stderr(&o)
    );
    assert!(!library.exists(), "a refused add made no library");
    let o = add(&lab_keys, &["--require-signed"], &unsigned);
    assert_eq!(o.status.code(), Some(1), "{}", out(&o));
    assert!(
        stderr(&o).contains("not signed (--require-signed)"),
        "{}",
        stderr(&o)
    );
    for dir in [&signed, &unsigned] {
        let o = add(&lab_keys, &[], dir);
        assert!(o.status.success(), "{}: {}", dir.display(), stderr(&o));
    }

    let export = lab_keys.join("custody.jsonl");
    let o = gonio(
        &lab_keys,
        &["library", "export", "--library", s(&library), s(&export)],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let import = |keys: &Path, extra: &[&str], file: &Path| {
        let target = keys.join("imported.sqlite");
        let mut args = vec!["library", "import", "--library", s(&target)];
        args.extend_from_slice(extra);
        args.push(s(file));
        (gonio(keys, &args), target)
    };
    // The other lab does not know this lab's key yet.
    let (o, target) = import(&other_keys, &[], &export);
    assert_eq!(o.status.code(), Some(1), "{}", out(&o));
    assert!(
        stderr(&o).contains("neither yours nor trusted")
            && stderr(&o).contains("nothing was imported"),
        "{}",
        stderr(&o)
    );
    assert!(!target.exists(), "a refused import made no library");
    let public = lab.public_key();
    let hex = host::output::folder::signature::hex(public.as_bytes());
    let o = gonio(&other_keys, &["keys", "trust", &hex, "--name", "lab"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let (o, target) = import(&other_keys, &["--require-signed"], &export);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("signed by 'lab'"), "{}", stderr(&o));
    assert!(out(&o).contains("2 sessions added"), "{}", out(&o));
    std::fs::remove_file(&target).unwrap();

    // A record changed after signing: refused, whoever holds the file.
    let text = std::fs::read_to_string(&export).unwrap();
    let changed = text.replacen("\"G\"", "\"H\"", 1);
    assert_ne!(changed, text);
    std::fs::write(&export, &changed).unwrap();
    let (o, target) = import(&other_keys, &[], &export);
    assert_eq!(o.status.code(), Some(1), "{}", out(&o));
    assert!(
        stderr(&o).contains("changed after it was signed"),
        "{}",
        stderr(&o)
    );
    assert!(!target.exists());

    // Unsigned: taken on its hashes, unless a signature is required.
    std::fs::remove_file(host::output::folder::signature::detached_path(&export)).unwrap();
    let (o, _) = import(&other_keys, &["--require-signed"], &export);
    assert_eq!(o.status.code(), Some(1), "{}", out(&o));
    let (o, _) = import(&other_keys, &["--require-signed"], Path::new("-"));
    assert_eq!(o.status.code(), Some(1), "{}", out(&o));
    assert!(
        stderr(&o).contains("standard input cannot carry a signature"),
        "{}",
        stderr(&o)
    );
    let (o, _) = import(&other_keys, &[], &export);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("unsigned"), "{}", stderr(&o));
    for d in [signed, forged, unsigned] {
        let _ = std::fs::remove_dir_all(d);
    }
}
