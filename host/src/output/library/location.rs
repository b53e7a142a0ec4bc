//! Where a library is: an SQLite file of one machine, or a PostgreSQL database an
//! institute shares; and the `[library]` setting that names it once for every command.
use super::{LibraryError, Result};
use std::ffi::OsString;
use std::path::{Path, PathBuf};

/// A library's place, as `--library` or the `[library]` setting gives it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Location {
    /// An SQLite file (one machine; the default).
    File(PathBuf),
    /// A PostgreSQL database, by its connection URL (`postgresql://…` or `postgres://…`,
    /// as libpq reads it). Kept whole (it may hold a password); shown without the password.
    Postgres(String),
}

impl Location {
    /// A library named on a command line or in the settings: a `postgresql://` or
    /// `postgres://` URL is a PostgreSQL database, anything else a file path.
    pub fn from_arg(arg: OsString) -> Location {
        match arg.to_str() {
            Some(s) if s.starts_with("postgresql://") || s.starts_with("postgres://") => {
                Location::Postgres(s.to_string())
            }
            _ => Location::File(PathBuf::from(arg)),
        }
    }

    /// The library a command uses when `--library` is not given: the `[library]` setting
    /// ([`Settings::find`]) when there is one, else the SQLite file of
    /// [`super::default_path`].
    pub fn configured() -> Result<Location> {
        if let Some((file, settings)) = Settings::find()?
            && let Some(library) = settings.library
        {
            return library.location(&file);
        }
        super::default_path().map(Location::File).ok_or_else(|| {
            LibraryError::Invalid(
                "no library: give --library FILE or URL, or set [library] location in the settings (neither XDG_DATA_HOME nor HOME is set)".into(),
            )
        })
    }

    /// The SQLite file, when it is one.
    pub fn file(&self) -> Option<&Path> {
        match self {
            Location::File(path) => Some(path),
            Location::Postgres(_) => None,
        }
    }
}

impl std::fmt::Display for Location {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Location::File(path) => write!(f, "{}", path.display()),
            Location::Postgres(url) => f.write_str(&without_password(url)),
        }
    }
}

/// A connection URL as it may be shown: a password in its user part or its query
/// (`password=`) replaced by `***`, so that no message, report or audit entry carries it.
pub fn without_password(url: &str) -> String {
    let (scheme, rest) = url.split_once("://").unwrap_or(("", url));
    let authority_end = rest.find(['/', '?']).unwrap_or(rest.len());
    let (authority, tail) = rest.split_at(authority_end);
    let authority = match authority.rsplit_once('@') {
        Some((user, host)) => match user.split_once(':') {
            Some((name, _password)) => format!("{name}:***@{host}"),
            None => authority.to_string(),
        },
        None => authority.to_string(),
    };
    let tail = match tail.split_once('?') {
        Some((path, query)) => {
            let query: Vec<String> = query
                .split('&')
                .map(|pair| match pair.split_once('=') {
                    Some((key, _)) if key.eq_ignore_ascii_case("password") => {
                        format!("{key}=***")
                    }
                    _ => pair.to_string(),
                })
                .collect();
            format!("{path}?{}", query.join("&"))
        }
        None => tail.to_string(),
    };
    if scheme.is_empty() {
        format!("{authority}{tail}")
    } else {
        format!("{scheme}://{authority}{tail}")
    }
}

/// The environment variable naming the settings file (a lab's or a test's own).
pub const SETTINGS_ENV: &str = "GONIO_SETTINGS";

/// The settings file where an institute names its library once:
///
/// ```toml
/// [library]
/// location = "postgresql://examiner@db.lab.example/gonio"
/// ```
///
/// Read from `$GONIO_SETTINGS` when set, else the user's
/// `$XDG_CONFIG_HOME/gonio/settings.toml` (`~/.config/gonio/settings.toml`), else the
/// machine's `/etc/gonio/settings.toml`: the first that exists, whole (not merged). An
/// unknown section or key is an error naming it, never ignored: a misspelt setting would
/// otherwise send an examiner's search to another library without a word.
#[derive(Clone, Debug, Default, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Settings {
    /// `[library]`.
    pub library: Option<LibrarySetting>,
}

/// `[library]` of the settings.
#[derive(Clone, Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LibrarySetting {
    /// A file path (relative to the settings file's folder) or a `postgresql://` URL.
    pub location: String,
}

impl LibrarySetting {
    fn location(&self, settings_file: &Path) -> Result<Location> {
        if self.location.trim().is_empty() {
            return Err(LibraryError::Invalid(format!(
                "{}: [library] location is empty",
                settings_file.display()
            )));
        }
        Ok(match Location::from_arg(OsString::from(&self.location)) {
            Location::File(path) if path.is_relative() => {
                Location::File(settings_file.parent().unwrap_or(Path::new(".")).join(path))
            }
            location => location,
        })
    }
}

impl Settings {
    /// The settings file in force and what it says, if there is one (see [`Settings`]).
    pub fn find() -> Result<Option<(PathBuf, Settings)>> {
        let var = |name: &str| std::env::var_os(name).filter(|v| !v.is_empty());
        if let Some(file) = var(SETTINGS_ENV) {
            let file = PathBuf::from(file);
            return Settings::read(&file).map(|s| Some((file, s)));
        }
        let user = var("XDG_CONFIG_HOME")
            .map(PathBuf::from)
            .filter(|p| p.is_absolute())
            .or_else(|| var("HOME").map(|home| PathBuf::from(home).join(".config")))
            .map(|base| base.join("gonio").join("settings.toml"));
        for file in user
            .into_iter()
            .chain([PathBuf::from("/etc/gonio/settings.toml")])
        {
            if file.exists() {
                return Settings::read(&file).map(|s| Some((file, s)));
            }
        }
        Ok(None)
    }

    /// Read one settings file.
    pub fn read(file: &Path) -> Result<Settings> {
        let text = std::fs::read_to_string(file).map_err(|source| LibraryError::Io {
            path: file.to_path_buf(),
            source,
        })?;
        toml::from_str(&text).map_err(|e| {
            LibraryError::Invalid(format!(
                "{}: not gonio settings: {}",
                file.display(),
                e.to_string().trim_end()
            ))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_password_is_never_shown() {
        for (url, shown) in [
            (
                "postgresql://curator:s3cret@db.lab:5432/gonio",
                "postgresql://curator:***@db.lab:5432/gonio",
            ),
            (
                "postgres://examiner@db/gonio?password=x&sslmode=disable",
                "postgres://examiner@db/gonio?password=***&sslmode=disable",
            ),
            (
                "postgresql://a:b@%2Ftmp%2Fpg/lib",
                "postgresql://a:***@%2Ftmp%2Fpg/lib",
            ),
            (
                "postgresql:///lib?host=/run/postgresql",
                "postgresql:///lib?host=/run/postgresql",
            ),
        ] {
            assert_eq!(without_password(url), shown);
            assert_eq!(
                Location::from_arg(url.into()).to_string(),
                shown,
                "{url} shown"
            );
        }
        assert_eq!(
            Location::from_arg("lib.sqlite".into()),
            Location::File("lib.sqlite".into())
        );
        assert_eq!(
            Location::from_arg("postgresql.sqlite".into()),
            Location::File("postgresql.sqlite".into())
        );
    }

    #[test]
    fn settings_name_the_library_and_refuse_what_they_do_not_know() {
        let dir = tempfile::tempdir().expect("temp dir");
        let file = dir.path().join("settings.toml");
        std::fs::write(
            &file,
            "[library]\nlocation = \"postgresql://examiner@db/gonio\"\n",
        )
        .expect("write");
        let settings = Settings::read(&file).expect("read");
        assert_eq!(
            settings
                .library
                .expect("[library]")
                .location(&file)
                .expect("location"),
            Location::Postgres("postgresql://examiner@db/gonio".into())
        );
        std::fs::write(&file, "[library]\nlocation = \"shared/lib.sqlite\"\n").expect("write");
        let settings = Settings::read(&file).expect("read");
        assert_eq!(
            settings
                .library
                .expect("[library]")
                .location(&file)
                .expect("location"),
            Location::File(dir.path().join("shared/lib.sqlite"))
        );
        for (text, names) in [
            ("[libary]\nlocation = \"x\"\n", "libary"),
            ("[library]\nlocaton = \"x\"\n", "locaton"),
            ("[library]\nlocation = 3\n", "location"),
        ] {
            std::fs::write(&file, text).expect("write");
            let err = Settings::read(&file).expect_err(text).to_string();
            assert!(
                err.contains("settings.toml") && err.contains(names),
                "{err}"
            );
        }
    }
}
