//! The person at the instrument: what they are asked to place on the sample port, and how
//! the session waits for them.
//!
//! A person takes seconds to minutes. The session must keep the instrument alive all that
//! time (heartbeats, and recovering the link if it breaks), so asking is split in two: the
//! session calls [`Operator::ask`] once, then polls [`Operator::answered`] between
//! heartbeats until the person is done. Nothing here blocks.
//!
//! While the person works, the arms are parked clear of the port and still, and the lamp
//! stays on (see `Session::ask_operator` for why).
use std::io::{BufRead, Write};
use std::sync::mpsc::{Receiver, TryRecvError, channel};
use std::time::{Duration, Instant};

/// What the operator is asked to put on the sample port.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Placement {
    /// The white reference tile.
    WhiteTile,
    /// The sample.
    Sample,
    /// The black glass gloss standard (`gonio characterize`).
    BlackGlass,
    /// The sheet moved so that another spot of it is under the beam (spot `spot` of `of`
    /// of a multi-spot session).
    NextSpot {
        /// The spot to come, from 1.
        spot: u16,
        /// The spots planned.
        of: u16,
    },
}

impl Placement {
    /// What the person is asked to do, in words.
    pub fn instruction(self) -> String {
        match self {
            Placement::WhiteTile => "Place the WHITE REFERENCE TILE on the sample port".to_string(),
            Placement::Sample => "Place the SAMPLE on the sample port".to_string(),
            Placement::BlackGlass => {
                "Place the BLACK GLASS gloss standard on the sample port, polished face to the arms"
                    .to_string()
            }
            // Spots a centimetre or more apart see different fibres and coating; a spot
            // measured twice would only repeat its own noise.
            Placement::NextSpot { spot, of } => format!(
                "MOVE THE SHEET so that a fresh area (at least 1 cm from the spots measured) lies on the sample port: spot {spot} of {of}"
            ),
        }
    }
}

/// The person at the instrument (a prompt), or a simulated one.
pub trait Operator {
    /// Ask for `placement` (print the prompt, start a timer); returns at once. `now` is
    /// the transport's clock (device time in process, wall time on a port).
    fn ask(&mut self, placement: Placement, now: Duration) -> std::io::Result<()>;
    /// Whether the placement asked for last is done. Called often (every 100 ms of the
    /// transport's clock) while the session keeps the instrument alive; must not block.
    /// An error (no one can answer any more) ends the session, readings kept.
    fn answered(&mut self, now: Duration) -> std::io::Result<bool>;
    /// The progress bar on the terminal, if any: a prompt is printed above it (with the
    /// bar suspended), so that no frozen copy of the bar is left in the scrollback.
    fn attach_progress(&mut self, bar: &indicatif::ProgressBar) {
        let _ = bar;
    }
}

/// No one to ask: the in-process simulator places the tile itself (when readings are
/// marked white), so every prompt is answered at once.
#[derive(Clone, Copy, Debug, Default)]
pub struct SimulatedOperator;

impl Operator for SimulatedOperator {
    fn ask(&mut self, _placement: Placement, _now: Duration) -> std::io::Result<()> {
        Ok(())
    }

    fn answered(&mut self, _now: Duration) -> std::io::Result<bool> {
        Ok(true)
    }
}

/// A simulated person who answers `delay` after being asked, on the transport's clock: in
/// process that is the simulator's virtual time, so a two-minute wait takes no wall time.
#[derive(Clone, Debug, Default)]
pub struct DelayedOperator {
    /// How long the person takes at every prompt.
    pub delay: Duration,
    asked_at: Option<Duration>,
    /// Every placement asked for, in order.
    pub asked: Vec<Placement>,
}

impl DelayedOperator {
    /// A person who takes `delay` at every prompt.
    pub fn answering_after(delay: Duration) -> DelayedOperator {
        DelayedOperator {
            delay,
            ..DelayedOperator::default()
        }
    }
}

impl Operator for DelayedOperator {
    fn ask(&mut self, placement: Placement, now: Duration) -> std::io::Result<()> {
        self.asked.push(placement);
        self.asked_at = Some(now);
        Ok(())
    }

    fn answered(&mut self, now: Duration) -> std::io::Result<bool> {
        Ok(self.asked_at.is_none_or(|at| now >= at + self.delay))
    }
}

/// A person who answers after a real delay (wall time), whatever the transport's clock:
/// for sessions on a pseudo-terminal, where the host's waits are real.
#[derive(Clone, Debug)]
pub struct WallClockOperator {
    /// How long the person takes at each prompt, in order; the last one repeats.
    pub delays: Vec<Duration>,
    asked_at: Option<Instant>,
    /// Every placement asked for, in order.
    pub asked: Vec<Placement>,
}

impl WallClockOperator {
    /// A person who takes `delays[k]` at the k-th prompt (the last delay for the rest).
    pub fn new(delays: Vec<Duration>) -> WallClockOperator {
        WallClockOperator {
            delays,
            asked_at: None,
            asked: Vec::new(),
        }
    }
}

impl Operator for WallClockOperator {
    fn ask(&mut self, placement: Placement, _now: Duration) -> std::io::Result<()> {
        self.asked.push(placement);
        self.asked_at = Some(Instant::now());
        Ok(())
    }

    fn answered(&mut self, _now: Duration) -> std::io::Result<bool> {
        let k = self
            .asked
            .len()
            .saturating_sub(1)
            .min(self.delays.len().saturating_sub(1));
        let delay = self.delays.get(k).copied().unwrap_or_default();
        Ok(self.asked_at.is_none_or(|at| at.elapsed() >= delay))
    }
}

/// Asks the person at the instrument on the terminal; Enter confirms. Standard input is
/// read on a thread of its own, so that the session goes on sending heartbeats meanwhile.
#[derive(Default)]
pub struct PromptOperator {
    lines: Option<Receiver<std::io::Result<Option<String>>>>,
    /// Where the answers come from (`None`: standard input).
    input: Option<Box<dyn BufRead + Send>>,
    /// The progress bar the prompt is printed above.
    bar: Option<indicatif::ProgressBar>,
}

impl PromptOperator {
    /// A prompt on standard error, answered on standard input.
    pub fn new() -> PromptOperator {
        PromptOperator::default()
    }

    /// A prompt on standard error, answered on `input` (for tests).
    pub fn answered_on(input: impl BufRead + Send + 'static) -> PromptOperator {
        PromptOperator {
            lines: None,
            input: Some(Box::new(input)),
            bar: None,
        }
    }

    /// The reader thread, started at the first prompt: it sends every line typed, then
    /// `None` at the end of input.
    fn lines(&mut self) -> &Receiver<std::io::Result<Option<String>>> {
        let input = self.input.take();
        self.lines.get_or_insert_with(|| {
            let (sender, receiver) = channel();
            std::thread::spawn(move || {
                let mut input: Box<dyn BufRead> = match input {
                    Some(input) => input,
                    None => Box::new(std::io::stdin().lock()),
                };
                loop {
                    let mut line = String::new();
                    let read = input.read_line(&mut line);
                    let end = !matches!(read, Ok(n) if n > 0);
                    let message = read.map(|n| (n > 0).then_some(line));
                    if sender.send(message).is_err() || end {
                        break;
                    }
                }
            });
            receiver
        })
    }
}

/// What the person is asked, as printed: the instruction and how to answer, each on a line
/// of its own (the bar, when there is one, is drawn again below it).
pub(crate) fn prompt_text(placement: Placement) -> String {
    format!(
        "\n{}.\n  The arms are parked clear of the port and the lamp stays on; take your time.\n  Press Enter when done (Ctrl-C stops the session; the readings are kept and `gonio measure --resume DIR` continues it).\n",
        placement.instruction()
    )
}

/// Ask the person at the instrument how the sheet lies on the port, one question a line
/// on `output`, answered on `input`: its orientation (md, cd) and side (felt, wire), each
/// only when `known` does not already say it (given on the command line). An empty
/// answer, "unknown" or the end of input leaves it unknown; anything else is asked again.
pub fn ask_lay(
    known: crate::analysis::specimen::SheetLay,
    input: &mut impl BufRead,
    output: &mut impl Write,
) -> std::io::Result<crate::analysis::specimen::SheetLay> {
    use crate::analysis::specimen::{Orientation, Side};
    fn ask<T>(
        question: &str,
        parse: impl Fn(&str) -> Option<T>,
        input: &mut impl BufRead,
        output: &mut impl Write,
    ) -> std::io::Result<Option<T>> {
        loop {
            write!(output, "{question} ")?;
            output.flush()?;
            let mut line = String::new();
            if input.read_line(&mut line)? == 0 {
                return Ok(None);
            }
            let answer = line.trim().to_lowercase();
            if answer.is_empty() || answer == "unknown" {
                return Ok(None);
            }
            match parse(&answer) {
                Some(v) => return Ok(Some(v)),
                None => writeln!(output, "  '{answer}' is not one of the answers.")?,
            }
        }
    }
    let orientation = match known.orientation {
        Some(o) => Some(o),
        None => ask(
            "The sheet's machine direction: in the plane of incidence (md) or across it (cd)? [md/cd, Enter: unknown]",
            |a| match a {
                "md" => Some(Orientation::Md),
                "cd" => Some(Orientation::Cd),
                _ => None,
            },
            input,
            output,
        )?,
    };
    let side = match known.side {
        Some(s) => Some(s),
        None => ask(
            "The side facing the instrument? [felt/wire, Enter: unknown]",
            |a| match a {
                "felt" => Some(Side::Felt),
                "wire" => Some(Side::Wire),
                _ => None,
            },
            input,
            output,
        )?,
    };
    Ok(crate::analysis::specimen::SheetLay { orientation, side })
}

/// Standard input ended: no one can answer.
fn no_one_answers() -> std::io::Error {
    std::io::Error::new(
        std::io::ErrorKind::UnexpectedEof,
        "no one can answer the prompt: standard input is closed (to run without a person, reuse a calibration with --calibration)",
    )
}

impl Operator for PromptOperator {
    fn ask(&mut self, placement: Placement, _now: Duration) -> std::io::Result<()> {
        let text = prompt_text(placement);
        match &self.bar {
            // Printed above the bar, which is drawn again below it: no frozen copy.
            Some(bar) if !bar.is_hidden() => bar.println(text.trim_end()),
            _ => {
                let mut stderr = std::io::stderr();
                write!(stderr, "{text}")?;
                stderr.flush()?;
            }
        }
        self.lines();
        Ok(())
    }

    fn attach_progress(&mut self, bar: &indicatif::ProgressBar) {
        self.bar = Some(bar.clone());
    }

    fn answered(&mut self, _now: Duration) -> std::io::Result<bool> {
        match self.lines().try_recv() {
            Ok(Ok(Some(_line))) => Ok(true),
            Ok(Ok(None)) | Err(TryRecvError::Disconnected) => Err(no_one_answers()),
            Ok(Err(error)) => Err(error),
            Err(TryRecvError::Empty) => Ok(false),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_person_states_orientation_and_side_or_leaves_them_unknown() {
        use crate::analysis::specimen::{Orientation, SheetLay, Side};
        let mut out = Vec::new();
        let lay = ask_lay(
            SheetLay::default(),
            &mut std::io::Cursor::new("sideways\nCD\nfelt\n"),
            &mut out,
        )
        .unwrap();
        assert_eq!(
            (lay.orientation, lay.side),
            (Some(Orientation::Cd), Some(Side::Felt))
        );
        assert!(
            String::from_utf8(out)
                .unwrap()
                .contains("'sideways' is not one of")
        );
        let lay = ask_lay(
            SheetLay::default(),
            &mut std::io::Cursor::new("\n"),
            &mut Vec::new(),
        )
        .unwrap();
        assert_eq!(
            lay,
            SheetLay::default(),
            "Enter, then the end of input: unknown"
        );
        let given = SheetLay {
            orientation: Some(Orientation::Md),
            side: None,
        };
        let lay = ask_lay(given, &mut std::io::Cursor::new("wire\n"), &mut Vec::new()).unwrap();
        assert_eq!(
            (lay.orientation, lay.side),
            (Some(Orientation::Md), Some(Side::Wire)),
            "what the command line gave is not asked"
        );
    }

    #[test]
    fn the_simulated_person_answers_after_the_delay_on_the_transports_clock() {
        let mut person = DelayedOperator::answering_after(Duration::from_secs(10));
        person
            .ask(Placement::WhiteTile, Duration::from_secs(5))
            .unwrap();
        assert!(!person.answered(Duration::from_secs(14)).unwrap());
        assert!(person.answered(Duration::from_secs(15)).unwrap());
        assert_eq!(person.asked, [Placement::WhiteTile]);
    }

    #[test]
    fn the_wall_clock_person_takes_each_delay_in_turn() {
        let mut person = WallClockOperator::new(vec![Duration::from_secs(3600), Duration::ZERO]);
        person.ask(Placement::WhiteTile, Duration::ZERO).unwrap();
        // Whatever the transport's clock says: an hour of device time is not a real hour.
        assert!(!person.answered(Duration::from_secs(7200)).unwrap());
        person.ask(Placement::Sample, Duration::ZERO).unwrap();
        assert!(person.answered(Duration::ZERO).unwrap());
        person.ask(Placement::WhiteTile, Duration::ZERO).unwrap();
        assert!(
            person.answered(Duration::ZERO).unwrap(),
            "the last delay repeats"
        );
    }

    /// Wait (on the reader thread) until `person` answers or fails.
    fn wait(person: &mut PromptOperator) -> std::io::Result<bool> {
        for _ in 0..10_000 {
            match person.answered(Duration::ZERO) {
                Ok(false) => std::thread::sleep(Duration::from_millis(1)),
                other => return other,
            }
        }
        Ok(false)
    }

    #[test]
    fn the_prompt_takes_a_line_per_placement_and_says_so_when_input_ends() {
        let mut person = PromptOperator::answered_on(std::io::Cursor::new(b"\n".to_vec()));
        person.ask(Placement::WhiteTile, Duration::ZERO).unwrap();
        assert!(wait(&mut person).unwrap());
        person.ask(Placement::Sample, Duration::ZERO).unwrap();
        let error = wait(&mut person).unwrap_err();
        assert_eq!(error.kind(), std::io::ErrorKind::UnexpectedEof);
        assert!(
            error.to_string().contains("standard input is closed")
                && error.to_string().contains("--calibration"),
            "{error}"
        );
    }
}
