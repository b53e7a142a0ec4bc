//! `gonio library …`: the reference library of measured paper stocks (issue 13), an SQLite
//! file or an institute's PostgreSQL database (`host::output::library`). Add session
//! folders under a stock, list, remove, exchange with other labs (JSON Lines,
//! `docs/LIBRARY.md`), search (which stock is a measured sheet most likely from), show the
//! audit trail, and migrate a library from one back end to another.
//!
//! Exit codes: 0 done; 1 failed (the message says what and where; a refused add or import
//! changes nothing); 2 a wrong command line.
use anyhow::Context;
use host::analysis::evidence::{self, Warning};
use host::output::folder::signature::{self, Keys};
use host::output::library::{self, ExchangeFile, Library, Location, OpenMode, StockInfo};
use serde_json::json;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Arguments of `gonio library`.
#[derive(clap::Args)]
#[command(
    after_help = "Exit codes: 0 done; 1 failed (nothing is changed by a refused add, import or remove); 2 a wrong command line; 3 a search done with warnings (printed)."
)]
pub struct Args {
    /// The library: a file, or a PostgreSQL URL (postgresql://USER@HOST/DB) [default: the
    /// [library] setting of the settings file, else $XDG_DATA_HOME/gonio/library.sqlite,
    /// else ~/.local/share/gonio/library.sqlite].
    #[arg(long, global = true, value_name = "FILE|URL", value_parser = location_arg())]
    pub library: Option<Location>,
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// `gonio library` subcommands.
#[derive(clap::Subcommand)]
pub enum Command {
    /// Add measured sheets (session folders of `gonio measure`) under a stock; creates the library when missing.
    Add(AddArgs),
    /// List the stocks with their sheet and spot counts.
    List(ListArgs),
    /// Remove a stock (with all its sheets) or one session.
    Remove(RemoveArgs),
    /// Write every spot to FILE as JSON Lines (the exchange format, docs/LIBRARY.md); `-` for standard output.
    Export(ExportArgs),
    /// Add the records of an exchange file; sessions already in the library are skipped. `-` for standard input.
    Import(ImportArgs),
    /// Rank the library's stocks by the likelihood ratio of a measured sheet against each.
    Search(SearchArgs),
    /// Show the audit trail: who changed what, when, from which machine and gonio.
    History(HistoryArgs),
    /// Copy the whole library into a new, empty one (SQLite ↔ PostgreSQL), checked byte for byte.
    Migrate(MigrateArgs),
}

/// The parser of a `--library` value: a `postgresql://` URL or a file path.
pub fn location_arg() -> impl clap::builder::TypedValueParser<Value = Location> {
    use clap::builder::TypedValueParser;
    clap::builder::OsStringValueParser::new().map(Location::from_arg)
}

/// Arguments of `gonio library history`.
#[derive(clap::Args)]
pub struct HistoryArgs {
    /// Print one JSON object instead of the table.
    #[arg(long)]
    pub json: bool,
    /// Only the entries of this stock.
    #[arg(long, value_name = "NAME")]
    pub stock: Option<String>,
    /// Instead of the entries: the library's contents as they were just after entry N,
    /// recovered from the trail (the contents identity a search made then reported).
    #[arg(long, value_name = "N", conflicts_with = "stock")]
    pub contents_at: Option<i64>,
    /// With --contents-at: also make the population of those contents, as a search of
    /// them makes it, and give its identity (the `population.identity` the search reported
    /// when it used a population made or cached, not one recorded by `gonio forensic`).
    #[arg(long, requires = "contents_at")]
    pub population: bool,
}

/// Arguments of `gonio library migrate`.
#[derive(clap::Args)]
pub struct MigrateArgs {
    /// The new, empty library to copy into (a file or a PostgreSQL URL); `--library` is the
    /// one copied from.
    #[arg(long, value_name = "FILE|URL", value_parser = location_arg())]
    pub to: Location,
}

/// Arguments of `gonio library add`.
#[derive(clap::Args)]
pub struct AddArgs {
    /// The stock the sheets are of (made when new).
    #[arg(long, value_name = "NAME")]
    pub stock: String,
    /// Lot or ream of these sheets.
    #[arg(long, value_name = "L")]
    pub lot: Option<String>,
    /// The stock's manufacturer (recorded when the library has none; must agree when it has).
    #[arg(long, value_name = "M")]
    pub manufacturer: Option<String>,
    /// Notes on the stock (recorded when the library has none; must agree when it has).
    #[arg(long, value_name = "TEXT")]
    pub notes: Option<String>,
    /// Add sessions whose result is flagged (`ok: false`) too.
    #[arg(long)]
    pub allow_flagged: bool,
    /// Refuse a folder that is not signed (a signed one must be signed by your key or one
    /// you trust, with or without this).
    #[arg(long)]
    pub require_signed: bool,
    /// Session folders, each finished and verifying as `gonio verify` checks it.
    #[arg(required = true, value_name = "DIR")]
    pub dirs: Vec<PathBuf>,
}

/// Arguments of `gonio library list`.
#[derive(clap::Args)]
pub struct ListArgs {
    /// Print one JSON object instead of the table.
    #[arg(long)]
    pub json: bool,
}

/// Arguments of `gonio library remove`.
#[derive(clap::Args)]
#[group(required = true, multiple = false)]
pub struct RemoveArgs {
    /// Remove this stock with all its sheets.
    #[arg(long, value_name = "NAME")]
    pub stock: Option<String>,
    /// Remove this session: its SHA-256 (as `list --json`/`export` show it) or a prefix only it has.
    #[arg(long, value_name = "SHA")]
    pub session: Option<String>,
}

/// Arguments of `gonio library export`.
#[derive(clap::Args)]
pub struct ExportArgs {
    /// The exchange file to write (replaced whole), or `-`.
    #[arg(value_name = "FILE")]
    pub file: PathBuf,
    /// The key (gonio keys list) that signs it (FILE.sig.json); default: the default or
    /// only key. Standard output is not signed.
    #[arg(long, value_name = "NAME")]
    pub key: Option<String>,
}

/// Arguments of `gonio library import`.
#[derive(clap::Args)]
pub struct ImportArgs {
    /// The exchange file to read, or `-`. Its signature (FILE.sig.json), when there is
    /// one, must hold and be by your key or one you trust.
    #[arg(value_name = "FILE")]
    pub file: PathBuf,
    /// Refuse a file that is not signed (standard input cannot be).
    #[arg(long)]
    pub require_signed: bool,
}

/// Arguments of `gonio library search`.
#[derive(clap::Args)]
pub struct SearchArgs {
    /// Print one JSON object instead of the table.
    #[arg(long)]
    pub json: bool,
    /// Show only the K best stocks.
    #[arg(long, value_name = "K")]
    pub top: Option<usize>,
    /// The measured sheet: a session folder (or its session.json).
    #[arg(value_name = "DIR")]
    pub dir: PathBuf,
}

/// Run `gonio library`.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let path = match args.library {
        Some(location) => location,
        None => Location::configured()?,
    };
    let done = |r: anyhow::Result<()>| r.map(|()| crate::cli::exit::OK);
    let code = match args.command {
        Command::Add(add) => done(run_add(&path, add)),
        Command::List(list) => done(run_list(&path, list)),
        Command::Remove(remove) => done(run_remove(&path, remove)),
        Command::Export(export) => done(run_export(&path, export)),
        Command::Import(import) => done(run_import(&path, import)),
        Command::Search(search) => run_search(&path, search),
        Command::History(history) => done(crate::cli::library_history::run(&path, history)),
        Command::Migrate(migrate) => done(crate::cli::library_migrate::run(&path, migrate)),
    }?;
    Ok(ExitCode::from(code))
}

fn short(sha256: &str) -> &str {
    sha256.get(..12).unwrap_or(sha256)
}

/// How many characters of a stock name a table shows: names are free text (an imported
/// file may hold a name of any length), and a table's column cannot be as wide as any.
const NAME_COLUMN: usize = 40;

/// A name from the library as a table cell: escaped and cut ([`host::text`]).
fn cell(name: &str) -> String {
    host::text::shown_at_most(name, NAME_COLUMN)
}

/// The width of a column of `cells`, at least that of its header.
fn column_width<'a>(cells: impl Iterator<Item = &'a String>) -> usize {
    cells.map(|c| c.chars().count()).max().unwrap_or(0).max(5)
}

fn run_add(path: &Location, args: AddArgs) -> anyhow::Result<()> {
    // Every folder is read and checked before the library is opened: a refused add
    // leaves no new, empty library behind.
    let keys = Keys::from_env().ok();
    let mut sheets = Vec::new();
    let mut related = Vec::new();
    for dir in &args.dirs {
        let sheet = library::read_session_folder(dir, args.lot.as_deref(), args.allow_flagged)?;
        let signature = dir.join(signature::SIGNATURE);
        let signed = signature::check_folder(dir).map_err(|f| anyhow::anyhow!("{f}"))?;
        custody(
            &signature,
            signed.as_ref(),
            args.require_signed,
            keys.as_ref(),
        )
        .map_err(|why| anyhow::anyhow!("{why}; nothing was added"))?;
        if let Some(earlier) = sheets
            .iter()
            .find(|s: &&library::SheetRecord| s.session_sha256 == sheet.session_sha256)
        {
            anyhow::bail!(
                "{} and {} are the same session ({}): given twice; nothing was added",
                earlier.session_path,
                dir.display(),
                sheet.session_sha256
            );
        }
        let same_sheet = library::same_sheet_folders(dir);
        for (earlier, earlier_dir) in sheets.iter().zip(&args.dirs) {
            if same_sheet
                .iter()
                .any(|(identity, _)| *identity == earlier.session_sha256)
            {
                return Err(library::LibraryError::SameSheet {
                    dir: dir.clone(),
                    other: earlier_dir.display().to_string(),
                    where_: "given in this add too; nothing was added".into(),
                }
                .into());
            }
        }
        sheets.push(sheet);
        related.push(same_sheet);
    }
    let stock = StockInfo {
        name: args.stock.clone(),
        manufacturer: args.manufacturer,
        notes: args.notes,
    };
    let mut library = Library::open(path, OpenMode::Add)?;
    for (dir, same_sheet) in args.dirs.iter().zip(&related) {
        for (identity, other) in same_sheet {
            if let Some(stock) = library.stock_of_session(identity)? {
                return Err(library::LibraryError::SameSheet {
                    dir: dir.clone(),
                    other: other.display().to_string(),
                    where_: format!(
                        "already in the library under stock '{}' (session {}); nothing was added",
                        host::text::shown(&stock),
                        short(identity)
                    ),
                }
                .into());
            }
        }
    }
    library.add_sheets(&stock, &sheets)?;
    for sheet in &sheets {
        println!(
            "added {} (sample '{}', instrument {}, session {}) to stock '{}'",
            host::text::shown(&sheet.session_path),
            host::text::shown(&sheet.sample),
            host::text::shown(&sheet.instrument_serial),
            short(&sheet.session_sha256),
            host::text::shown(&args.stock)
        );
    }
    println!(
        "{}: {} sheet{} added",
        path,
        sheets.len(),
        if sheets.len() == 1 { "" } else { "s" }
    );
    Ok(())
}

fn run_list(path: &Location, args: ListArgs) -> anyhow::Result<()> {
    let library = Library::open(path, OpenMode::Existing)?;
    let stocks = library.stocks()?;
    if args.json {
        println!(
            "{}",
            json!({"schema": host::schema::LIBRARY_LIST, "library": path.to_string(), "database_version": library::SCHEMA_VERSION, "stocks": stocks})
        );
        return Ok(());
    }
    println!(
        "{}: {} stock{}",
        path,
        stocks.len(),
        if stocks.len() == 1 { "" } else { "s" }
    );
    if stocks.is_empty() {
        return Ok(());
    }
    let names: Vec<String> = stocks.iter().map(|s| cell(&s.name)).collect();
    let width = column_width(names.iter());
    println!(
        "  {:<width$}  {:>6}  {:>6}  manufacturer",
        "stock", "sheets", "spots"
    );
    for (s, name) in stocks.iter().zip(&names) {
        println!(
            "  {:<width$}  {:>6}  {:>6}  {}",
            name,
            s.sheets,
            s.spots,
            s.manufacturer.as_deref().map_or_else(|| "—".into(), cell)
        );
    }
    Ok(())
}

fn run_remove(path: &Location, args: RemoveArgs) -> anyhow::Result<()> {
    let mut library = Library::open(path, OpenMode::Existing)?;
    let removed = match (&args.stock, &args.session) {
        (Some(stock), _) => library.remove_stock(stock)?,
        (None, Some(session)) => library.remove_session(session)?,
        (None, None) => anyhow::bail!("give --stock NAME or --session SHA"),
    };
    for sha in &removed.sessions {
        println!("removed session {sha}");
    }
    for stock in &removed.stocks {
        println!("removed stock '{}'", host::text::shown(stock));
    }
    println!(
        "{}: {} session{} and {} spot{} removed",
        path,
        removed.sessions.len(),
        if removed.sessions.len() == 1 { "" } else { "s" },
        removed.spots,
        if removed.spots == 1 { "" } else { "s" }
    );
    Ok(())
}

fn run_export(path: &Location, args: ExportArgs) -> anyhow::Result<()> {
    let library = Library::open(path, OpenMode::Existing)?;
    if args.file.as_os_str() == "-" {
        let stdout = std::io::stdout();
        library.export(&mut stdout.lock(), Path::new("(standard output)"))?;
        return Ok(());
    }
    // Chosen before anything is written: a wrong --key stops here.
    let signer = crate::cli::keys::file_signer(args.key.as_deref(), "the export")?;
    // Written beside the target and renamed over it: an interrupted export never leaves
    // a half file that a later import would take for a whole one.
    let dir = args
        .file
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let mut temp = tempfile::NamedTempFile::new_in(dir)
        .with_context(|| format!("{}: cannot write there", dir.display()))?;
    let records = {
        let mut out = std::io::BufWriter::new(temp.as_file_mut());
        let records = library.export(&mut out, &args.file)?;
        out.flush()
            .with_context(|| args.file.display().to_string())?;
        records
    };
    temp.as_file()
        .sync_all()
        .with_context(|| args.file.display().to_string())?;
    temp.persist(&args.file)
        .with_context(|| format!("{}: cannot write", args.file.display()))?;
    crate::cli::keys::sign_file(signer.as_ref(), &args.file)?;
    eprintln!(
        "{}: {records} record{} (one per spot) written to {}",
        path,
        if records == 1 { "" } else { "s" },
        args.file.display()
    );
    Ok(())
}

/// Whether what `signature_file` signs (by `signed`, when signed) may enter the library:
/// a signature must be by your key or one you trust (as `gonio verify` requires), and
/// with `require_signed` there must be one. What to say of it, or why not.
fn custody(
    signature_file: &Path,
    signed: Option<&signature::Signed>,
    require_signed: bool,
    keys: Option<&Keys>,
) -> Result<String, String> {
    let Some(signed) = signed else {
        return if require_signed {
            Err(format!(
                "{}: missing: not signed (--require-signed)",
                signature_file.display()
            ))
        } else {
            Ok("unsigned: its custody rests on its hashes alone".into())
        };
    };
    if let Some(finding) = signature::untrusted(signature_file, signed, keys) {
        return Err(finding.to_string());
    }
    Ok(format!(
        "signed by '{}' ({})",
        host::text::shown(&signed.signer),
        signed.fingerprint
    ))
}

fn run_import(path: &Location, args: ImportArgs) -> anyhow::Result<()> {
    // The file is read and checked first, so a bad file creates no empty library. Its
    // signature is checked over the very bytes parsed, not over a second read that the
    // file could have changed between.
    let file = if args.file.as_os_str() == "-" {
        if args.require_signed {
            anyhow::bail!(
                "standard input cannot carry a signature (--require-signed): give the file, with its {}; nothing was imported",
                signature::DETACHED_SUFFIX
            );
        }
        ExchangeFile::read(&mut std::io::stdin().lock(), Path::new("(standard input)"))?
    } else {
        let bytes = std::fs::read(&args.file)
            .with_context(|| format!("{}: cannot read", args.file.display()))?;
        let sig_path = signature::detached_path(&args.file);
        let signed = match std::fs::read(&sig_path) {
            Ok(sig) => {
                let checked = serde_json::from_slice::<signature::SignatureDoc>(&sig)
                    .map_err(|e| format!("not a gonio signature ({e})"))
                    .and_then(|doc| signature::check_doc(&doc, &bytes));
                match checked {
                    Ok(signed) => Some(signed),
                    Err(why) => {
                        anyhow::bail!("{}: {why}; nothing was imported", sig_path.display())
                    }
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
            Err(e) => anyhow::bail!("{}: cannot read: {e}", sig_path.display()),
        };
        let keys = Keys::from_env().ok();
        let said = custody(
            &sig_path,
            signed.as_ref(),
            args.require_signed,
            keys.as_ref(),
        )
        .map_err(|why| anyhow::anyhow!("{why}; nothing was imported"))?;
        eprintln!("{}: {said}", args.file.display());
        ExchangeFile::read(&mut &bytes[..], &args.file)?
    };
    let mut library = Library::open(path, OpenMode::Add)?;
    let counts = library.import(&file)?;
    println!(
        "{}: {} records read; {} session{} added, {} already present (skipped); {} new stock{}",
        path,
        counts.records,
        counts.sessions_added,
        if counts.sessions_added == 1 { "" } else { "s" },
        counts.sessions_skipped,
        counts.stocks_added,
        if counts.stocks_added == 1 { "" } else { "s" }
    );
    Ok(())
}

/// One stock's result in `search`.
#[derive(serde::Serialize)]
struct Ranked {
    stock: String,
    sheets: usize,
    /// How the stock's sheets lay: `md`, `cd`, `mixed` or `unknown`.
    orientation: &'static str,
    /// `felt`, `wire`, `mixed` or `unknown`.
    side: &'static str,
    log10_lr: f64,
    raw_log10_lr: f64,
    verbal: String,
}

/// Exit 0 when nothing warns, 3 with warnings (printed).
fn run_search(path: &Location, args: SearchArgs) -> anyhow::Result<u8> {
    let measured =
        host::output::folder::sheet::read_measured(&args.dir).map_err(anyhow::Error::msg)?;
    // The measured sheet, when it is itself in the library, is left out of its stock and
    // of the population: it would otherwise be evidence for itself.
    let own_identity = measured.identity.clone();
    let library = Library::open(path, OpenMode::Existing)?;
    let excluded = match own_identity {
        Some(own) if library.has_session(&own)? => Some(own),
        _ => None,
    };
    anyhow::ensure!(
        library.sheet_count()? > usize::from(excluded.is_some()),
        "{}: no sheets to search{}",
        path,
        if excluded.is_some() {
            " but the measured one"
        } else {
            ""
        }
    );
    let population = crate::cli::population::from_library(library, path, excluded.as_slice())?;
    let found = evidence::search(&measured.questioned(), &population.population);
    let stocks = found.ranking.len();
    // Only the stocks shown are described (their lay looked up): a library of 10⁴ stocks
    // is ranked whole, but shown by its top K.
    let ranking: Vec<Ranked> = found
        .ranking
        .into_iter()
        .take(args.top.unwrap_or(usize::MAX))
        .map(|r| Ranked {
            orientation: population.stock_lay(&r.stock).0,
            side: population.stock_lay(&r.stock).1,
            stock: r.stock,
            sheets: r.sheets,
            log10_lr: r.log10_lr,
            raw_log10_lr: r.raw_log10_lr,
            verbal: evidence::verbal(r.log10_lr),
        })
        .collect();
    let mut warnings = population.warnings(&found.warnings);
    // The sheet against every stock: measured as it was, otherwise, or not known.
    warnings.extend(
        population.lay_warnings(evidence::Side::A, host::output::comparison::lay(&measured)),
    );
    let bounds = population.population.validation.as_ref().map(|v| v.bounds);
    let code = if warnings.is_empty() {
        crate::cli::exit::OK
    } else {
        crate::cli::exit::FLAGGED
    };
    if args.json {
        println!(
            "{}",
            json!({
                "schema": host::schema::LIBRARY_SEARCH,
                "sheet": args.dir.display().to_string(),
                "sample": measured.sample,
                "library": path.to_string(),
                "stocks": stocks,
                "population": {"identity": population.population.identity(), "source": population.population.source, "bounds": bounds},
                "library_state": population.library_state,
                "caveat": evidence::SEARCH_CAVEAT,
                "warnings": warnings.iter().map(Warning::to_json).collect::<Vec<_>>(),
                "excluded_own_session": excluded,
                "ranking": ranking
            })
        );
        return Ok(code);
    }
    if let Some(sha) = &excluded {
        println!(
            "(the measured session {} is in the library: left out of its stock and the population)",
            short(sha)
        );
    }
    let lay = host::output::comparison::lay(&measured);
    println!(
        "{} (sample '{}', orientation {}, side {}) against {} stock{} of {}",
        args.dir.display(),
        host::text::shown(&measured.sample),
        host::analysis::specimen::orientation_text(lay.orientation),
        host::analysis::specimen::side_text(lay.side),
        stocks,
        if stocks == 1 { "" } else { "s" },
        path
    );
    println!("  ({})", evidence::SEARCH_CAVEAT);
    let names: Vec<String> = ranking.iter().map(|r| cell(&r.stock)).collect();
    let width = column_width(names.iter());
    println!(
        "  {:>4}  {:<width$}  {:>6}  {:>9}  {:<15}  verbal",
        "rank", "stock", "sheets", "log10 LR", "lay"
    );
    for (k, (r, name)) in ranking.iter().zip(&names).enumerate() {
        println!(
            "  {:>4}  {:<width$}  {:>6}  {:>+9.2}  {:<15}  {}",
            k + 1,
            name,
            r.sheets,
            r.log10_lr,
            format!("{} {}", r.orientation, r.side),
            r.verbal
        );
    }
    for w in &warnings {
        println!("  warning: {w}");
    }
    Ok(code)
}
