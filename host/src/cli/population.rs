//! The population a comparison or a search weighs against, always named on the command
//! line: a library of the lab's own stocks, or the demonstration population (never chosen
//! silently by a file's presence).
use host::analysis::evidence::{LibrarySheet, Population, population, validation};
use host::analysis::specimen::SheetLay;
use host::output::comparison::{LibraryState, PopulationInUse};
use host::output::library::{Library, Location, OpenMode};

/// Where the population comes from (one of the two is required).
#[derive(clap::Args, Clone, Debug)]
#[group(required = true, multiple = false)]
pub struct PopulationArgs {
    /// The stock library whose stocks make the population (validated on its own sheets): a
    /// file, or a PostgreSQL URL.
    #[arg(long, value_name = "FILE|URL", value_parser = crate::cli::library::location_arg())]
    pub library: Option<Location>,
    /// Weigh against the demonstration population (the eight reference papers with assumed
    /// variations): for demonstration, not evidence.
    #[arg(long)]
    pub demo_population: bool,
}

impl PopulationArgs {
    /// The population, with its sheets when it comes from a library (each with its
    /// session's SHA-256), leaving out the sheets whose SHA-256 is in `exclude`.
    pub fn load(&self, exclude: &[String]) -> anyhow::Result<PopulationInUse> {
        let Some(path) = &self.library else {
            return Ok(PopulationInUse {
                population: Population::demonstration(),
                name: "the demonstration population".to_string(),
                not_validated_because: None,
                stock_lays: None,
                library_state: None,
            });
        };
        from_library(Library::open(path, OpenMode::Existing)?, path, exclude)
    }
}

/// The population of the open library at `path`, leaving out the sheets whose SHA-256 is
/// in `exclude`: the one `gonio forensic --library` validated and recorded for these
/// contents, else the one cached for them, else made (and cached). The contents are read
/// as one state of the library, and that state (its last audit entry, its contents
/// identity) is named with the population.
pub fn from_library(
    mut library: Library,
    path: &Location,
    exclude: &[String],
) -> anyhow::Result<PopulationInUse> {
    let contents = library.contents()?;
    let mut by_stock: std::collections::BTreeMap<String, Vec<SheetLay>> = Default::default();
    let mut sheets: Vec<LibrarySheet> = Vec::new();
    for (sha, sheet, lay) in contents.sheets {
        if !exclude.contains(&sha) {
            by_stock.entry(sheet.stock.clone()).or_default().push(lay);
            sheets.push(sheet);
        }
    }
    let stock_lays = Some(by_stock.into_iter().collect());
    // The population `gonio forensic --library` validated and recorded for exactly these
    // contents is the reviewed evidence: used as recorded, not made again.
    let identity = population::contents_identity(&sheets);
    let library_state = Some(LibraryState {
        audit_entry: contents.last_entry,
        contents: identity.clone(),
        left_out_sessions: exclude.to_vec(),
    });
    let in_use = |population, not_validated_because| PopulationInUse {
        population,
        name: path.to_string(),
        not_validated_because,
        stock_lays: stock_lays.clone(),
        library_state: library_state.clone(),
    };
    let recorded = library
        .validation_record(&identity)?
        .and_then(|r| serde_json::from_value::<Population>(r["population"].clone()).ok())
        .filter(|p| p.validation.is_some());
    if let Some(population) = recorded {
        return Ok(in_use(population, None));
    }
    // The population made for these contents by an earlier search or comparison: the
    // same numbers, without the time (quadratic in the stocks) of making them again.
    let cached = library.cached_population(&identity)?.and_then(|c| {
        let population = serde_json::from_value::<Population>(c["population"].clone()).ok()?;
        let why = c["not_validated_because"].as_str()?.to_string();
        Some((population, why))
    });
    if let Some((population, why)) = cached {
        return Ok(in_use(population, Some(why)));
    }
    let (population, why) = validation::validate_or_explain(&sheets).map_err(|e| {
        anyhow::anyhow!(
            "{path}: the library cannot make a population: {e} (add sheets of more stocks, or weigh against --demo-population for a demonstration)"
        )
    })?;
    let why = why.map_or_else(
        || format!(
            "validated for this comparison only: the library's contents as they are now have not been validated and recorded by `gonio forensic --library {path}`"
        ),
        |e| e.to_string(),
    );
    // A library that cannot be written to (another's, read-only) is searched all the
    // same: the cache only saves time.
    let _ = library.cache_population(
        &identity,
        &serde_json::json!({"population": population, "not_validated_because": why}),
    );
    Ok(in_use(population, Some(why)))
}
