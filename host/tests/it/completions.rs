//! `gonio completions SHELL`: a script the shell accepts, naming every subcommand and the
//! options of `gonio measure`.
use crate::cli_support;
use cli_support::{gonio, stderr};

#[test]
fn completions_name_every_subcommand_and_bash_accepts_them() {
    let out = gonio(&["completions", "bash"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let script = String::from_utf8(out.stdout).expect("UTF-8");
    for word in [
        "measure",
        "fit",
        "compare",
        "library",
        "report",
        "sessions",
        "verify",
        "--spots",
        "--case",
        "--operator",
        "--resume",
    ] {
        assert!(script.contains(word), "the completions know {word}");
    }
    // bash parses it (no syntax error) and defines the completion function.
    let dir = cli_support::temp_dir("completions", "bash");
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("gonio.bash");
    std::fs::write(&file, &script).unwrap();
    let check = std::process::Command::new("bash")
        .arg("-c")
        .arg(format!("source {} && complete -p gonio", file.display()))
        .output()
        .expect("bash");
    assert!(
        check.status.success() && String::from_utf8_lossy(&check.stdout).contains("_gonio"),
        "{}",
        String::from_utf8_lossy(&check.stderr)
    );
    for shell in ["zsh", "fish", "elvish", "powershell"] {
        let out = gonio(&["completions", shell]);
        assert!(out.status.success() && out.stdout.len() > 1000, "{shell}");
    }
    let out = gonio(&["completions", "tcsh"]);
    assert_eq!(
        out.status.code(),
        Some(2),
        "an unknown shell is a usage error"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
