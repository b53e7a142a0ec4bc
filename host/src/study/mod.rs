//! Campaigns of whole simulated sessions.
pub mod accuracy;
pub mod forensic;
pub mod instruments;
pub mod interruptions;
pub mod library_concurrency;
pub mod library_scale;
pub mod library_validation;
pub mod pty;
pub mod reliability;
pub mod shapes;
pub mod trade;
pub mod trade_plot;

use crate::instrument::link::{Client, LinkError, RetryPolicy};
use crate::instrument::sim::{SimOptionError, SimOptions};
use crate::session::{
    DiscardRecorder, Outcome, Plan, Policy, Session, SessionError, SimulatedOperator,
};
use hil_sim::SimInstrument;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

/// A campaign's table as CSV through the csv crate, so a field's commas, quotes and line
/// breaks (a failure's message) are quoted by construction. `header` is the comma-separated
/// column names (plain words).
pub(crate) fn csv_table(header: &str, records: &[Vec<String>]) -> String {
    let mut csv = csv::Writer::from_writer(Vec::new());
    // Writing to memory fails only on a record of another length than the first, which
    // would be this file's bug: the debug assertion names it, a release build writes on.
    let header_record: Vec<&str> = header.split(',').collect();
    let _ = csv.write_record(&header_record);
    for record in records {
        debug_assert_eq!(record.len(), header_record.len(), "a CSV record's length");
        let _ = csv.write_record(record);
    }
    csv.into_inner()
        .map(|bytes| String::from_utf8_lossy(&bytes).into_owned())
        .unwrap_or_default()
}

/// `work` on every item on `threads` threads, the results in the items' order; `progress`
/// is called after each. Sessions of a campaign are independent and take from a few ms to
/// a second each, so the items are handed out one at a time.
pub fn parallel<I: Sync, O: Send>(
    items: &[I],
    threads: usize,
    progress: &(dyn Fn() + Sync),
    work: impl Fn(&I) -> O + Sync,
) -> Vec<O> {
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<Option<O>>> = Mutex::new((0..items.len()).map(|_| None).collect());
    std::thread::scope(|scope| {
        for _ in 0..threads.max(1) {
            scope.spawn(|| {
                loop {
                    let k = next.fetch_add(1, Ordering::Relaxed);
                    let Some(item) = items.get(k) else { break };
                    let out = work(item);
                    if let Ok(mut results) = results.lock() {
                        results[k] = Some(out);
                    }
                    progress();
                }
            });
        }
    });
    // A worker that panicked leaves its item's result out (and poisons nothing else).
    results
        .into_inner()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
        .into_iter()
        .flatten()
        .collect()
}

/// What a campaign's session is: the sample, the simulator, the policy, the integration
/// time (`None`: the instrument's default).
pub struct SimulatedRun<'a> {
    /// The sample on the port (a reference paper's name or `custom:…`).
    pub sample: &'a str,
    /// The simulated instrument and sheet.
    pub options: &'a SimOptions,
    /// The refinement policy.
    pub policy: Policy,
    /// Integration time per reading, ms.
    pub integration_ms: Option<u16>,
}

/// Why a campaign's simulated session or sheet could not be run. Its message is the whole
/// story: no `source`, so an error chain (`{:#}`) says it once.
#[derive(Debug, thiserror::Error)]
pub enum SimulationError {
    /// The simulator's options or the sample are not usable.
    #[error("{0}")]
    Simulator(SimOptionError),
    /// The simulated instrument did not answer the handshake.
    #[error("{0}")]
    Hello(LinkError),
    /// The session failed.
    #[error("{0}")]
    Session(SessionError),
}

impl From<SimOptionError> for SimulationError {
    fn from(error: SimOptionError) -> Self {
        SimulationError::Simulator(error)
    }
}

impl From<SessionError> for SimulationError {
    fn from(error: SessionError) -> Self {
        SimulationError::Session(error)
    }
}

/// The simulated instrument of `run`, greeted, and the plan `gonio measure` would make.
fn connect(
    run: &SimulatedRun<'_>,
) -> Result<(Client<SimInstrument>, protocol::DeviceInfo, Plan), SimulationError> {
    let instrument = run.options.instrument(run.sample)?;
    let mut client = Client::new(instrument, RetryPolicy::default());
    let info = client.hello().map_err(SimulationError::Hello)?;
    let plan = Plan {
        sample: run.sample.to_string(),
        integration_ms: run.integration_ms.unwrap_or(info.default_integration_ms),
        policy: run.policy.clone(),
        acceptance_deg: f64::from(info.acceptance_deg),
        white_check: false,
        white_drift_limit: 0.005,
    };
    Ok((client, info, plan))
}

/// One whole session as `gonio measure --sim` runs it, in process, with an operator who
/// answers at once and nothing recorded; `configure` states what the operator would (the
/// tile, the arm zero). Returns the outcome and what the instrument truly was.
pub fn simulated_session(
    run: &SimulatedRun<'_>,
    configure: impl for<'s> FnOnce(Session<'s, SimInstrument>) -> Session<'s, SimInstrument>,
) -> Result<(Outcome, hil_sim::Truth), SimulationError> {
    let (mut client, info, plan) = connect(run)?;
    let (mut recorder, mut operator) = (DiscardRecorder, SimulatedOperator);
    let outcome = configure(Session::new(
        &mut client,
        info,
        plan,
        &mut recorder,
        &mut operator,
    ))
    .run()?;
    Ok((outcome, client.transport().truth().clone()))
}

/// One sheet measured at `spots` spots as `gonio measure --sim --spots N` measures it (one
/// connection, the first spot's calibration for all, a flagged spot replaced), with an
/// operator who answers at once and nothing recorded; `configure` states what the operator
/// would, for every spot's session (the tile). Returns every spot's outcome, the sheet's
/// result and the spots' results.
pub fn simulated_sheet(
    run: &SimulatedRun<'_>,
    spots: u16,
    configure: impl for<'s> Fn(Session<'s, SimInstrument>) -> Session<'s, SimInstrument>,
) -> Result<
    (
        Vec<Outcome>,
        crate::analysis::spots::SheetSummary,
        Vec<crate::analysis::spots::SpotResult>,
    ),
    SimulationError,
> {
    let (mut client, info, plan) = connect(run)?;
    let mut outcomes: Vec<Outcome> = Vec::new();
    let measure_spot = |number: u16,
                        of: u16|
     -> Result<
        crate::analysis::spots::SpotResult,
        crate::session::SessionError,
    > {
        let (mut recorder, mut operator) = (DiscardRecorder, SimulatedOperator);
        let mut session = configure(
            Session::new(
                &mut client,
                info.clone(),
                plan.clone(),
                &mut recorder,
                &mut operator,
            )
            .at_spot(number, of),
        );
        if let Some(first) = outcomes.first() {
            session = session.with_calibration(first.calibration.clone());
        }
        let outcome = session.run()?;
        let result = crate::analysis::spots::SpotResult {
            number,
            flags: outcome.flags.clone(),
            spot: crate::analysis::evidence::Spot::of_fit(&outcome.report.fit),
            shape_widening: crate::analysis::evidence::ShapeWidening::of_fit(&outcome.report.fit),
            class: outcome
                .report
                .classification
                .class
                .map(|c| c.name().to_string()),
        };
        outcomes.push(outcome);
        Ok(result)
    };
    let (results, summary) = crate::session::multi_spot::measure_sheet(
        crate::session::multi_spot::SheetPlan::new(spots),
        Vec::new(),
        measure_spot,
        |_| {},
    )?;
    Ok((outcomes, summary, results))
}

#[cfg(test)]
mod tests {
    /// A failure's message with a comma, quotes and a line break stays one field.
    #[test]
    fn a_campaign_csv_field_is_quoted_by_construction() {
        let message = "cannot read \"x,y\"\nline 2";
        let text = super::csv_table(
            "index,failure,class",
            &[vec!["7".into(), message.into(), "G".into()]],
        );
        let mut reader = csv::Reader::from_reader(text.as_bytes());
        let headers = reader.headers().expect("a header").clone();
        assert_eq!(
            headers.iter().collect::<Vec<_>>(),
            ["index", "failure", "class"]
        );
        let records: Vec<csv::StringRecord> =
            reader.records().map(|r| r.expect("a record")).collect();
        assert_eq!(records.len(), 1);
        assert_eq!(&records[0][1], message);
        assert_eq!(&records[0][2], "G");
    }
}
