//! The person at the instrument: what they are asked to place on the sample port, and how
//! the session waits for them.
use std::io::{BufRead, Write};

/// What the operator is asked to put on the sample port.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Placement {
    /// The white reference tile.
    WhiteTile,
    /// The sample.
    Sample,
}

/// The person at the instrument (a prompt), or nobody (the simulator's operator swaps by
/// itself when readings are marked white).
pub trait Operator {
    /// Ask for `placement` and wait until it is done.
    fn place(&mut self, placement: Placement) -> std::io::Result<()>;
}

/// No one to ask: the in-process simulator places the tile itself.
pub struct SimulatedOperator;

impl Operator for SimulatedOperator {
    fn place(&mut self, _placement: Placement) -> std::io::Result<()> {
        Ok(())
    }
}

/// Asks the person at the instrument, on the terminal.
pub struct PromptOperator;

impl Operator for PromptOperator {
    fn place(&mut self, placement: Placement) -> std::io::Result<()> {
        let what = match placement {
            Placement::WhiteTile => "Place the WHITE REFERENCE TILE on the sample port",
            Placement::Sample => "Place the SAMPLE on the sample port",
        };
        eprint!("{what}, then press Enter: ");
        std::io::stderr().flush()?;
        let mut line = String::new();
        if std::io::stdin().lock().read_line(&mut line)? == 0 {
            return Err(std::io::Error::new(std::io::ErrorKind::UnexpectedEof, "no one answered (standard input closed); use --calibration"));
        }
        Ok(())
    }
}

