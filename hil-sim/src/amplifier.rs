//! The detector's transimpedance amplifier in time: a first-order response with the range's
//! time constant τ, its output held to the ADC's full scale (the rail), and what a range
//! switch does to it.
//!
//! The firmware's configuration states the amplifier as an instrument assumption
//! ([`firmware::config::REFERENCE_RANGES`]): a feedback resistor switched a decade apart per
//! range across one compensation capacitor, so τ = R·C (470, 47 and 4.7 µs) and a settling
//! time after a switch. The simulator models exactly that, and nothing finer:
//!
//! - The output y follows the input x (the photocurrent times the range's gain, in ADC
//!   counts above dark) as dy/dt = (x − y)/τ. The input the simulator hands in is piecewise
//!   constant in time (the arm stands on a microstep between two step pulses), so each piece
//!   is solved exactly: y(t) = x + (y₀ − x)·e^(−t/τ), and its integral in closed form. At
//!   rest y reaches x exactly (the difference underflows) and the response changes nothing.
//! - The output cannot pass the rail (the ADC's full scale: the op-amp swings to the ADC's
//!   reference): it sits there while the input is beyond it, and leaves it with τ when the
//!   input falls. Every conversion of a block spent at the rail reads full scale.
//! - A range switch keeps the output where it is (the capacitor's voltage is the output's),
//!   so it relaxes from the old range's level to the new one's with the NEW range's τ; the
//!   analog switch injects a charge ([`SWITCH_KICK_FRACTION`] of full scale), and the op-amp
//!   recovers for [`SWITCH_RECOVERY_US`] before it follows again. The firmware's settling
//!   times are 9.2 τ + 100 µs rounded up: this model leaves less than 1e-4 of full scale of
//!   a full-scale step after them, and blocks inside them read visibly wrong.

/// Charge injected by the analog switch at a range switch, as a step of the output:
/// fraction of full scale (a few pC into 4.7 pF; positive: the switch's gate charge).
pub const SWITCH_KICK_FRACTION: f64 = 0.02;

/// After a range switch the op-amp recovers from the switch's glitch for this long, its
/// output held, before it follows the input again, µs (the 100 µs of the firmware's
/// settling times beyond 9.2 τ).
pub const SWITCH_RECOVERY_US: f64 = 100.0;

/// What the output does over one piece of constant input.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Response {
    /// The output at the piece's end, counts.
    pub end: f64,
    /// The output's integral over the piece, counts·µs.
    pub integral: f64,
    /// Time spent at the rail, µs.
    pub rail_us: f64,
}

/// The output over `duration_us` from `start` towards a constant input `input`, with time
/// constant `tau_us`, held at or below `rail` (`start` is at or below it).
pub fn respond(start: f64, input: f64, duration_us: f64, tau_us: f64, rail: f64) -> Response {
    if duration_us <= 0.0 {
        return Response {
            end: start,
            integral: 0.0,
            rail_us: 0.0,
        };
    }
    if start >= rail && input >= rail {
        return Response {
            end: rail,
            integral: rail * duration_us,
            rail_us: duration_us,
        };
    }
    if tau_us <= 0.0 {
        // An ideal amplifier: the output is the input (clipped).
        let end = input.min(rail);
        let rail_us = if input >= rail { duration_us } else { 0.0 };
        return Response {
            end,
            integral: end * duration_us,
            rail_us,
        };
    }
    // Below the rail the closed form; `free_us` is how long it stays below.
    let free_us = if input > rail {
        (tau_us * ((input - start) / (input - rail)).ln()).min(duration_us)
    } else {
        duration_us
    };
    let decay = (-free_us / tau_us).exp();
    let away = start - input;
    let free_end = input + away * decay;
    let free_integral = input * free_us + away * tau_us * (1.0 - decay);
    if free_us >= duration_us {
        Response {
            end: free_end,
            integral: free_integral,
            rail_us: 0.0,
        }
    } else {
        let rail_us = duration_us - free_us;
        Response {
            end: rail,
            integral: free_integral + rail * rail_us,
            rail_us,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The same piece by small explicit steps (the ODE integrated numerically, clipped).
    fn numeric(start: f64, input: f64, duration_us: f64, tau_us: f64, rail: f64) -> Response {
        let n = 200_000;
        let dt = duration_us / n as f64;
        let (mut y, mut integral, mut rail_us) = (start, 0.0, 0.0);
        for _ in 0..n {
            // Exact step for a constant input, clipped: the reference for the closed form.
            let next = (input + (y - input) * (-dt / tau_us).exp()).min(rail);
            integral += 0.5 * (y + next) * dt;
            if next >= rail && y >= rail {
                rail_us += dt;
            }
            y = next;
        }
        Response {
            end: y,
            integral,
            rail_us,
        }
    }

    #[test]
    fn the_closed_form_is_the_ode_below_and_at_the_rail() {
        for &(start, input, duration, tau) in &[
            (0.0, 1000.0, 1000.0, 470.0),
            (5000.0, 100.0, 300.0, 47.0),
            (100.0, 90_000.0, 1000.0, 470.0),
            (60_000.0, 90_000.0, 1000.0, 4.7),
            (65_000.0, 20.0, 800.0, 47.0),
        ] {
            let rail = 65_000.0;
            let exact = respond(start, input, duration, tau, rail);
            let reference = numeric(start, input, duration, tau, rail);
            assert!(
                (exact.end - reference.end).abs() < 1e-3 * rail.max(1.0) * 1e-3,
                "{start} → {input}: {exact:?} vs {reference:?}"
            );
            assert!(
                (exact.integral - reference.integral).abs() < 1e-5 * rail * duration,
                "{start} → {input}: {exact:?} vs {reference:?}"
            );
            assert!(
                (exact.rail_us - reference.rail_us).abs() < 0.01 * duration,
                "{start} → {input}: {exact:?} vs {reference:?}"
            );
        }
    }

    #[test]
    fn at_rest_the_output_is_the_input_exactly() {
        for input in [0.0, 1.0, 12_345.678_9, 64_000.5] {
            let r = respond(input, input, 1000.0, 470.0, 65_000.0);
            assert_eq!(r.end, input);
            assert_eq!(r.integral, input * 1000.0);
        }
        // And it gets there: the difference underflows against the input's own precision.
        let mut y = 0.0;
        for _ in 0..40 {
            y = respond(y, 26_000.25, 1000.0, 470.0, 65_000.0).end;
        }
        assert_eq!(y, 26_000.25);
    }

    #[test]
    fn a_settling_time_of_the_reference_leaves_less_than_1e4_of_a_full_scale_step() {
        for range in firmware::config::REFERENCE_RANGES {
            let rail = 65_000.0;
            // A full-scale step plus the switch's kick, held for the recovery, then relaxing.
            let start = rail;
            let left = respond(
                start,
                0.0,
                f64::from(range.settle_us) - SWITCH_RECOVERY_US,
                f64::from(range.time_constant_us),
                rail,
            )
            .end;
            assert!(
                left < 1e-4 * rail,
                "τ {} µs: {left} counts left after {} µs",
                range.time_constant_us,
                range.settle_us
            );
        }
    }
}
