//! `gonio library history`: the library's audit trail (who changed what, when, from which
//! machine and gonio), or with `--contents-at N` the contents as they were just after
//! entry N, recovered from the trail: the contents identity a search or comparison made
//! then reported (`library_state` of their JSON) is found again from the trail alone.
use super::library::HistoryArgs;
use host::output::library::{AuditEntry, Library, Location, OpenMode};
use serde_json::json;

/// Run `gonio library history`.
pub fn run(location: &Location, args: HistoryArgs) -> anyhow::Result<()> {
    let library = Library::open(location, OpenMode::Existing)?;
    if let Some(entry) = args.contents_at {
        let replayed = library.contents_at(entry)?;
        let stocks: std::collections::BTreeSet<&str> = replayed
            .sheets
            .iter()
            .map(|(_, s)| s.stock.as_str())
            .collect();
        let population = if args.population {
            let sheets: Vec<_> = replayed.sheets.iter().map(|(_, s)| s.clone()).collect();
            let (population, _) = host::analysis::evidence::validation::validate_or_explain(
                &sheets,
            )
            .map_err(|e| {
                anyhow::anyhow!(
                    "{location}: the contents after entry {entry} make no population: {e}"
                )
            })?;
            Some(population.identity())
        } else {
            None
        };
        if args.json {
            println!(
                "{}",
                json!({
                    "schema": host::schema::LIBRARY_CONTENTS_AT,
                    "library": location.to_string(),
                    "entry": entry,
                    "contents": replayed.identity,
                    "stocks": stocks.len(),
                    "sheets": replayed.sheets.len(),
                    "sessions": replayed.sheets.iter().map(|(sha, _)| sha).collect::<Vec<_>>(),
                    "checked_against_trail": replayed.checked_against_trail,
                    "population": population,
                })
            );
        } else {
            println!(
                "{location}: after audit entry {entry}: {} sheet{} of {} stock{}; contents identity {}",
                replayed.sheets.len(),
                if replayed.sheets.len() == 1 { "" } else { "s" },
                stocks.len(),
                if stocks.len() == 1 { "" } else { "s" },
                replayed.identity
            );
            if let Some(identity) = &population {
                println!("  population made from them: identity {identity}");
            }
            println!(
                "  ({} sheet{} held today checked against the entries that added them)",
                replayed.checked_against_trail,
                if replayed.checked_against_trail == 1 {
                    ""
                } else {
                    "s"
                }
            );
        }
        return Ok(());
    }
    let entries: Vec<AuditEntry> = library
        .audit_entries()?
        .into_iter()
        .filter(|e| args.stock.is_none() || e.stock == args.stock)
        .collect();
    if args.json {
        println!(
            "{}",
            json!({
                "schema": host::schema::LIBRARY_HISTORY,
                "library": location.to_string(),
                "entries": entries,
            })
        );
        return Ok(());
    }
    println!(
        "{location}: {} audit entr{}",
        entries.len(),
        if entries.len() == 1 { "y" } else { "ies" }
    );
    for e in &entries {
        println!("{}", line(e));
    }
    Ok(())
}

/// One entry as a line: number, time, who (the database role, else the system user) and
/// where, what, and what it concerned.
fn line(e: &AuditEntry) -> String {
    let shown = |s: &Option<String>| s.as_deref().map(host::text::shown);
    let who = match (shown(&e.db_user), shown(&e.os_user), shown(&e.host)) {
        (Some(role), Some(user), Some(host)) => format!("{role} ({user}@{host})"),
        (Some(role), _, _) => role,
        (None, Some(user), Some(host)) => format!("{user}@{host}"),
        (None, Some(user), None) => user,
        _ => "unknown".into(),
    };
    let mut what = e.action.clone();
    if let Some(stock) = shown(&e.stock) {
        what.push_str(&format!(" stock '{stock}'"));
    }
    if let Some(sha) = &e.session_sha256 {
        what.push_str(&format!(" session {}", sha.get(..12).unwrap_or(sha)));
    }
    if let Some(serial) = shown(&e.instrument_serial) {
        what.push_str(&format!(" (instrument {serial})"));
    }
    if let Some(origin) = e.detail.get("origin") {
        what.push_str(&format!(
            " [migrated: entry {} of {} at {}]",
            origin["entry"],
            host::text::shown(origin["library"].as_str().unwrap_or("?")),
            origin["at"].as_str().unwrap_or("?")
        ));
    }
    format!(
        "  {:>6}  {}  {}  {}  {}",
        e.entry,
        e.at,
        who,
        host::text::shown(&e.gonio_version),
        what
    )
}
