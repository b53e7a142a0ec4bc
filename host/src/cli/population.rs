//! The population a comparison or a search weighs against, always named on the command
//! line: a library of the lab's own stocks, or the demonstration population (never chosen
//! silently by a file's presence).
use host::analysis::evidence::{LibrarySheet, Population, population, validation};
use host::analysis::specimen::SheetLay;
use host::output::comparison::PopulationInUse;
use host::output::library::{Library, OpenMode};
use std::path::PathBuf;

/// Where the population comes from (one of the two is required).
#[derive(clap::Args, Clone, Debug)]
#[group(required = true, multiple = false)]
pub struct PopulationArgs {
    /// The stock library whose stocks make the population (validated on its own sheets).
    #[arg(long, value_name = "FILE")]
    pub library: Option<PathBuf>,
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
            });
        };
        from_library(Library::open(path, OpenMode::Existing)?, path, exclude)
    }
}

/// The population of the open library at `path`, leaving out the sheets whose SHA-256 is
/// in `exclude`: the one `gonio forensic --library` validated and recorded for these
/// contents, else the one cached for them, else made (and cached).
pub fn from_library(
    mut library: Library,
    path: &std::path::Path,
    exclude: &[String],
) -> anyhow::Result<PopulationInUse> {
    let sheets: Vec<LibrarySheet> = library
        .sheets()?
        .into_iter()
        .filter(|(sha, _)| !exclude.contains(sha))
        .map(|(_, sheet)| sheet)
        .collect();
    // The population `gonio forensic --library` validated and recorded for exactly these
    // contents is the reviewed evidence: used as recorded, not made again.
    let contents = population::contents_identity(&sheets);
    let stock_lays = Some(stock_lays(&library, exclude)?);
    let recorded = library
        .validation_record(&contents)?
        .and_then(|r| serde_json::from_value::<Population>(r["population"].clone()).ok())
        .filter(|p| p.validation.is_some());
    if let Some(population) = recorded {
        return Ok(PopulationInUse {
            population,
            name: path.display().to_string(),
            not_validated_because: None,
            stock_lays,
        });
    }
    // The population made for these contents by an earlier search or comparison: the
    // same numbers, without the time (quadratic in the stocks) of making them again.
    let cached = library.cached_population(&contents)?.and_then(|c| {
        let population = serde_json::from_value::<Population>(c["population"].clone()).ok()?;
        let why = c["not_validated_because"].as_str()?.to_string();
        Some((population, why))
    });
    if let Some((population, why)) = cached {
        return Ok(PopulationInUse {
            population,
            name: path.display().to_string(),
            not_validated_because: Some(why),
            stock_lays,
        });
    }
    let (population, why) = validation::validate_or_explain(&sheets).map_err(|e| {
            anyhow::anyhow!(
                "{}: the library cannot make a population: {e} (add sheets of more stocks, or weigh against --demo-population for a demonstration)",
                path.display()
            )
        })?;
    let why = Some(why.map_or_else(
            || format!(
                "validated for this comparison only: the library's contents as they are now have not been validated and recorded by `gonio forensic --library {}`",
                path.display()
            ),
            |e| e.to_string(),
        ));
    if let Some(why) = &why {
        // A library that cannot be written to (another's, read-only) is searched all
        // the same: the cache only saves time.
        let _ = library.cache_population(
            &contents,
            &serde_json::json!({"population": population, "not_validated_because": why}),
        );
    }
    Ok(PopulationInUse {
        population,
        name: path.display().to_string(),
        not_validated_because: why,
        stock_lays,
    })
}

/// How the sheets of each stock lay, by stock name, leaving out the sheets whose SHA-256
/// is in `exclude` (as the population leaves them out).
fn stock_lays(
    library: &Library,
    exclude: &[String],
) -> anyhow::Result<Vec<(String, Vec<SheetLay>)>> {
    let mut by_stock: std::collections::BTreeMap<String, Vec<SheetLay>> = Default::default();
    for (sha, stock, lay) in library.lays()? {
        if !exclude.contains(&sha) {
            by_stock.entry(stock).or_default().push(lay);
        }
    }
    Ok(by_stock.into_iter().collect())
}
