//! Taking a folder to write: the lock that keeps other `gonio` processes out while one
//! writes it, and [`FolderError`], why a folder cannot be taken (for a new session or
//! sheet, or to resume one).
use crate::output::folder::{Finding, SESSION, SHEET, Status};
use std::io;
use std::path::{Path, PathBuf};

/// Why a folder cannot take this session.
#[derive(Debug, thiserror::Error)]
pub enum FolderError {
    /// `--out` onto a folder that holds something.
    #[error("{} is not empty (it holds {}): a session folder holds one session only; give a new or empty folder to --out", .dir.display(), .entries)]
    NotEmpty {
        /// The folder.
        dir: PathBuf,
        /// Some of what it holds.
        entries: String,
    },
    /// `--out` onto another session's folder.
    #[error(
        "{} holds another session (sample '{}', instrument {}, started {}, {}): continue it with gonio measure --resume {}, or give a new folder to --out",
        .dir.display(), crate::text::shown(.sample), crate::text::shown(.serial), crate::text::shown(.started), .status, .dir.display()
    )]
    OtherSession {
        /// The folder.
        dir: PathBuf,
        /// Its sample.
        sample: String,
        /// Its instrument's serial number.
        serial: String,
        /// When its first run started.
        started: String,
        /// Where it stands.
        status: Status,
    },
    /// Not a folder.
    #[error("{} is not a folder", .0.display())]
    NotAFolder(PathBuf),
    /// `--resume` onto a folder that holds no session.
    #[error("{} holds no session (no session.json, no readings): nothing was measured there; start a session with --out {}", .0.display(), .0.display())]
    NoSession(PathBuf),
    /// `--resume` onto a missing folder.
    #[error("no session folder {}: give the folder of the session to resume", .0.display())]
    NoFolder(PathBuf),
    /// A finished session is not measured again.
    #[error(
        "{} holds a finished session of '{}' (finished {}{}): it is not measured again; its result is in {} (gonio verify {} checks the folder); measure anew with --out NEW_FOLDER",
        .dir.display(), crate::text::shown(.sample), crate::text::shown(.ended), .class.as_ref().map(|c| format!(", class {}", crate::text::shown(c))).unwrap_or_default(), .dir.join(SESSION).display(), .dir.display()
    )]
    Finished {
        /// The folder.
        dir: PathBuf,
        /// Its sample.
        sample: String,
        /// Its class.
        class: Option<String>,
        /// When it finished.
        ended: String,
    },
    /// A finished sheet of several spots is not measured again.
    #[error(
        "{} holds a finished sheet of '{}' ({} spots): it is not measured again; its result is in {} (gonio verify {} checks the folder); measure anew with --out NEW_FOLDER",
        .dir.display(), crate::text::shown(.sample), .spots, .dir.join(SHEET).display(), .dir.display()
    )]
    FinishedSheet {
        /// The folder.
        dir: PathBuf,
        /// Its sample.
        sample: String,
        /// Its spots measured.
        spots: usize,
    },
    /// `--resume` with another sample, instrument or plan.
    #[error("cannot resume {}: {}; a session is continued only as it began (or start a new one with --out)", .dir.display(), .differences.join("; "))]
    Mismatch {
        /// The folder.
        dir: PathBuf,
        /// What differs, in words.
        differences: Vec<String>,
    },
    /// Damage a resume does not repair.
    #[error("cannot resume: {0}; nothing was changed in the folder")]
    Damaged(Finding),
    /// Another process has the folder.
    #[error("{} is in use by another gonio process: one session, one process", .0.display())]
    InUse(PathBuf),
    /// The folder could not be written.
    #[error("cannot write the session folder {}: {source}", .dir.display())]
    Io {
        /// The folder.
        dir: PathBuf,
        /// Why.
        source: io::Error,
    },
}

pub(crate) fn io_error(dir: &Path) -> impl Fn(io::Error) -> FolderError + '_ {
    move |source| FolderError::Io {
        dir: dir.to_path_buf(),
        source,
    }
}

/// Keeps other `gonio` processes out of a folder while this one writes it (an advisory
/// lock on the folder itself, which survives the renames inside it; the kernel drops it
/// when the process ends, however it ends).
pub struct FolderLock {
    #[cfg(unix)]
    _lock: nix::fcntl::Flock<std::fs::File>,
}

impl FolderLock {
    /// Lock `dir`, or say it is in use.
    pub fn take(dir: &Path) -> Result<FolderLock, FolderError> {
        #[cfg(unix)]
        {
            let file = std::fs::File::open(dir).map_err(io_error(dir))?;
            match nix::fcntl::Flock::lock(file, nix::fcntl::FlockArg::LockExclusiveNonblock) {
                Ok(lock) => Ok(FolderLock { _lock: lock }),
                Err((_, nix::errno::Errno::EWOULDBLOCK)) => {
                    Err(FolderError::InUse(dir.to_path_buf()))
                }
                Err((_, errno)) => Err(FolderError::Io {
                    dir: dir.to_path_buf(),
                    source: io::Error::from(errno),
                }),
            }
        }
        #[cfg(not(unix))]
        {
            let _ = dir;
            Ok(FolderLock {})
        }
    }
}
