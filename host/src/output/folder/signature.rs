//! Signatures of what gonio writes, and the keys that make them (issue 30, the chain of
//! custody). A session or sheet folder is signed over its manifest (which holds the
//! SHA-256 of every file), a library export and a compare report over the file's bytes,
//! with an Ed25519 key of the lab or the instrument.
//!
//! # What is signed
//!
//! A folder gets `signature.json` beside `MANIFEST.sha256`, written right after it; a file
//! `F` gets `F.sig.json`. Both are a [`SignatureDoc`]. The message signed is the text
//!
//! ```text
//! gonio-signature/1
//! signer: NAME
//! signed_at: TIME
//! sha256: HEX
//! ```
//!
//! (each line ending in `\n`), where `HEX` is the SHA-256 of the manifest's bytes (the
//! folder's identity) or of the file's: the signature covers the name and the time the
//! signer gave as well as what was signed, and anyone with the public key can rebuild
//! the message from `signature.json` and check it with any Ed25519 tool.
//!
//! # The keys
//!
//! A keys folder ([`Keys`]: `$GONIO_KEYS_DIR`, else `$XDG_CONFIG_HOME/gonio/keys`, else
//! `~/.config/gonio/keys`) holds the user's own keys, `NAME.key` (a [`KeyFile`]: the private
//! key as PKCS#8 PEM, readable by the owner only), the public keys trusted, `NAME.pub` (a
//! [`PublicKeyDoc`], as `gonio keys export-public` prints them), and the name of the key
//! that signs by default, `default`. A folder's signer is trusted when its public key is
//! one of the own keys or of the trusted ones: the name in `signature.json` is the
//! signer's claim, the trust is looked up by the key.
use crate::output::folder::manifest::sha256_hex;
use crate::output::folder::store::{SignManifest, Store};
use crate::output::folder::{Finding, MANIFEST};
use ed25519_dalek::pkcs8::{DecodePrivateKey, EncodePrivateKey};
use ed25519_dalek::{Signature, Signer as _, SigningKey, VerifyingKey};
use serde::{Deserialize, Serialize};
use std::io;
use std::path::{Path, PathBuf};

pub use crate::output::folder::SIGNATURE;
/// What follows a signed file's name in the name of its signature.
pub const DETACHED_SUFFIX: &str = ".sig.json";
/// The environment variable naming the keys folder (tests, or a lab's shared folder).
pub const KEYS_DIR_ENV: &str = "GONIO_KEYS_DIR";
/// The key `gonio measure --sim` signs with unless given `--key`: made on first use.
pub const SIM_KEY: &str = "sim";
/// The algorithm, as the documents name it.
pub const ALGORITHM: &str = "ed25519";
/// The first line of every signed message (and the schema of [`SignatureDoc`]).
const MESSAGE_HEADER: &str = "gonio-signature/1";
/// The file in the keys folder naming the default key.
const DEFAULT_FILE: &str = "default";

/// What went wrong with a key or the keys folder.
#[derive(Debug, thiserror::Error)]
pub enum KeyError {
    /// Nowhere to keep keys.
    #[error(
        "no keys folder: set {KEYS_DIR_ENV} (or XDG_CONFIG_HOME or HOME, under which gonio keeps gonio/keys)"
    )]
    NoKeysDir,
    /// A name that is not a key name.
    #[error(
        "'{0}' is not a key name: 1 to 64 letters, digits, '.', '-' or '_', not starting with '.' or '-'"
    )]
    BadName(String),
    /// `keys new` of a name taken.
    #[error(
        "{0}: a key of that name exists; it is never replaced without --force (folders it signed would then be checked only against its exported public key)"
    )]
    Exists(PathBuf),
    /// No key of that name.
    #[error(
        "no key named '{name}' in {dir} (gonio keys list shows the keys; gonio keys new NAME makes one)"
    )]
    NoSuchKey {
        /// The name asked for.
        name: String,
        /// The keys folder.
        dir: PathBuf,
    },
    /// Several own keys and none chosen.
    #[error(
        "several keys in {dir} ({names}) and none is the default: give --key NAME, or choose one with gonio keys default NAME"
    )]
    Ambiguous {
        /// The keys folder.
        dir: PathBuf,
        /// The keys' names.
        names: String,
    },
    /// A key file or public key that cannot be used.
    #[error("{path}: {message}")]
    Bad {
        /// The file (or the argument).
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A read or write that failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        source: io::Error,
    },
}

fn io_at(path: &Path) -> impl FnOnce(io::Error) -> KeyError + '_ {
    move |source| KeyError::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn bad(path: &Path, message: impl Into<String>) -> KeyError {
    KeyError::Bad {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

/// Whether `name` can name a key (and so a file in the keys folder).
pub fn check_name(name: &str) -> Result<(), KeyError> {
    let ok = (1..=64).contains(&name.len())
        && !name.starts_with(['.', '-'])
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b"._-".contains(&b));
    if ok {
        Ok(())
    } else {
        Err(KeyError::BadName(crate::text::shown(name)))
    }
}

/// Lowercase hex of `bytes`.
pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// The bytes of the hex text `text`, exactly `N` of them.
fn unhex<const N: usize>(text: &str) -> Option<[u8; N]> {
    if text.len() != 2 * N || !text.is_ascii() {
        return None;
    }
    let mut out = [0u8; N];
    for (k, byte) in out.iter_mut().enumerate() {
        *byte = u8::from_str_radix(&text[2 * k..2 * k + 2], 16).ok()?;
    }
    Some(out)
}

/// A public key's fingerprint: `ed25519:` and the first 8 bytes of the SHA-256 of its 32
/// bytes, in hex. For people to compare by eye; trust is decided on the whole key.
pub fn fingerprint(key: &VerifyingKey) -> String {
    format!("{ALGORITHM}:{}", &sha256_hex(key.as_bytes())[..16])
}

/// The public key that `text` (64 hex digits) is.
pub fn parse_public_key(text: &str) -> Result<VerifyingKey, String> {
    let bytes = unhex::<32>(text.trim())
        .ok_or_else(|| "a public key is 64 hex digits (32 bytes)".to_string())?;
    VerifyingKey::from_bytes(&bytes).map_err(|_| "not an Ed25519 public key".to_string())
}

/// A key file of the keys folder, `NAME.key` (owner-only): the private key and what
/// `gonio keys list` shows of it.
#[derive(Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KeyFile {
    /// `gonio-key/1`.
    pub schema: String,
    /// The key's name.
    pub name: String,
    /// `ed25519`.
    pub algorithm: String,
    /// When it was made (local time, RFC 3339).
    pub created: String,
    /// The public key, 64 hex digits.
    pub public_key: String,
    /// The private key, PKCS#8 PEM (what `openssl pkey` reads).
    pub private_key_pkcs8: String,
}

/// A public key as one lab hands it to another (`gonio keys export-public`), and as the
/// keys folder keeps a trusted one (`NAME.pub`).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PublicKeyDoc {
    /// `gonio-public-key/1`.
    pub schema: String,
    /// The key's name (its holder's, or the one it is trusted under).
    pub name: String,
    /// `ed25519`.
    pub algorithm: String,
    /// The public key, 64 hex digits.
    pub public_key: String,
    /// Its fingerprint ([`fingerprint`]).
    pub fingerprint: String,
    /// When the key was made (own keys) or trusted (trusted ones).
    pub created: String,
}

impl PublicKeyDoc {
    fn new(name: &str, key: &VerifyingKey, created: &str) -> PublicKeyDoc {
        PublicKeyDoc {
            schema: crate::schema::PUBLIC_KEY.into(),
            name: name.into(),
            algorithm: ALGORITHM.into(),
            public_key: hex(key.as_bytes()),
            fingerprint: fingerprint(key),
            created: created.into(),
        }
    }
}

/// A key that signs.
pub struct Signer {
    name: String,
    key: SigningKey,
}

impl std::fmt::Debug for Signer {
    // The private key is never printed.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "Signer({}, {})",
            self.name,
            fingerprint(&self.key.verifying_key())
        )
    }
}

/// Local date-time now, RFC 3339 with milliseconds (as the folder's runs record it).
fn local_now() -> String {
    chrono::Local::now().to_rfc3339_opts(chrono::SecondsFormat::Millis, false)
}

/// The message a signature is made over ([module docs](self)).
fn message(signer: &str, signed_at: &str, sha256: &str) -> String {
    format!("{MESSAGE_HEADER}\nsigner: {signer}\nsigned_at: {signed_at}\nsha256: {sha256}\n")
}

impl Signer {
    /// The key `key`, named `name`.
    pub fn new(name: &str, key: SigningKey) -> Signer {
        Signer {
            name: name.into(),
            key,
        }
    }

    /// Its name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Its public key.
    pub fn public_key(&self) -> VerifyingKey {
        self.key.verifying_key()
    }

    /// The signature of `covered` (the bytes of the file named `covers`), now.
    pub fn sign(&self, covers: &str, covered: &[u8]) -> SignatureDoc {
        let signed_at = local_now();
        let sha256 = sha256_hex(covered);
        let signature = self
            .key
            .sign(message(&self.name, &signed_at, &sha256).as_bytes());
        let public = self.public_key();
        SignatureDoc {
            schema: crate::schema::SIGNATURE.into(),
            algorithm: ALGORITHM.into(),
            signer: self.name.clone(),
            public_key: hex(public.as_bytes()),
            fingerprint: fingerprint(&public),
            signed_at,
            covers: covers.into(),
            sha256,
            signature: hex(&signature.to_bytes()),
        }
    }

    /// [`Signer::sign`], as the bytes of `signature.json` (or `F.sig.json`).
    pub fn sign_bytes(&self, covers: &str, covered: &[u8]) -> io::Result<Vec<u8>> {
        let mut bytes = serde_json::to_vec_pretty(&self.sign(covers, covered))?;
        bytes.push(b'\n');
        Ok(bytes)
    }
}

impl SignManifest for Signer {
    fn signature_bytes(&self, covers: &str, manifest: &[u8]) -> io::Result<Vec<u8>> {
        self.sign_bytes(covers, manifest)
    }
}

/// `signature.json`, or `F.sig.json` of a file `F`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SignatureDoc {
    /// `gonio-signature/1`.
    pub schema: String,
    /// `ed25519`.
    pub algorithm: String,
    /// The name the signer gave its key.
    pub signer: String,
    /// The signer's public key, 64 hex digits.
    pub public_key: String,
    /// Its fingerprint ([`fingerprint`]).
    pub fingerprint: String,
    /// When it was signed, by the signer's clock (local time, RFC 3339).
    pub signed_at: String,
    /// The file signed: `MANIFEST.sha256`, or the signed file's name.
    pub covers: String,
    /// The SHA-256 of that file's bytes, 64 hex digits.
    pub sha256: String,
    /// The Ed25519 signature of the message, 128 hex digits.
    pub signature: String,
}

/// A signature that holds: who signed and when (by their clock).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Signed {
    /// The name the signer gave.
    pub signer: String,
    /// The public key, 64 hex digits.
    pub public_key: String,
    /// Its fingerprint.
    pub fingerprint: String,
    /// When, by the signer's clock.
    pub signed_at: String,
}

/// Check the signature `doc` of `covered` (the bytes of the file it says it covers): the
/// reason when it does not hold.
pub fn check_doc(doc: &SignatureDoc, covered: &[u8]) -> Result<Signed, String> {
    if doc.schema != crate::schema::SIGNATURE {
        return Err(format!(
            "schema '{}' is not {}",
            crate::text::shown(&doc.schema),
            crate::schema::SIGNATURE
        ));
    }
    if doc.algorithm != ALGORITHM {
        return Err(format!(
            "algorithm '{}' is not {ALGORITHM}",
            crate::text::shown(&doc.algorithm)
        ));
    }
    // A line break in a field would let two different documents sign one message.
    if [&doc.signer, &doc.signed_at]
        .iter()
        .any(|s| s.contains(['\n', '\r']))
    {
        return Err("a line break in signer or signed_at".into());
    }
    let key = parse_public_key(&doc.public_key).map_err(|e| format!("public_key: {e}"))?;
    if doc.fingerprint != fingerprint(&key) {
        return Err(format!(
            "fingerprint '{}' is not that of public_key ({})",
            crate::text::shown(&doc.fingerprint),
            fingerprint(&key)
        ));
    }
    let signature = unhex::<64>(&doc.signature)
        .map(|b| Signature::from_bytes(&b))
        .ok_or("signature: not 128 hex digits")?;
    let now = sha256_hex(covered);
    // Checked before the signature, so that the reason says what changed.
    if !doc.sha256.eq_ignore_ascii_case(&now) {
        return Err(format!(
            "{} changed after it was signed (it was signed with SHA-256 {}…, it is now {}…)",
            crate::text::shown(&doc.covers),
            doc.sha256.get(..16).unwrap_or(&doc.sha256),
            &now[..16]
        ));
    }
    key.verify_strict(
        message(&doc.signer, &doc.signed_at, &doc.sha256).as_bytes(),
        &signature,
    )
    .map_err(|_| {
        format!(
            "the signature is not a signature by public_key {} of this {} with this signer and time: it was altered or forged",
            doc.fingerprint,
            crate::text::shown(&doc.covers)
        )
    })?;
    Ok(Signed {
        signer: doc.signer.clone(),
        public_key: doc.public_key.to_ascii_lowercase(),
        fingerprint: doc.fingerprint.clone(),
        signed_at: doc.signed_at.clone(),
    })
}

/// Read the signature file `path` and check it over `covered`; `Ok(None)` when there is
/// no such file (unsigned).
fn check_file_over(path: &Path, covered: &[u8]) -> Result<Option<Signed>, String> {
    let bytes = match std::fs::read(path) {
        Ok(bytes) => bytes,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(format!("cannot read: {e}")),
    };
    let doc: SignatureDoc =
        serde_json::from_slice(&bytes).map_err(|e| format!("not a gonio signature ({e})"))?;
    check_doc(&doc, covered).map(Some)
}

/// The signature of the folder `dir` over its manifest: `Ok(None)` unsigned, or why the
/// signature does not hold.
pub fn check_folder(dir: &Path) -> Result<Option<Signed>, Finding> {
    let path = dir.join(SIGNATURE);
    let problem = |message: String| Finding {
        file: path.clone(),
        line: None,
        message,
    };
    if !path.exists() {
        return Ok(None);
    }
    let manifest = std::fs::read(dir.join(MANIFEST))
        .map_err(|e| problem(format!("signs {MANIFEST}, which cannot be read: {e}")))?;
    check_file_over(&path, &manifest).map_err(problem)
}

/// [`check_folder`] over the manifest already read (`manifest`: its bytes as read), not
/// read again.
pub(crate) fn check_folder_over(dir: &Path, manifest: &[u8]) -> Result<Option<Signed>, Finding> {
    let path = dir.join(SIGNATURE);
    if !path.exists() {
        return Ok(None);
    }
    check_file_over(&path, manifest).map_err(|message| Finding {
        file: path.clone(),
        line: None,
        message,
    })
}

/// The name of the signature of the file `file`: `F.sig.json`.
pub fn detached_path(file: &Path) -> PathBuf {
    let mut name = file.file_name().unwrap_or_default().to_os_string();
    name.push(DETACHED_SUFFIX);
    file.with_file_name(name)
}

/// The signature of the file `file` (`F.sig.json`): `Ok(None)` unsigned, or why it does not
/// hold.
pub fn check_detached(file: &Path) -> Result<Option<Signed>, Finding> {
    let path = detached_path(file);
    let problem = |message: String| Finding {
        file: path.clone(),
        line: None,
        message,
    };
    if !path.exists() {
        return Ok(None);
    }
    let bytes =
        std::fs::read(file).map_err(|e| problem(format!("its file cannot be read: {e}")))?;
    check_file_over(&path, &bytes).map_err(problem)
}

/// Sign the file `file` (already written): `F.sig.json` beside it, replaced atomically.
pub fn sign_detached(signer: &Signer, file: &Path) -> io::Result<PathBuf> {
    let bytes = std::fs::read(file)?;
    let name = file
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let path = detached_path(file);
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let mut temp = tempfile::NamedTempFile::new_in(dir)?;
    io::Write::write_all(temp.as_file_mut(), &signer.sign_bytes(&name, &bytes)?)?;
    temp.as_file().sync_all()?;
    temp.persist(&path).map_err(|e| e.error)?;
    Ok(path)
}

/// The manifest `manifest` was just written into the folder of `store`: sign it with the
/// store's key into `signature.json`; with no key, remove a signature of an earlier
/// manifest (it no longer holds), so the folder is plainly unsigned.
pub(crate) fn sign_manifest(store: &mut Store, manifest: &[u8]) -> io::Result<()> {
    match store.signer() {
        Some(signer) => {
            let bytes = signer.signature_bytes(MANIFEST, manifest)?;
            store.replace(SIGNATURE, &bytes)
        }
        None if store.dir().join(SIGNATURE).exists() => store.remove(SIGNATURE),
        None => Ok(()),
    }
}

/// A finished folder whose signing a kill cut short (its manifest written, its signature
/// not): sign the manifest as it is, when the store has a key and `whole` (the files match
/// the manifest). Returns whether it signed.
pub(crate) fn sign_if_unsigned(store: &mut Store, whole: bool) -> io::Result<bool> {
    let dir = store.dir().to_path_buf();
    if store.signer().is_none() || !whole || dir.join(SIGNATURE).exists() {
        return Ok(false);
    }
    let manifest = std::fs::read(dir.join(MANIFEST))?;
    sign_manifest(store, &manifest)?;
    Ok(true)
}

/// How far a signer is trusted here.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Trust {
    /// One of the user's own keys, by that name.
    Own(String),
    /// A public key the user trusts, under that name.
    Trusted(String),
    /// A key this keys folder does not know.
    Unknown,
}

impl std::fmt::Display for Trust {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Trust::Own(name) => write!(f, "trusted: your own key '{name}'"),
            Trust::Trusted(name) => write!(f, "trusted: as '{name}'"),
            Trust::Unknown => write!(
                f,
                "NOT TRUSTED: a key not among your keys nor the trusted ones"
            ),
        }
    }
}

/// The keys folder.
#[derive(Clone, Debug)]
pub struct Keys {
    dir: PathBuf,
}

/// What `gonio keys list` shows of an own key.
#[derive(Clone, Debug)]
pub struct KeyInfo {
    /// The key's public part, name and creation time.
    pub public: PublicKeyDoc,
    /// Its file.
    pub path: PathBuf,
    /// Whether it is the default.
    pub default: bool,
}

impl Keys {
    /// The keys folder `dir` (made when a key is first written).
    pub fn at(dir: &Path) -> Keys {
        Keys {
            dir: dir.to_path_buf(),
        }
    }

    /// The user's keys folder: `$GONIO_KEYS_DIR`, else `$XDG_CONFIG_HOME/gonio/keys`, else
    /// `$HOME/.config/gonio/keys`.
    pub fn from_env() -> Result<Keys, KeyError> {
        let var = |name: &str| std::env::var_os(name).filter(|v| !v.is_empty());
        let dir = if let Some(dir) = var(KEYS_DIR_ENV) {
            PathBuf::from(dir)
        } else if let Some(config) = var("XDG_CONFIG_HOME") {
            PathBuf::from(config).join("gonio").join("keys")
        } else if let Some(home) = var("HOME") {
            PathBuf::from(home)
                .join(".config")
                .join("gonio")
                .join("keys")
        } else {
            return Err(KeyError::NoKeysDir);
        };
        Ok(Keys { dir })
    }

    /// The folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    fn key_path(&self, name: &str) -> PathBuf {
        self.dir.join(format!("{name}.key"))
    }

    fn public_path(&self, name: &str) -> PathBuf {
        self.dir.join(format!("{name}.pub"))
    }

    /// Make the folder, owner-only.
    fn make_dir(&self) -> Result<(), KeyError> {
        use std::os::unix::fs::DirBuilderExt;
        std::fs::DirBuilder::new()
            .recursive(true)
            .mode(0o700)
            .create(&self.dir)
            .map_err(io_at(&self.dir))
    }

    /// Write `bytes` to `path` (owner-only), whole or not at all; an existing file is kept
    /// (and [`KeyError::Exists`] returned) unless `force`.
    fn write_file(&self, path: &Path, bytes: &[u8], force: bool) -> Result<(), KeyError> {
        use std::os::unix::fs::PermissionsExt;
        self.make_dir()?;
        let mut temp = tempfile::Builder::new()
            .prefix(".gonio-key-")
            .tempfile_in(&self.dir)
            .map_err(io_at(&self.dir))?;
        let file = temp.as_file_mut();
        file.set_permissions(std::fs::Permissions::from_mode(0o600))
            .and_then(|()| io::Write::write_all(file, bytes))
            .and_then(|()| file.sync_all())
            .map_err(io_at(path))?;
        // No-clobber is one link(2): two gonio making the same key at once keep one.
        let persisted = if force {
            temp.persist(path).map(drop)
        } else {
            temp.persist_noclobber(path).map(drop)
        };
        match persisted {
            Ok(()) => {}
            Err(e) if e.error.kind() == io::ErrorKind::AlreadyExists => {
                return Err(KeyError::Exists(path.to_path_buf()));
            }
            Err(e) => return Err(io_at(path)(e.error)),
        }
        std::fs::File::open(&self.dir)
            .and_then(|d| d.sync_all())
            .map_err(io_at(&self.dir))
    }

    /// Make the key `name` (`force`: replace one of that name). The private key is drawn
    /// from the operating system's random source.
    pub fn create(&self, name: &str, force: bool) -> Result<KeyInfo, KeyError> {
        check_name(name)?;
        let path = self.key_path(name);
        if !force && path.exists() {
            return Err(KeyError::Exists(path));
        }
        let mut seed = [0u8; 32];
        rand::TryRngCore::try_fill_bytes(&mut rand::rngs::OsRng, &mut seed).map_err(|e| {
            bad(
                &path,
                format!("cannot draw a key from the system's random source: {e}"),
            )
        })?;
        let key = SigningKey::from_bytes(&seed);
        seed.fill(0);
        // PKCS#8 version 1, without the public key: what OpenSSL 3.0 reads (it refuses the
        // version 2 document with the public key that the key alone would write).
        let pem = ed25519_dalek::pkcs8::KeypairBytes {
            secret_key: key.to_bytes(),
            public_key: None,
        }
        .to_pkcs8_pem(ed25519_dalek::pkcs8::spki::der::pem::LineEnding::LF)
        .map_err(|e| bad(&path, format!("cannot encode the key: {e}")))?;
        let created = local_now();
        let file = KeyFile {
            schema: crate::schema::KEY.into(),
            name: name.into(),
            algorithm: ALGORITHM.into(),
            created: created.clone(),
            public_key: hex(key.verifying_key().as_bytes()),
            private_key_pkcs8: pem.to_string(),
        };
        let mut bytes = serde_json::to_vec_pretty(&file).map_err(|e| bad(&path, e.to_string()))?;
        bytes.push(b'\n');
        self.write_file(&path, &bytes, force)?;
        Ok(KeyInfo {
            public: PublicKeyDoc::new(name, &key.verifying_key(), &created),
            default: self.default_name()?.as_deref() == Some(name),
            path,
        })
    }

    /// Read the key file `path`: refused when others can read it (as ssh refuses).
    fn read_key(path: &Path) -> Result<(KeyFile, SigningKey), KeyError> {
        use std::os::unix::fs::PermissionsExt;
        let meta = std::fs::metadata(path).map_err(io_at(path))?;
        let mode = meta.permissions().mode() & 0o777;
        if mode & 0o077 != 0 {
            return Err(bad(
                path,
                format!(
                    "a private key readable by others (mode {mode:03o}) is not used: chmod 600 it (and ask who else had it)"
                ),
            ));
        }
        let bytes = std::fs::read(path).map_err(io_at(path))?;
        let file: KeyFile = serde_json::from_slice(&bytes)
            .map_err(|e| bad(path, format!("not a gonio key file: {e}")))?;
        if file.schema != crate::schema::KEY || file.algorithm != ALGORITHM {
            return Err(bad(
                path,
                format!("not a {} {ALGORITHM} key", crate::schema::KEY),
            ));
        }
        let key = SigningKey::from_pkcs8_pem(&file.private_key_pkcs8)
            .map_err(|e| bad(path, format!("private_key_pkcs8: {e}")))?;
        if hex(key.verifying_key().as_bytes()) != file.public_key.to_ascii_lowercase() {
            return Err(bad(path, "public_key is not the private key's public key"));
        }
        Ok((file, key))
    }

    /// The key `name`.
    pub fn load(&self, name: &str) -> Result<Signer, KeyError> {
        check_name(name)?;
        let path = self.key_path(name);
        if !path.exists() {
            return Err(KeyError::NoSuchKey {
                name: name.into(),
                dir: self.dir.clone(),
            });
        }
        let (_, key) = Keys::read_key(&path)?;
        Ok(Signer::new(name, key))
    }

    /// The names of the files in the folder with the extension `ext`, sorted.
    fn names(&self, ext: &str) -> Result<Vec<String>, KeyError> {
        let entries = match std::fs::read_dir(&self.dir) {
            Ok(entries) => entries,
            Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(Vec::new()),
            Err(e) => return Err(io_at(&self.dir)(e)),
        };
        let mut names: Vec<String> = entries
            .filter_map(Result::ok)
            .filter_map(|e| e.file_name().into_string().ok())
            .filter_map(|n| n.strip_suffix(ext).map(str::to_string))
            .filter(|n| check_name(n).is_ok())
            .collect();
        names.sort();
        Ok(names)
    }

    /// The own keys, by name.
    pub fn own(&self) -> Result<Vec<KeyInfo>, KeyError> {
        let default = self.default_name()?;
        self.names(".key")?
            .into_iter()
            .map(|name| {
                // The public part only: listing and looking up trust need no private key
                // (loading one to sign checks it whole, and its file's mode).
                let path = self.key_path(&name);
                let bytes = std::fs::read(&path).map_err(io_at(&path))?;
                let file: KeyFile = serde_json::from_slice(&bytes)
                    .map_err(|e| bad(&path, format!("not a gonio key file: {e}")))?;
                let key = parse_public_key(&file.public_key)
                    .map_err(|e| bad(&path, format!("public_key: {e}")))?;
                Ok(KeyInfo {
                    public: PublicKeyDoc::new(&name, &key, &file.created),
                    default: default.as_deref() == Some(name.as_str()),
                    path,
                })
            })
            .collect()
    }

    /// The public keys trusted, by name.
    pub fn trusted(&self) -> Result<Vec<PublicKeyDoc>, KeyError> {
        self.names(".pub")?
            .into_iter()
            .map(|name| {
                let path = self.public_path(&name);
                let text = std::fs::read_to_string(&path).map_err(io_at(&path))?;
                read_public(&path, &text)
            })
            .collect()
    }

    /// Trust the public key `key` under `name` (`force`: replace a trusted key of that name).
    pub fn trust(
        &self,
        name: &str,
        key: &VerifyingKey,
        force: bool,
    ) -> Result<PublicKeyDoc, KeyError> {
        check_name(name)?;
        if self.key_path(name).exists() {
            return Err(bad(
                &self.key_path(name),
                "one of your own keys has this name: trust the key under another --name",
            ));
        }
        let doc = PublicKeyDoc::new(name, key, &local_now());
        let mut bytes =
            serde_json::to_vec_pretty(&doc).map_err(|e| bad(self.dir(), e.to_string()))?;
        bytes.push(b'\n');
        self.write_file(&self.public_path(name), &bytes, force)?;
        Ok(doc)
    }

    /// The key signing by default, when one was chosen.
    pub fn default_name(&self) -> Result<Option<String>, KeyError> {
        let path = self.dir.join(DEFAULT_FILE);
        match std::fs::read_to_string(&path) {
            Ok(text) => {
                let name = text.trim().to_string();
                check_name(&name).map_err(|e| bad(&path, e.to_string()))?;
                Ok(Some(name))
            }
            Err(e) if e.kind() == io::ErrorKind::NotFound => Ok(None),
            Err(e) => Err(io_at(&path)(e)),
        }
    }

    /// Make the own key `name` the default.
    pub fn set_default(&self, name: &str) -> Result<(), KeyError> {
        self.load(name)?;
        self.write_file(
            &self.dir.join(DEFAULT_FILE),
            format!("{name}\n").as_bytes(),
            true,
        )
    }

    /// The key to sign with: `name` when given, else the default, else the only own key;
    /// `None` when there is no key at all.
    pub fn choose(&self, name: Option<&str>) -> Result<Option<Signer>, KeyError> {
        if let Some(name) = name {
            return self.load(name).map(Some);
        }
        if let Some(name) = self.default_name()? {
            return self.load(&name).map(Some);
        }
        let names = self.names(".key")?;
        match names.as_slice() {
            [] => Ok(None),
            [only] => self.load(only).map(Some),
            _ => Err(KeyError::Ambiguous {
                dir: self.dir.clone(),
                names: names.join(", "),
            }),
        }
    }

    /// The key `name`, made first when there is none of that name; and whether it was
    /// made now.
    pub fn load_or_create(&self, name: &str) -> Result<(Signer, bool), KeyError> {
        if self.key_path(name).exists() {
            return Ok((self.load(name)?, false));
        }
        match self.create(name, false) {
            Ok(_) => Ok((self.load(name)?, true)),
            // Another gonio made it in the meantime: that one is the key.
            Err(KeyError::Exists(_)) => Ok((self.load(name)?, false)),
            Err(e) => Err(e),
        }
    }

    /// How far the signer with the public key `public_key` (hex) is trusted here.
    pub fn trust_of(&self, public_key: &str) -> Result<Trust, KeyError> {
        let public_key = public_key.to_ascii_lowercase();
        if let Some(own) = self
            .own()?
            .into_iter()
            .find(|k| k.public.public_key == public_key)
        {
            return Ok(Trust::Own(own.public.name));
        }
        Ok(self
            .trusted()?
            .into_iter()
            .find(|k| k.public_key.to_ascii_lowercase() == public_key)
            .map_or(Trust::Unknown, |k| Trust::Trusted(k.name)))
    }
}

/// The public key document `text` (from the file `path`), checked.
pub fn read_public(path: &Path, text: &str) -> Result<PublicKeyDoc, KeyError> {
    let doc: PublicKeyDoc = serde_json::from_str(text)
        .map_err(|e| bad(path, format!("not a gonio public key ({e})")))?;
    if doc.schema != crate::schema::PUBLIC_KEY || doc.algorithm != ALGORITHM {
        return Err(bad(
            path,
            format!("not a {} {ALGORITHM} key", crate::schema::PUBLIC_KEY),
        ));
    }
    let key = parse_public_key(&doc.public_key).map_err(|e| bad(path, e))?;
    if doc.fingerprint != fingerprint(&key) {
        return Err(bad(path, "fingerprint is not that of public_key"));
    }
    Ok(doc)
}

/// The signer's trust, or a finding saying it is not trusted (a folder or file `at`).
pub fn untrusted(at: &Path, signed: &Signed, keys: Option<&Keys>) -> Option<Finding> {
    let trust = keys.map(|k| k.trust_of(&signed.public_key));
    match trust {
        Some(Ok(Trust::Own(_) | Trust::Trusted(_))) => None,
        Some(Err(e)) => Some(Finding {
            file: at.to_path_buf(),
            line: None,
            message: format!(
                "signed by '{}' ({}), whose trust cannot be looked up: {e}",
                crate::text::shown(&signed.signer),
                signed.fingerprint
            ),
        }),
        _ => Some(Finding {
            file: at.to_path_buf(),
            line: None,
            message: format!(
                "signed by '{}' ({}), a key that is neither yours nor trusted: whoever made that key could have written this; if it is a lab's you trust, gonio keys trust {} --name NAME",
                crate::text::shown(&signed.signer),
                signed.fingerprint,
                signed.public_key
            ),
        }),
    }
}

/// The findings of signers not trusted among `signed` (each a folder and its signer, if
/// signed), looked up in the user's keys folder ([`Keys::from_env`]); unsigned folders
/// are not findings.
pub fn untrusted_signers<'a>(
    signed: impl IntoIterator<Item = (&'a Path, Option<&'a Signed>)>,
) -> Vec<Finding> {
    let keys = Keys::from_env().ok();
    signed
        .into_iter()
        .filter_map(|(dir, s)| untrusted(&dir.join(SIGNATURE), s?, keys.as_ref()))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn signer(seed: u8) -> Signer {
        Signer::new("lab", SigningKey::from_bytes(&[seed; 32]))
    }

    #[test]
    fn a_signature_holds_over_what_it_signed_and_only_that() {
        let s = signer(7);
        let doc = s.sign(MANIFEST, b"abc  x\n");
        let signed = check_doc(&doc, b"abc  x\n").expect("holds");
        assert_eq!(signed.signer, "lab");
        assert!(
            check_doc(&doc, b"abd  x\n")
                .unwrap_err()
                .contains("changed after it was signed")
        );
        // A forger who recomputes sha256 but cannot sign.
        let mut forged = doc.clone();
        forged.sha256 = sha256_hex(b"abd  x\n");
        assert!(
            check_doc(&forged, b"abd  x\n")
                .unwrap_err()
                .contains("altered or forged")
        );
        // The name and the time are signed too.
        for change in [
            |d: &mut SignatureDoc| d.signer = "other".into(),
            |d: &mut SignatureDoc| d.signed_at = "1999-01-01T00:00:00.000+00:00".into(),
        ] {
            let mut changed = doc.clone();
            change(&mut changed);
            assert!(check_doc(&changed, b"abc  x\n").is_err());
        }
        // Another key's public key in the document does not verify the signature.
        let mut swapped = doc.clone();
        let other = signer(8).public_key();
        swapped.public_key = hex(other.as_bytes());
        swapped.fingerprint = fingerprint(&other);
        assert!(check_doc(&swapped, b"abc  x\n").is_err());
    }

    #[test]
    fn the_message_is_the_documented_text() {
        assert_eq!(
            message("lab", "T", "ab"),
            "gonio-signature/1\nsigner: lab\nsigned_at: T\nsha256: ab\n"
        );
    }

    #[test]
    fn key_names_are_file_names_of_the_keys_folder_only() {
        for good in ["lab", "lab-2", "sim", "A.b_c"] {
            assert!(check_name(good).is_ok(), "{good}");
        }
        for bad in [
            "",
            ".hidden",
            "-x",
            "a/b",
            "..",
            "a b",
            "é",
            &"x".repeat(65),
        ] {
            assert!(check_name(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn hex_round_trips_and_rejects_what_is_not_hex() {
        assert_eq!(unhex::<2>("0aff"), Some([0x0a, 0xff]));
        assert_eq!(unhex::<2>("0aff0"), None);
        assert_eq!(unhex::<2>("0ag0"), None);
        assert_eq!(unhex::<2>("éé"), None);
        assert_eq!(hex(&[0x0a, 0xff]), "0aff");
    }
}
