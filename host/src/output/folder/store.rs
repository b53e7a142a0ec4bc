//! Every write into a session folder goes through [`Store`]: lines appended whole, files
//! replaced atomically, the folder itself created atomically. One place that a test can
//! tell to "crash" at its N-th write ([`Crash`]), leaving the folder exactly as a killed
//! process would.
//!
//! # What is synced when
//!
//! A process that is killed (SIGKILL, a panic, the OOM killer) loses nothing that a
//! `write(2)` returned for: the data are in the kernel's page cache. Power loss or a kernel
//! crash loses what was not yet `fsync`ed. So:
//!
//! - an append ([`Store::append`]) is one `write` call of one whole line, on a file opened
//!   for appending and never buffered in the process. The primary record `points.jsonl` is
//!   also `fdatasync`ed after every line ([`Sync::Data`]): a reading costs tens of
//!   milliseconds of device time or more, an `fdatasync` about a millisecond, and it bounds
//!   the loss at power failure to the reading being written. The derived `readings.csv` and
//!   the decision log `session.log` are not synced per line ([`Sync::Never`]); a resume
//!   rebuilds `readings.csv` from `points.jsonl`, and both are synced at the end of every
//!   run ([`Store::sync_all`]), so power loss can cost at most the log lines of the run in
//!   progress;
//! - a replaced file ([`Store::replace`]: `session.json`, `calibration.json`, the summary
//!   files, the manifest) is written to a temporary file in the same folder, `fsync`ed,
//!   renamed over the old one and the folder `fsync`ed: after a kill or a power loss it is
//!   the old file or the new one, never a mix. A temporary file left by a kill is named
//!   `.NAME.gonio-tmp` and removed by the next `--resume`
//!   ([`crate::output::folder::is_temp_name`]);
//! - a new file or folder is made durable by an `fsync` of the folder that holds it.
use crate::output::folder::temp_name;
use std::collections::{HashMap, HashSet};
use std::fs::{File, OpenOptions};
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// When an append is synced to the disk.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Sync {
    /// `fdatasync` after the line: the primary record.
    Data,
    /// Only at [`Store::sync_all`] (the end of a run): derived files and the log.
    Never,
}

/// What a simulated fault does at its write.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Fault {
    /// The process is killed: a prefix of the write reaches the file, then nothing more.
    #[default]
    Kill,
    /// The disk is full from this write on: a prefix of it is written and it fails, and
    /// so does every later write of data; the process goes on (and rolls back what it can).
    DiskFull,
    /// The operator presses Ctrl-C as this write is made: the write is made whole and
    /// [`Crash::interrupt`] is set, as the binary's SIGINT handler sets the flag it gave
    /// `measure_with`.
    Interrupt,
}

/// A simulated fault at the `at`-th write (from 1): a kill (the default) or a full disk.
/// `count` counts every write made, so that a first run without a fault (`at: None`) tells
/// how many writes a session makes.
#[derive(Clone, Debug, Default)]
pub struct Crash {
    /// The write to fail at; `None` only counts.
    pub at: Option<u64>,
    /// What happens there.
    pub fault: Fault,
    /// Writes made so far (shared, so the test can read it after the session).
    pub count: Arc<AtomicU64>,
    /// The flag a [`Fault::Interrupt`] sets (give the same to `measure_with`).
    pub interrupt: Arc<AtomicBool>,
}

impl Crash {
    /// Count writes, fail at none.
    pub fn counting() -> Crash {
        Crash::default()
    }

    /// Kill the process at the `n`-th write (from 1).
    pub fn at(n: u64) -> Crash {
        Crash {
            at: Some(n),
            ..Crash::default()
        }
    }

    /// Fill the disk at the `n`-th write (from 1).
    pub fn disk_full_at(n: u64) -> Crash {
        Crash {
            at: Some(n),
            fault: Fault::DiskFull,
            ..Crash::default()
        }
    }

    /// Ctrl-C at the `n`-th write (from 1): `interrupt` is set there.
    pub fn interrupt_at(n: u64, interrupt: Arc<AtomicBool>) -> Crash {
        Crash {
            at: Some(n),
            fault: Fault::Interrupt,
            interrupt,
            ..Crash::default()
        }
    }

    /// Writes made (or attempted, the failing one included).
    pub fn writes(&self) -> u64 {
        self.count.load(Ordering::Relaxed)
    }

    /// Whether the fault happened.
    pub fn crashed(&self) -> bool {
        self.at.is_some_and(|at| self.writes() >= at)
    }
}

/// How I/O ends in a [`Store`]: for real, or through a simulated fault.
#[derive(Clone, Debug, Default)]
pub struct StoreOptions {
    /// A simulated fault (tests); `None` for real use.
    pub crash: Option<Crash>,
    /// The key that signs the folder's manifest when it is written (`signature.json`;
    /// in use the `Signer` of the `signature` module, above this); `None`: the folder is left unsigned.
    pub signer: Option<std::sync::Arc<dyn SignManifest>>,
}

/// What signs a folder's manifest: the store asks it for the bytes of the signature file
/// (what a signature is, and the keys, are the `signature` module's, above this).
pub trait SignManifest: Send + std::marker::Sync + std::fmt::Debug {
    /// The signature file's bytes for the manifest `manifest` (the bytes of `covers`).
    fn signature_bytes(&self, covers: &str, manifest: &[u8]) -> io::Result<Vec<u8>>;
}

/// What the store does at one write.
enum Step {
    /// Do it.
    Whole,
    /// Do only this many bytes of it (or nothing, for a rename), then fail with `error`;
    /// `dead` when the process is gone (no more I/O at all).
    Cut { len: usize, dead: bool },
}

fn crashed_error() -> io::Error {
    io::Error::other("simulated crash: the process is gone, no more writes")
}

fn disk_full_error() -> io::Error {
    io::Error::new(
        io::ErrorKind::StorageFull,
        "no space left on device (simulated)",
    )
}

/// The one writer of a session folder.
pub(crate) struct Store {
    dir: PathBuf,
    options: StoreOptions,
    appenders: HashMap<String, File>,
    /// Files an append failed on and could not be cut back: never appended to again, so
    /// that nothing is written onto a partial line.
    poisoned: HashSet<String>,
    dead: bool,
}

impl Store {
    /// Create the folder `dir` (its parent must exist); fails with
    /// [`io::ErrorKind::AlreadyExists`] if it does, so two sessions never share one.
    pub fn create_dir(dir: &Path, options: StoreOptions) -> io::Result<Store> {
        let mut store = Store::open_dir(dir, options);
        let step = store.step(0)?;
        step.whole_or(|dead| Err(store.fail(dead)))?;
        std::fs::create_dir(dir)?;
        if let Some(parent) = dir.parent().filter(|p| !p.as_os_str().is_empty()) {
            sync_dir(parent)?;
        }
        Ok(store)
    }

    /// Write into the existing folder `dir`.
    pub(crate) fn open_dir(dir: &Path, options: StoreOptions) -> Store {
        Store {
            dir: dir.to_path_buf(),
            options,
            appenders: HashMap::new(),
            poisoned: HashSet::new(),
            dead: false,
        }
    }

    /// The folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The key that signs the folder's manifest, if any.
    pub(crate) fn signer(&self) -> Option<&dyn SignManifest> {
        self.options.signer.as_deref()
    }

    /// Whether the store crashed (simulated) and refuses every write (its tests ask).
    #[cfg(test)]
    pub(crate) fn is_dead(&self) -> bool {
        self.dead
    }

    /// Account for one write of `len` bytes (0: an operation on names, or a truncation).
    fn step(&mut self, len: usize) -> io::Result<Step> {
        if self.dead {
            return Err(crashed_error());
        }
        let Some(crash) = &self.options.crash else {
            return Ok(Step::Whole);
        };
        let n = crash.count.fetch_add(1, Ordering::Relaxed) + 1;
        // Cut somewhere inside the write, differently for different writes.
        let cut = if len == 0 {
            0
        } else {
            (n as usize).wrapping_mul(2_654_435_761) % len
        };
        match (crash.at, crash.fault) {
            (Some(at), Fault::Kill) if n == at => Ok(Step::Cut {
                len: cut,
                dead: true,
            }),
            // Another store sharing the crash: the process is gone for it too.
            (Some(at), Fault::Kill) if n > at => {
                self.dead = true;
                self.appenders.clear();
                Err(crashed_error())
            }
            // A full disk takes data, not names or truncations.
            (Some(at), Fault::DiskFull) if n == at && len > 0 => Ok(Step::Cut {
                len: cut,
                dead: false,
            }),
            (Some(at), Fault::DiskFull) if n > at && len > 0 => Ok(Step::Cut {
                len: 0,
                dead: false,
            }),
            (Some(at), Fault::Interrupt) if n == at => {
                crash.interrupt.store(true, Ordering::SeqCst);
                Ok(Step::Whole)
            }
            _ => Ok(Step::Whole),
        }
    }

    /// After a cut write: the error to return, and the store dead if the process is.
    fn fail(&mut self, dead: bool) -> io::Error {
        if dead {
            self.dead = true;
            self.appenders.clear();
            crashed_error()
        } else {
            disk_full_error()
        }
    }

    fn appender(&mut self, name: &str) -> io::Result<&mut File> {
        if !self.appenders.contains_key(name) {
            let path = self.dir.join(name);
            let existed = path.exists();
            if !existed {
                // Creating the file is a write of its own: it can be where the crash is.
                if let Step::Cut { dead, .. } = self.step(0)? {
                    return Err(self.fail(dead));
                }
            }
            let file = open_in_folder(&path, OpenOptions::new().create(true).append(true))?;
            if !existed {
                sync_dir(&self.dir)?;
            }
            self.appenders.insert(name.to_string(), file);
        }
        Ok(self.appenders.get_mut(name).expect("inserted above"))
    }

    /// Append `line` (which must end in a newline) to `name` in one `write` call. If the
    /// write fails part-way (a full disk), the file is cut back to where it was; if even
    /// that fails, the file takes no further appends.
    pub fn append(&mut self, name: &str, line: &[u8], sync: Sync) -> io::Result<()> {
        debug_assert!(line.ends_with(b"\n"), "appends are whole lines");
        if self.poisoned.contains(name) {
            return Err(io::Error::other(format!(
                "{name}: an earlier write failed part-way and could not be undone; resume to repair it"
            )));
        }
        self.appender(name)?;
        let step = self.step(line.len())?;
        let file = self.appenders.get_mut(name).expect("opened above");
        let before = file.metadata()?.len();
        let result = match step {
            Step::Whole => file.write_all(line).and_then(|()| {
                if sync == Sync::Data {
                    file.sync_data()
                } else {
                    Ok(())
                }
            }),
            Step::Cut { len, dead: true } => {
                let _ = file.write_all(&line[..len]);
                return Err(self.fail(true));
            }
            Step::Cut { len, dead: false } => {
                let _ = file.write_all(&line[..len]);
                Err(disk_full_error())
            }
        };
        if let Err(error) = result {
            let file = self.appenders.get_mut(name).expect("opened above");
            if file
                .set_len(before)
                .and_then(|()| file.sync_data())
                .is_err()
            {
                self.poisoned.insert(name.to_string());
            }
            return Err(error);
        }
        Ok(())
    }

    /// Replace `name` by `bytes` atomically: a temporary file in the folder, `fsync`,
    /// rename, `fsync` of the folder. A failed write (a full disk) removes the temporary file
    /// and leaves the old one.
    pub fn replace(&mut self, name: &str, bytes: &[u8]) -> io::Result<()> {
        let temp = self.dir.join(temp_name(name));
        let written = match self.step(bytes.len())? {
            Step::Whole => create_in_folder(&temp).and_then(|mut file| {
                file.write_all(bytes)?;
                file.sync_all()
            }),
            Step::Cut { len, dead } => {
                if let Ok(mut file) = create_in_folder(&temp) {
                    let _ = file.write_all(&bytes[..len]);
                }
                if dead {
                    return Err(self.fail(true));
                }
                Err(disk_full_error())
            }
        };
        if let Err(error) = written {
            let _ = std::fs::remove_file(&temp);
            return Err(error);
        }
        let step = self.step(0)?;
        step.whole_or(|dead| Err(self.fail(dead)))?;
        std::fs::rename(&temp, self.dir.join(name))?;
        // An appender open on the old file would write into the replaced inode.
        self.appenders.remove(name);
        self.poisoned.remove(name);
        sync_dir(&self.dir)
    }

    /// Cut `name` to its first `len` bytes (a resume drops a line cut short by a crash).
    pub fn truncate(&mut self, name: &str, len: u64) -> io::Result<()> {
        let step = self.step(0)?;
        step.whole_or(|dead| Err(self.fail(dead)))?;
        let file = open_in_folder(&self.dir.join(name), OpenOptions::new().write(true))?;
        file.set_len(len)?;
        file.sync_all()
    }

    /// Remove `name` (a temporary file a kill left behind).
    pub fn remove(&mut self, name: &str) -> io::Result<()> {
        let step = self.step(0)?;
        step.whole_or(|dead| Err(self.fail(dead)))?;
        self.appenders.remove(name);
        std::fs::remove_file(self.dir.join(name))?;
        sync_dir(&self.dir)
    }

    /// `fdatasync` one appended file (lines appended with [`Sync::Never`] become durable).
    pub(crate) fn sync_file(&mut self, name: &str) -> io::Result<()> {
        if self.dead {
            return Err(crashed_error());
        }
        match self.appenders.get(name) {
            Some(file) => file.sync_data(),
            None => Ok(()),
        }
    }

    /// `fsync` every file appended to, and the folder: the end of a run.
    pub fn sync_all(&mut self) -> io::Result<()> {
        if self.dead {
            return Err(crashed_error());
        }
        for file in self.appenders.values() {
            file.sync_all()?;
        }
        sync_dir(&self.dir)
    }
}

impl Step {
    /// `Ok` for a whole step; for a cut one (a rename or a name that is not made), `cut`.
    fn whole_or(self, cut: impl FnOnce(bool) -> io::Result<()>) -> io::Result<()> {
        match self {
            Step::Whole => Ok(()),
            Step::Cut { dead, .. } => cut(dead),
        }
    }
}

/// Open `path`, a file inside a session folder, with `options`, refusing a symbolic link
/// at its name (`O_NOFOLLOW`): a link in the folder could lead the write anywhere outside it
/// (issue 30: a `session.log` linked elsewhere was written through). The error says so.
pub(crate) fn open_in_folder(path: &Path, options: &mut OpenOptions) -> io::Result<File> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt as _;
        options.custom_flags(nix::libc::O_NOFOLLOW);
    }
    options.open(path).map_err(|error| {
        let is_link = std::fs::symlink_metadata(path).is_ok_and(|m| m.file_type().is_symlink());
        if is_link {
            io::Error::new(
                io::ErrorKind::InvalidInput,
                format!(
                    "{} is a symbolic link: gonio writes nothing through a link inside a session folder (it could lead outside the folder); remove the link",
                    path.display()
                ),
            )
        } else {
            error
        }
    })
}

/// [`open_in_folder`] to create or truncate `path` for writing (as [`File::create`]).
pub(crate) fn create_in_folder(path: &Path) -> io::Result<File> {
    open_in_folder(
        path,
        OpenOptions::new().write(true).create(true).truncate(true),
    )
}

/// `fsync` a folder, so that the names in it (new files, renames) survive a power loss.
pub(crate) fn sync_dir(dir: &Path) -> io::Result<()> {
    #[cfg(unix)]
    {
        File::open(dir)?.sync_all()
    }
    #[cfg(not(unix))]
    {
        let _ = dir;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::output::folder::is_temp_name;

    fn temp(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("gonio-store-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        dir
    }

    #[test]
    fn a_crash_cuts_one_write_and_refuses_the_rest() {
        let dir = temp("crash");
        let crash = Crash::at(3);
        let mut store = Store::create_dir(
            &dir,
            StoreOptions {
                crash: Some(crash.clone()),
                ..Default::default()
            },
        )
        .unwrap();
        // 1: the folder; 2: creating a.txt; 3: its first line, cut short.
        let line = b"0123456789abcdef\n";
        assert!(store.append("a.txt", line, Sync::Data).is_err());
        assert!(store.is_dead() && crash.crashed());
        let kept = std::fs::read(dir.join("a.txt")).unwrap();
        assert!(
            kept.len() < line.len() && line.starts_with(&kept),
            "a prefix: {kept:?}"
        );
        assert!(store.replace("b.json", b"{}").is_err());
        assert!(!dir.join("b.json").exists() && !dir.join(temp_name("b.json")).exists());
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_full_disk_cuts_an_append_back_and_keeps_the_old_file() {
        let dir = temp("full");
        let mut store = Store::create_dir(&dir, StoreOptions::default()).unwrap();
        store.append("a.txt", b"first\n", Sync::Data).unwrap();
        store.replace("s.json", b"old").unwrap();
        // 1: the append's data, cut part-way; 2: the replace's data; 3: another append.
        let mut store = Store::open_dir(
            &dir,
            StoreOptions {
                crash: Some(Crash::disk_full_at(1)),
                ..Default::default()
            },
        );
        let error = store
            .append("a.txt", b"second line\n", Sync::Data)
            .unwrap_err();
        assert_eq!(error.kind(), io::ErrorKind::StorageFull);
        assert_eq!(
            std::fs::read(dir.join("a.txt")).unwrap(),
            b"first\n",
            "cut back to the last whole line"
        );
        assert_eq!(
            store.replace("s.json", b"new").unwrap_err().kind(),
            io::ErrorKind::StorageFull
        );
        assert_eq!(std::fs::read(dir.join("s.json")).unwrap(), b"old");
        assert!(
            !dir.join(temp_name("s.json")).exists(),
            "no temporary file left"
        );
        assert!(store.append("a.txt", b"third\n", Sync::Never).is_err());
        assert_eq!(std::fs::read(dir.join("a.txt")).unwrap(), b"first\n");
        assert!(!store.is_dead(), "a full disk is not a dead process");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_replace_cut_short_leaves_the_old_file_and_a_temporary_one() {
        let dir = temp("replace");
        let mut store = Store::create_dir(&dir, StoreOptions::default()).unwrap();
        store.replace("s.json", b"old").unwrap();
        let crash = Crash::at(1);
        let mut store = Store::open_dir(
            &dir,
            StoreOptions {
                crash: Some(crash),
                ..Default::default()
            },
        );
        assert!(store.replace("s.json", b"new and longer").is_err());
        assert_eq!(std::fs::read(dir.join("s.json")).unwrap(), b"old");
        assert!(dir.join(temp_name("s.json")).exists());
        assert!(is_temp_name(&temp_name("s.json")) && !is_temp_name("s.json"));
        // Crash at the rename: the new content is complete in the temporary file only.
        let mut store = Store::open_dir(
            &dir,
            StoreOptions {
                crash: Some(Crash::at(2)),
                ..Default::default()
            },
        );
        assert!(store.replace("s.json", b"new").is_err());
        assert_eq!(std::fs::read(dir.join("s.json")).unwrap(), b"old");
        assert!(
            Store::create_dir(&dir, StoreOptions::default())
                .is_err_and(|e| e.kind() == io::ErrorKind::AlreadyExists)
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
