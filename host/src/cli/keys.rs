//! `gonio keys`: the Ed25519 keys that sign session and sheet folders, library exports and
//! compare reports, and the public keys of others that `gonio verify` trusts
//! ([`host::output::folder::signature`]). The keys folder is `$GONIO_KEYS_DIR`, else
//! `$XDG_CONFIG_HOME/gonio/keys`, else `~/.config/gonio/keys`.
//!
//! Exit codes: 0 done; 1 failed (the message says what and where; nothing is replaced
//! without --force); 2 a wrong command line.
use anyhow::Context;
use host::output::folder::signature::{Keys, Signer, parse_public_key, read_public};
use std::path::PathBuf;
use std::process::ExitCode;

/// Arguments of `gonio keys`.
#[derive(clap::Args)]
#[command(
    after_help = "Exit codes: 0 done; 1 failed (nothing is replaced without --force); 2 a wrong command line.\nThe keys folder: $GONIO_KEYS_DIR, else $XDG_CONFIG_HOME/gonio/keys, else ~/.config/gonio/keys."
)]
pub struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(clap::Subcommand)]
enum Command {
    /// Make a key pair: the private key (owner-only file) signs, its public key is what others trust.
    New(NewArgs),
    /// List your keys (name, fingerprint, created) and the public keys you trust.
    List,
    /// Print a key's public key (a gonio-public-key/1 document) for another lab to trust.
    ExportPublic(ExportArgs),
    /// Trust a public key: a file from gonio keys export-public, or 64 hex digits.
    Trust(TrustArgs),
    /// Make one of your keys the one that signs by default.
    Default(DefaultArgs),
}

#[derive(clap::Args)]
struct NewArgs {
    /// The key's name: letters, digits, '.', '-', '_' (e.g. the lab's or instrument's).
    name: String,
    /// Replace a key of that name (what it signed then verifies only against its exported
    /// public key, trusted under another name).
    #[arg(long)]
    force: bool,
    /// Make it the key that signs by default.
    #[arg(long)]
    default: bool,
}

#[derive(clap::Args)]
struct ExportArgs {
    /// The key's name.
    name: String,
}

#[derive(clap::Args)]
struct TrustArgs {
    /// A public key file (gonio keys export-public) or the public key in hex.
    #[arg(value_name = "FILE|KEY")]
    key: String,
    /// The name it is trusted under (default: the name in the file).
    #[arg(long)]
    name: Option<String>,
    /// Replace a trusted key of that name.
    #[arg(long)]
    force: bool,
}

#[derive(clap::Args)]
struct DefaultArgs {
    /// The key's name.
    name: String,
}

/// The key that signs a file gonio writes (a library export, a compare report): `key`,
/// else the default or only key; `None` (said on stderr) when there is none.
pub fn file_signer(key: Option<&str>, what: &str) -> anyhow::Result<Option<Signer>> {
    let keys = match (Keys::from_env(), key) {
        (Ok(keys), _) => keys,
        (Err(e), Some(_)) => return Err(e.into()),
        (Err(e), None) => {
            eprintln!("note: {what} is written unsigned ({e})");
            return Ok(None);
        }
    };
    let signer = keys.choose(key)?;
    if signer.is_none() {
        eprintln!(
            "note: no signing key in {}: {what} is written unsigned (gonio keys new NAME makes one)",
            keys.dir().display()
        );
    }
    Ok(signer)
}

/// Sign the file `file` just written with `signer`, and say so.
pub fn sign_file(signer: Option<&Signer>, file: &std::path::Path) -> anyhow::Result<()> {
    if let Some(signer) = signer {
        let path = host::output::folder::signature::sign_detached(signer, file)
            .with_context(|| format!("{}: cannot write its signature", file.display()))?;
        eprintln!(
            "signed by '{}' ({}): {}",
            signer.name(),
            host::output::folder::signature::fingerprint(&signer.public_key()),
            path.display()
        );
    } else {
        // A signature of what the file held before no longer holds: gone, the file is
        // plainly unsigned.
        let stale = host::output::folder::signature::detached_path(file);
        if stale.exists() {
            std::fs::remove_file(&stale)
                .with_context(|| format!("{}: cannot remove", stale.display()))?;
        }
    }
    Ok(())
}

/// Run `gonio keys`.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let keys = Keys::from_env()?;
    match args.command {
        Command::New(a) => {
            let info = keys.create(&a.name, a.force)?;
            if a.default {
                keys.set_default(&a.name)?;
            }
            println!(
                "{}: key '{}' made, {}\npublic key: {}\n(gonio keys export-public {} prints it for others to trust)",
                info.path.display(),
                info.public.name,
                info.public.fingerprint,
                info.public.public_key,
                info.public.name
            );
        }
        Command::List => list(&keys)?,
        Command::ExportPublic(a) => {
            let info = keys
                .own()?
                .into_iter()
                .find(|k| k.public.name == a.name)
                .ok_or_else(|| host::output::folder::signature::KeyError::NoSuchKey {
                    name: host::text::shown(&a.name),
                    dir: keys.dir().to_path_buf(),
                })?;
            println!("{}", serde_json::to_string_pretty(&info.public)?);
        }
        Command::Trust(a) => trust(&keys, a)?,
        Command::Default(a) => {
            keys.set_default(&a.name)?;
            println!("'{}' signs by default", a.name);
        }
    }
    Ok(ExitCode::from(crate::cli::exit::OK))
}

/// `gonio keys list`.
fn list(keys: &Keys) -> anyhow::Result<()> {
    let own = keys.own()?;
    let trusted = keys.trusted()?;
    {
        println!("keys in {}:", keys.dir().display());
        if own.is_empty() {
            println!("  (none: gonio keys new NAME makes one)");
        }
        for k in &own {
            println!(
                "  {:<20} {}  created {}{}",
                k.public.name,
                k.public.fingerprint,
                k.public.created,
                if k.default { "  (default)" } else { "" }
            );
        }
        println!("trusted public keys:");
        if trusted.is_empty() {
            println!("  (none: gonio keys trust FILE|KEY --name NAME adds one)");
        }
        for k in &trusted {
            println!("  {:<20} {}  trusted {}", k.name, k.fingerprint, k.created);
        }
    }
    Ok(())
}

/// `gonio keys trust`.
fn trust(keys: &Keys, a: TrustArgs) -> anyhow::Result<()> {
    let path = PathBuf::from(&a.key);
    let (key, given_name) = if path.is_file() {
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("{}: cannot read", path.display()))?;
        let doc = read_public(&path, &text)?;
        (
            parse_public_key(&doc.public_key).map_err(anyhow::Error::msg)?,
            Some(doc.name),
        )
    } else {
        let key = parse_public_key(&a.key).map_err(|e| {
            anyhow::anyhow!(
                "'{}' is neither a public key file nor a public key: {e}",
                host::text::shown(&a.key)
            )
        })?;
        (key, None)
    };
    let name = a
        .name
        .or(given_name)
        .context("give --name NAME: the name the key is trusted under (whose key it is)")?;
    let doc = keys.trust(&name, &key, a.force)?;
    println!(
        "trusted '{}' ({}): gonio verify accepts what this key signed",
        doc.name, doc.fingerprint
    );
    Ok(())
}
