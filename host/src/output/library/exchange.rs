//! The exchange file (`gonio library export` / `import`): JSON Lines, one
//! [`ExchangeRecord`] per spot, each line standing on its own; read whole and checked
//! before anything is imported.
use super::{LibraryError, Result, SheetRecord, StockInfo, check_spot, check_text, is_sha256_hex};
use crate::analysis::evidence::Spot;
use crate::analysis::specimen::{Orientation, SheetLay, Side};
use serde::{Deserialize, Serialize};
use std::io::BufRead;
use std::path::{Path, PathBuf};

/// One line of the exchange file: one spot, with every field of its sheet and stock so a
/// line stands on its own. Field order here is the order in the file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExchangeRecord {
    /// [`crate::schema::LIBRARY_RECORD`]. The older versions are imported too:
    /// [`crate::schema::LIBRARY_RECORD_V2`] (no `orientation`, `side`: both unknown) and
    /// [`crate::schema::LIBRARY_RECORD_V1`] (its key was `format`, otherwise as version 2).
    #[serde(alias = "format")]
    pub schema: String,
    /// Stock name.
    pub stock: String,
    /// Stock manufacturer.
    pub manufacturer: Option<String>,
    /// Stock notes.
    pub(crate) stock_notes: Option<String>,
    /// Session identity (SHA-256 of its `MANIFEST.sha256`, lowercase hex).
    pub session_sha256: String,
    /// Sample name.
    pub sample: String,
    /// Lot or ream.
    pub lot: Option<String>,
    /// When measured.
    pub measured_at: Option<String>,
    /// The sheet's orientation on the port (`md`, `cd`); null when unknown. Absent from
    /// records before `gonio-library/3` (read as unknown).
    #[serde(default)]
    pub orientation: Option<Orientation>,
    /// The side of the sheet facing the instrument (`felt`, `wire`); null when unknown.
    /// Absent before `gonio-library/3`.
    #[serde(default)]
    pub side: Option<Side>,
    /// Instrument serial number.
    pub instrument_serial: String,
    /// Session folder path as it was given to `add` (where the lab that measured keeps it).
    pub session_path: String,
    /// When added to the library it was exported from.
    pub(crate) added_at: String,
    /// Spot index in the sheet, from 0.
    pub spot: usize,
    /// Number of spots of the sheet (so an import can tell a sheet is whole).
    pub spots: usize,
    /// σ [deg], null when not determined.
    pub sigma_deg: Option<f64>,
    /// ρs, null when not determined.
    pub rho_s: Option<f64>,
    /// ρd, null when not determined.
    pub rho_d: Option<f64>,
    /// Covariance of (σ [deg], ρs, ρd), row by row.
    pub covariance: [[f64; 3]; 3],
}

/// An exchange file read whole and checked, ready for [`super::Library::import`]: reading
/// it first means a bad file is refused before any library is opened or created.
#[derive(Debug)]
pub struct ExchangeFile {
    pub(super) path: PathBuf,
    pub(super) sessions: Vec<ImportedSession>,
}

impl ExchangeFile {
    /// Read and check the whole exchange file from `input`; `path` names it in messages.
    pub fn read(input: &mut dyn BufRead, path: &Path) -> Result<ExchangeFile> {
        Ok(ExchangeFile {
            path: path.to_path_buf(),
            sessions: parse_exchange(input, path)?,
        })
    }

    /// The spot records it holds.
    pub fn records(&self) -> usize {
        self.sessions.iter().map(|s| s.sheet.spots.len()).sum()
    }
}

/// One session of an exchange file, its records gathered.
#[derive(Debug)]
pub(super) struct ImportedSession {
    pub(super) stock: StockInfo,
    pub(super) sheet: SheetRecord,
    pub(super) first_line: usize,
    /// The `spots` field of its records.
    declared_spots: usize,
}

/// What is wrong with a line of an exchange file, or with the session its records make.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// The line is not a record of this format.
    #[error("not an exchange record: {0}")]
    NotRecord(serde_json::Error),
    /// A record of a schema this gonio does not read.
    #[error(
        "schema '{0}', this gonio reads {newest}, {v2} and {v1}",
        newest = crate::schema::LIBRARY_RECORD,
        v2 = crate::schema::LIBRARY_RECORD_V2,
        v1 = crate::schema::LIBRARY_RECORD_V1
    )]
    Schema(String),
    /// A record of a version before the lay was recorded that states one.
    #[error(
        "a record of '{0}' with an orientation or side: those are recorded from {newest} on",
        newest = crate::schema::LIBRARY_RECORD
    )]
    LayBeforeItsVersion(String),
    /// A stock name that is not acceptable.
    #[error(transparent)]
    StockName(Box<LibraryError>),
    /// A session identity that is not a SHA-256.
    #[error("session_sha256 '{0}' is not 64 lowercase hex digits")]
    BadSessionSha256(String),
    /// A spot that is not a possible measurement (a number not finite, out of the fit's
    /// range, a covariance not positive definite or implausible for the instrument).
    #[error(transparent)]
    Spot(#[from] super::SpotError),
    /// A stock given differently than on earlier lines.
    #[error("stock '{0}' has a different manufacturer or notes than on earlier lines")]
    StockDiffers(String),
    /// A session whose first record is not spot 0.
    #[error("session {session} begins at spot {spot}, not 0")]
    BeginsAt {
        /// The session's SHA-256.
        session: String,
        /// The spot of its first record.
        spot: usize,
    },
    /// A session whose records are not together.
    #[error("session {0} appears again after other sessions: a session's records must be together")]
    SessionAgain(String),
    /// A record whose sheet or stock differs from its session's first.
    #[error("a record of session {0} whose sheet or stock fields differ from its first record's")]
    SheetDiffers(String),
    /// A spot out of order.
    #[error("spot {spot} of session {session} out of order (expected {expected})")]
    OutOfOrder {
        /// The session's SHA-256.
        session: String,
        /// The record's spot.
        spot: usize,
        /// The spot expected next.
        expected: usize,
    },
    /// A session with fewer or more records than its records declare.
    #[error("session {session} has {records} spot records, its records say {declared}")]
    NotWhole {
        /// The session's SHA-256.
        session: String,
        /// The records read.
        records: usize,
        /// The count they declare.
        declared: usize,
    },
}

/// What is wrong, and on which line (1-based).
type LineError = (usize, RecordError);

/// Read and check a whole exchange file: every line a record of this format
/// ([`checked_record`]), the records of one session together, agreeing on the sheet and
/// stock, with spots 0…n-1 in order ([`Sessions::add`]), and each session whole.
fn parse_exchange(input: &mut dyn BufRead, in_path: &Path) -> Result<Vec<ImportedSession>> {
    let fail = |(line, what): LineError| LibraryError::Import {
        path: in_path.to_path_buf(),
        line,
        what,
    };
    let mut sessions = Sessions::default();
    let mut line_no = 0;
    let mut line = String::new();
    loop {
        line.clear();
        let n = input
            .read_line(&mut line)
            .map_err(|source| LibraryError::Io {
                path: in_path.to_path_buf(),
                source,
            })?;
        if n == 0 {
            break;
        }
        line_no += 1;
        let text = line.strip_suffix('\n').unwrap_or(&line);
        if text.trim().is_empty() {
            continue;
        }
        let (record, spot) = checked_record(text).map_err(|what| fail((line_no, what)))?;
        sessions.add(record, spot, line_no).map_err(fail)?;
    }
    if let Some(last) = sessions.gathered.last() {
        check_whole(last).map_err(|what| fail((line_no, what)))?;
    }
    Ok(sessions.gathered)
}

/// One line as a record of this format, on its own: a schema this gonio reads, an
/// acceptable stock name, a session SHA-256, finite numbers; with its spot.
fn checked_record(text: &str) -> std::result::Result<(ExchangeRecord, Spot), RecordError> {
    let record: ExchangeRecord = serde_json::from_str(text).map_err(RecordError::NotRecord)?;
    if ![
        crate::schema::LIBRARY_RECORD,
        crate::schema::LIBRARY_RECORD_V2,
        crate::schema::LIBRARY_RECORD_V1,
    ]
    .contains(&record.schema.as_str())
    {
        return Err(RecordError::Schema(record.schema));
    }
    // An older record naming a lay was not written by a gonio of its version: refused
    // rather than read as a version it does not claim.
    if record.schema != crate::schema::LIBRARY_RECORD
        && (record.orientation.is_some() || record.side.is_some())
    {
        return Err(RecordError::LayBeforeItsVersion(record.schema));
    }
    check_text("stock name", &record.stock).map_err(|e| RecordError::StockName(Box::new(e)))?;
    if !is_sha256_hex(&record.session_sha256) {
        return Err(RecordError::BadSessionSha256(record.session_sha256));
    }
    let spot = Spot {
        values: [record.sigma_deg, record.rho_s, record.rho_d],
        covariance: record.covariance,
    };
    check_spot(&spot)?;
    Ok((record, spot))
}

/// The sessions gathered so far, and what the later lines must agree with.
#[derive(Default)]
struct Sessions {
    gathered: Vec<ImportedSession>,
    /// Every session begun (a session's records must be together).
    seen: std::collections::HashSet<String>,
    /// Every stock as first given.
    stocks: std::collections::HashMap<String, StockInfo>,
}

impl Sessions {
    /// Add the record of line `line`: to the session of the line before, or as a new one.
    fn add(
        &mut self,
        record: ExchangeRecord,
        spot: Spot,
        line: usize,
    ) -> std::result::Result<(), LineError> {
        let stock = StockInfo {
            name: record.stock.clone(),
            manufacturer: record.manufacturer.clone(),
            notes: record.stock_notes.clone(),
        };
        self.check_stock(&stock).map_err(|what| (line, what))?;
        let continues = self
            .gathered
            .last()
            .is_some_and(|s| s.sheet.session_sha256 == record.session_sha256);
        if continues {
            self.continue_session(record, stock, spot)
                .map_err(|what| (line, what))
        } else {
            self.begin_session(record, stock, spot, line)
        }
    }

    /// A stock is the same on every line that names it.
    fn check_stock(&mut self, stock: &StockInfo) -> std::result::Result<(), RecordError> {
        match self.stocks.get(&stock.name) {
            Some(known) if known != stock => Err(RecordError::StockDiffers(stock.name.clone())),
            Some(_) => Ok(()),
            None => {
                self.stocks.insert(stock.name.clone(), stock.clone());
                Ok(())
            }
        }
    }

    /// A new session: it begins at spot 0, was not seen before, and the one before it is
    /// whole (checked at the line before).
    fn begin_session(
        &mut self,
        record: ExchangeRecord,
        stock: StockInfo,
        spot: Spot,
        line: usize,
    ) -> std::result::Result<(), LineError> {
        if record.spot != 0 {
            return Err((
                line,
                RecordError::BeginsAt {
                    session: record.session_sha256,
                    spot: record.spot,
                },
            ));
        }
        if !self.seen.insert(record.session_sha256.clone()) {
            return Err((line, RecordError::SessionAgain(record.session_sha256)));
        }
        if let Some(last) = self.gathered.last() {
            check_whole(last).map_err(|what| (line - 1, what))?;
        }
        self.gathered.push(ImportedSession {
            stock,
            sheet: SheetRecord {
                lot: record.lot,
                measured_at: record.measured_at,
                instrument_serial: record.instrument_serial,
                session_path: record.session_path,
                session_sha256: record.session_sha256,
                sample: record.sample,
                lay: SheetLay {
                    orientation: record.orientation,
                    side: record.side,
                },
                added_at: record.added_at,
                spots: vec![spot],
            },
            first_line: line,
            declared_spots: record.spots,
        });
        Ok(())
    }

    /// The next spot of the last session: the same sheet and stock, in order.
    fn continue_session(
        &mut self,
        record: ExchangeRecord,
        stock: StockInfo,
        spot: Spot,
    ) -> std::result::Result<(), RecordError> {
        let Some(last) = self.gathered.last_mut() else {
            return Ok(());
        };
        let same_sheet = last.stock == stock
            && last.sheet.lot == record.lot
            && last.sheet.measured_at == record.measured_at
            && last.sheet.instrument_serial == record.instrument_serial
            && last.sheet.session_path == record.session_path
            && last.sheet.sample == record.sample
            && last.sheet.added_at == record.added_at
            && last.sheet.lay.orientation == record.orientation
            && last.sheet.lay.side == record.side
            && last.declared_spots == record.spots;
        if !same_sheet {
            return Err(RecordError::SheetDiffers(record.session_sha256));
        }
        if record.spot != last.sheet.spots.len() {
            return Err(RecordError::OutOfOrder {
                session: record.session_sha256,
                spot: record.spot,
                expected: last.sheet.spots.len(),
            });
        }
        last.sheet.spots.push(spot);
        Ok(())
    }
}

/// A session's records must be all of its spots: the count each record declares.
fn check_whole(session: &ImportedSession) -> std::result::Result<(), RecordError> {
    if session.sheet.spots.len() == session.declared_spots {
        Ok(())
    } else {
        Err(RecordError::NotWhole {
            session: session.sheet.session_sha256.clone(),
            records: session.sheet.spots.len(),
            declared: session.declared_spots,
        })
    }
}
