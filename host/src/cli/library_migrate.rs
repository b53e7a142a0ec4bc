//! `gonio library migrate --to NEW`: the whole library copied into a new, empty one of
//! either back end (SQLite → PostgreSQL when a lab joins its institute's collection, and
//! back), with its audit trail and recorded validations; both exported afterwards and
//! compared byte for byte, the migration failing if they differ.
use super::library::MigrateArgs;
use host::output::library::{self, Library, Location, OpenMode};

/// Run `gonio library migrate`.
pub fn run(from: &Location, args: MigrateArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        *from != args.to,
        "{from}: a library cannot be migrated into itself"
    );
    let source = Library::open(from, OpenMode::Existing)?;
    let mut target = Library::open(&args.to, OpenMode::Add)?;
    let migrated = library::migrate(&source, &mut target)?;
    println!(
        "{from} → {}: {} sessions ({} records), {} audit entries and {} recorded validations copied; both export to the same bytes (SHA-256 {})",
        args.to,
        migrated.sessions,
        migrated.records,
        migrated.audit_entries,
        migrated.validations,
        migrated.export_sha256
    );
    Ok(())
}
