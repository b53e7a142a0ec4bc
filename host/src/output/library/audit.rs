//! The audit trail: every change to a library is one entry of an append-only table (who,
//! when, from which machine and gonio, what), written in the change's own transaction, so
//! a change and its entry exist together or not at all. Both back ends keep it; the
//! database refuses to change or delete an entry (triggers; on PostgreSQL no role has the
//! right either).
//!
//! What the entries carry is enough to recover the library's contents as they were after
//! any entry ([`super::Library::contents_at`]): an add records the digest of the sheet it
//! added (the contents identity of that sheet alone), a removal the whole sheet it took
//! away. Going back from today's contents, entry by entry, undoes each change; the digests
//! check that the sheets still in the library are the ones that were added.
use super::SheetRecord;
use crate::analysis::evidence::{LibrarySheet, Sheet, population};
use serde::{Deserialize, Serialize};

/// One entry of the trail, as `gonio library history` shows it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AuditEntry {
    /// Its number: entries are numbered in the order their changes committed.
    pub entry: i64,
    /// When (UTC RFC 3339; on PostgreSQL the server's clock, stamped by the database).
    pub at: String,
    /// The database role that made the change (PostgreSQL's `session_user`, stamped by the
    /// database, not given by gonio); `None` for an SQLite file, which has no roles.
    pub db_user: Option<String>,
    /// The operating-system user gonio ran as.
    pub os_user: Option<String>,
    /// The machine gonio ran on.
    pub host: Option<String>,
    /// The gonio that made the change (`gonio 0.1.0`).
    pub gonio_version: String,
    /// `create`, `upgrade`, `add`, `import`, `remove`, `validate` or `migrate`.
    pub action: String,
    /// The stock concerned, when one is.
    pub stock: Option<String>,
    /// The session (SHA-256) concerned, when one is.
    pub session_sha256: Option<String>,
    /// The instrument that measured the session, when one is concerned.
    pub instrument_serial: Option<String>,
    /// What else the change needs to be undone or checked (see the module's comment).
    pub detail: serde_json::Value,
}

/// What a change writes into the trail; the back end adds its number, time and role.
#[derive(Clone, Debug)]
pub(crate) struct NewEntry {
    pub action: &'static str,
    pub stock: Option<String>,
    pub session_sha256: Option<String>,
    pub instrument_serial: Option<String>,
    pub detail: serde_json::Value,
}

/// Who is making a change, as this process can tell.
#[derive(Clone, Debug)]
pub(crate) struct Actor {
    pub os_user: Option<String>,
    pub host: Option<String>,
    pub gonio_version: String,
}

impl Actor {
    /// This process's user and machine.
    pub fn current() -> Actor {
        let os_user = ["USER", "LOGNAME", "USERNAME"]
            .iter()
            .find_map(|name| std::env::var(name).ok().filter(|v| !v.is_empty()));
        let host = nix::unistd::gethostname()
            .ok()
            .and_then(|h| h.into_string().ok())
            .filter(|h| !h.is_empty());
        Actor {
            os_user,
            host,
            gonio_version: format!("gonio {}", env!("CARGO_PKG_VERSION")),
        }
    }
}

/// A sheet record as the evidence weighs it (what a library's contents identity covers).
pub(crate) fn library_sheet(stock: &str, sheet: &SheetRecord) -> LibrarySheet {
    LibrarySheet {
        stock: stock.to_string(),
        lot: sheet.lot.clone(),
        instrument: Some(sheet.instrument_serial.clone()),
        sheet: Sheet {
            spots: sheet.spots.clone(),
        },
    }
}

/// The digest an add records of its sheet: the contents identity of that sheet alone.
pub(crate) fn sheet_digest(sheet: &LibrarySheet) -> String {
    population::contents_identity(std::slice::from_ref(sheet))
}

/// The entry of a sheet added (by `add`, or `import` of `from`).
pub(crate) fn added(action: &'static str, stock: &str, sheet: &SheetRecord) -> NewEntry {
    let weighed = library_sheet(stock, sheet);
    NewEntry {
        action,
        stock: Some(stock.to_string()),
        session_sha256: Some(sheet.session_sha256.clone()),
        instrument_serial: Some(sheet.instrument_serial.clone()),
        detail: serde_json::json!({
            "sheet_sha256": sheet_digest(&weighed),
            "spots": sheet.spots.len(),
            "session_path": sheet.session_path,
            "sample": sheet.sample,
        }),
    }
}

/// The entry of a sheet removed: the whole sheet, so that it can be put back by a replay.
pub(crate) fn removed(
    session_sha256: &str,
    instrument: Option<&str>,
    sheet: &LibrarySheet,
) -> NewEntry {
    NewEntry {
        action: "remove",
        stock: Some(sheet.stock.clone()),
        session_sha256: Some(session_sha256.to_string()),
        instrument_serial: instrument.map(str::to_string),
        detail: serde_json::json!({ "sheet": sheet }),
    }
}

/// The entry of a population validated and recorded for contents of `identity`.
pub(crate) fn validated(identity: &str) -> NewEntry {
    NewEntry {
        action: "validate",
        stock: None,
        session_sha256: None,
        instrument_serial: None,
        detail: serde_json::json!({ "contents": identity }),
    }
}

/// An entry with only an action and its detail (create, upgrade, migrate).
pub(crate) fn event(action: &'static str, detail: serde_json::Value) -> NewEntry {
    NewEntry {
        action,
        stock: None,
        session_sha256: None,
        instrument_serial: None,
        detail,
    }
}

/// An entry of another library copied by a migration: the action, stock, session and
/// instrument as they were, and the original's number, time and who under `origin` (the
/// copy itself is stamped with the migration's own time and role; an entry copied before
/// keeps its earlier `origin` inside the new one).
pub(crate) fn migrated(original: &AuditEntry, from: &str) -> NewEntry {
    let mut detail = original.detail.clone();
    let mut origin = serde_json::json!({
        "library": from,
        "entry": original.entry,
        "at": original.at,
        "db_user": original.db_user,
        "os_user": original.os_user,
        "host": original.host,
        "gonio_version": original.gonio_version,
    });
    match &mut detail {
        serde_json::Value::Object(map) => {
            // Copied before: the earlier origin goes inside this one, so a trail migrated
            // twice still leads back to the original entry.
            if let Some(earlier) = map.remove("origin") {
                origin["origin"] = earlier;
            }
            map.insert("origin".into(), origin);
        }
        other => {
            *other = serde_json::json!({ "origin": origin, "was": other.clone() });
        }
    }
    NewEntry {
        action: match original.action.as_str() {
            "create" => "create",
            "upgrade" => "upgrade",
            "add" => "add",
            "import" => "import",
            "remove" => "remove",
            "validate" => "validate",
            _ => "migrate",
        },
        stock: original.stock.clone(),
        session_sha256: original.session_sha256.clone(),
        instrument_serial: original.instrument_serial.clone(),
        detail,
    }
}

/// The actions an entry may have (a CHECK in both back ends).
pub(crate) const ACTIONS: &str =
    "'create', 'upgrade', 'add', 'import', 'remove', 'validate', 'migrate'";
