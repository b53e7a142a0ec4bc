//! The home switches, debounced: a state is taken only from
//! [`HOME_SWITCH_DEBOUNCE_SAMPLES`] consecutive equal samples of the switch, one per device
//! poll (1 kHz on the board and in the simulator).
//!
//! Why: a switch on a long wire beside the stepper cables picks up the drivers' chopping
//! (µs spikes), and a microswitch's contacts bounce for up to about a millisecond when
//! they close. Sampled raw at 1 kHz, one low sample was a trip: a homing reference taken
//! from noise, or, outside homing, a fail-safe stop for nothing. Three samples span 2 ms
//! between the first and the last: longer than a bounce, and a spike must repeat at three
//! polls in a row to count. What it costs: a press is acted on 2 ms late, so an arm stops
//! that much further on (3.2 steps in the homing's search at 20°/s, 0.3 steps in its slow
//! approach at 2°/s), but the step count where the press began is kept
//! ([`SwitchState::since_steps`]) and the homing takes its reference from it, so the
//! reference is as exact as with a raw sample.

/// Consecutive equal samples that make a switch state (see the module doc): at the 1 kHz
/// poll, 2 ms from the first to the last.
pub const HOME_SWITCH_DEBOUNCE_SAMPLES: u8 = 3;

/// A switch's debounced state.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SwitchState {
    /// Whether the switch is pressed.
    pub pressed: bool,
    /// The arm's step count at the first of the samples that made this state: where the
    /// press (or release) began.
    pub since_steps: i32,
}

/// One home switch's debouncer.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct HomeSwitch {
    /// The debounced state; `None` until the first one is made (after boot).
    state: Option<SwitchState>,
    /// Samples in a row that differ from `state`: the state they say, the step count at
    /// the first of them, how many.
    run: Option<(bool, i32, u8)>,
}

impl HomeSwitch {
    /// No sample taken yet.
    pub const fn new() -> HomeSwitch {
        HomeSwitch {
            state: None,
            run: None,
        }
    }

    /// The debounced state, if made yet.
    pub fn state(&self) -> Option<SwitchState> {
        self.state
    }

    /// Take one raw sample (`pressed`) with the arm's step count now. Returns the new state
    /// when this sample changed the debounced state from a known one (`Some(true)`: a
    /// press); `None` otherwise, and for the first state made after boot (an arm that
    /// stands on its switch at power-on was not pressed onto it).
    pub fn sample(&mut self, pressed: bool, steps: i32) -> Option<bool> {
        if self.state.map(|state| state.pressed) == Some(pressed) {
            // A glitch, if there was one, is over.
            self.run = None;
            return None;
        }
        let (since_steps, count) = match self.run {
            Some((run_pressed, since, count)) if run_pressed == pressed => {
                (since, count.saturating_add(1))
            }
            _ => (steps, 1),
        };
        if count < HOME_SWITCH_DEBOUNCE_SAMPLES {
            self.run = Some((pressed, since_steps, count));
            return None;
        }
        self.run = None;
        let known = self.state.is_some();
        self.state = Some(SwitchState {
            pressed,
            since_steps,
        });
        known.then_some(pressed)
    }
}
