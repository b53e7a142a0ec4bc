//! `gonio selftest`'s work: the device's self-test ([`protocol::Command::SelfTest`]) and a
//! dark reading per range, judged against limits held here (the firmware measures, the
//! host judges, so a limit can change without a firmware release).
//!
//! Every limit says where it comes from; the figures the reference hardware is expected
//! to give are in docs/HARDWARE.md's first-power-on checklist. A check the hardware cannot
//! make (the simulator has no interrupts to time and no stack to paint) is "not measured",
//! which is neither a pass nor a failure, and the report says so.

use crate::instrument::link::{Client, LinkError, Transport};
use protocol::{
    Command, DeviceInfo, PulseCheck, Reading, Reply, ResetCause, SelfTestReport, Status,
};
use serde::Serialize;

/// The crystal measured against HSI may be off by this much, percent: HSI is trimmed to
/// ±1 % at 25 °C and drifts to about ±3 % over the MCU's temperature range (RM0383,
/// datasheet 6.3.9); a crystal is good to 50 ppm, so anything past this is the wrong
/// crystal or a failing HSI. (The boot refuses past 10 %, `firmware::clock`.)
pub const HSE_LIMIT_PCT: f64 = 3.0;
/// The core clock measured against the crystal, percent: the boot's own tolerance
/// (`firmware::clock::SYSCLK_TOLERANCE_PERCENT`), far above the 1/16,000 of the capture.
pub const SYSCLK_LIMIT_PCT: f64 = firmware::clock::SYSCLK_TOLERANCE_PERCENT as f64;
/// A pulse check's duration against its profile's: the step timer and the device clock
/// are one crystal, so they agree to the poll's resolution; 0.5 % catches a wrong timer
/// prescaler or clock tree (a factor, never a fraction of a percent).
pub const PULSE_DURATION_LIMIT_PCT: f64 = 0.5;
/// The device loop polls every millisecond: a duration measured by it may be late by this
/// much beyond the percentage, µs.
pub const POLL_RESOLUTION_US: f64 = 2_000.0;
/// Detector blocks counted against the block period, percent, plus two blocks for the
/// window's ends: the ADC's trigger timer runs from the same crystal.
pub const BLOCK_COUNT_LIMIT_PCT: f64 = 0.5;
/// A step interrupt, or the longest interrupt-off section, may use this fraction of the
/// step deadline (a safety factor of 2: the estimate it replaces was 5 µs against 12 µs).
pub const DEADLINE_FRACTION: f64 = 0.5;
/// Stack high-water mark, fraction of the stack: beyond it a deeper path not exercised yet
/// (a fault handler, a long command) may overflow.
pub const STACK_LIMIT_FRACTION: f64 = 0.75;
/// Dark mean, fraction of full scale: INSTRUMENT.md's offset is about 0.3 %. Above 2 %
/// light reaches the detector or the amplifier's offset is wrong; below 0.02 % the offset
/// is gone and the ADC clips the noise at zero (a reading's mean is then biased).
pub const DARK_MEAN_LIMITS: (f64, f64) = (0.0002, 0.02);
/// Noise of a dark reading's mean, scaled to 100 ms, fraction of full scale: five times
/// INSTRUMENT.md's read noise (0.02 %).
pub const DARK_NOISE_LIMIT: f64 = 0.001;

/// What became of one check.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Verdict {
    /// Within its limit.
    Pass,
    /// Outside it.
    Fail,
    /// This hardware cannot measure it.
    NotMeasured,
}

/// One judged figure.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Check {
    /// What was checked (stable, for scripts).
    pub name: String,
    /// What was measured, in words with units.
    pub measured: String,
    /// The limit, in words with units.
    pub limit: String,
    /// Pass, fail or not measured.
    pub verdict: Verdict,
    /// On a failure: what to look at.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub advice: Option<String>,
}

impl Check {
    fn new(name: &str, measured: String, limit: String, pass: bool, advice: &str) -> Check {
        Check {
            name: name.to_string(),
            measured,
            limit,
            verdict: if pass { Verdict::Pass } else { Verdict::Fail },
            advice: (!pass).then(|| advice.to_string()),
        }
    }

    fn not_measured(name: &str, limit: String) -> Check {
        Check {
            name: name.to_string(),
            measured: "not measured (this hardware or firmware cannot)".into(),
            limit,
            verdict: Verdict::NotMeasured,
            advice: None,
        }
    }
}

/// The self-test's measurements and their verdicts.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SelfTest {
    /// The instrument's serial number.
    pub serial_number: String,
    /// Its firmware version.
    pub firmware_version: String,
    /// The checks, in the order of docs/HARDWARE.md's checklist.
    pub checks: Vec<Check>,
}

impl SelfTest {
    /// Whether no check failed (a check not measured is no failure).
    pub fn passed(&self) -> bool {
        self.checks.iter().all(|c| c.verdict != Verdict::Fail)
    }
}

/// Run the self-test on a greeted instrument, then a dark reading per range at the
/// default integration time, and judge both. The arms are not homed afterwards.
pub fn run<T: Transport>(client: &mut Client<T>, info: &DeviceInfo) -> Result<SelfTest, LinkError> {
    // Where the arms stood: a homed arm rests on its switch after a `Home`.
    let before = ask(client, Command::GetStatus, |reply| match reply {
        Reply::Status(status) => Some(*status),
        _ => None,
    })?;
    let report = ask(client, Command::SelfTest, |reply| match reply {
        Reply::SelfTest(report) => Some(*report),
        _ => None,
    })?;
    let integration_ms = info.default_integration_ms;
    let dark = ask(
        client,
        Command::TakeDark { integration_ms },
        |reply| match reply {
            Reply::Dark(readings) => Some(readings.to_vec()),
            _ => None,
        },
    )?;
    Ok(judge(info, Some(&before), &report, &dark))
}

/// `command`'s answer of the kind `pick` takes; any other is [`LinkError::UnexpectedReply`].
fn ask<T: Transport, R>(
    client: &mut Client<T>,
    command: Command,
    pick: impl FnOnce(&Reply) -> Option<R>,
) -> Result<R, LinkError> {
    let name = crate::instrument::link::command_name(&command);
    let reply = client.request(command)?;
    pick(&reply).ok_or_else(|| LinkError::UnexpectedReply {
        command: name,
        reply: Box::new(reply),
    })
}

fn pct_off(measured: f64, expected: f64) -> f64 {
    if expected == 0.0 {
        f64::INFINITY
    } else {
        100.0 * (measured - expected) / expected
    }
}

fn clock_check(
    name: &str,
    measured: Option<u32>,
    expected: u32,
    limit_pct: f64,
    advice: &str,
) -> Check {
    let limit = format!("{expected} Hz ± {limit_pct} %");
    match measured {
        None => Check::not_measured(name, limit),
        Some(hz) => {
            let off = pct_off(f64::from(hz), f64::from(expected));
            Check::new(
                name,
                format!("{hz} Hz ({off:+.2} %)"),
                limit,
                off.abs() <= limit_pct,
                advice,
            )
        }
    }
}

fn pulse_checks(arm: &str, pulses: &PulseCheck) -> [Check; 2] {
    let expected_us = f64::from(pulses.duration_expected_us);
    let allowed_us = expected_us * PULSE_DURATION_LIMIT_PCT / 100.0 + POLL_RESOLUTION_US;
    let off_us = f64::from(pulses.duration_measured_us) - expected_us;
    [
        Check::new(
            &format!("pulses-{arm}"),
            format!("{} steps counted", pulses.steps_counted),
            format!("{} steps, exactly", pulses.steps_expected),
            pulses.steps_counted == pulses.steps_expected,
            "the step generator lost or added steps: a late step interrupt halted it (see step-lateness) or the timer is misconfigured",
        ),
        Check::new(
            &format!("pulse-rate-{arm}"),
            format!(
                "{:.1} ms ({:+.2} %)",
                f64::from(pulses.duration_measured_us) / 1e3,
                pct_off(f64::from(pulses.duration_measured_us), expected_us)
            ),
            format!(
                "{:.1} ms ± {PULSE_DURATION_LIMIT_PCT} % + {:.0} ms",
                expected_us / 1e3,
                POLL_RESOLUTION_US / 1e3
            ),
            off_us.abs() <= allowed_us,
            "the step timer does not run at its nominal tick against the device clock: a wrong prescaler or timer clock",
        ),
    ]
}

/// Which arms stood at their switch before the self-test: homed and beyond the working
/// range, where a `Home` leaves them (the switches sit past `arm_max`).
fn at_switch(info: &DeviceInfo, before: Option<&Status>) -> [bool; 2] {
    before.map_or([false; 2], |s| {
        [
            s.homed_i && s.position.theta_i > info.arm_max,
            s.homed_r && s.position.theta_r > info.arm_max,
        ]
    })
}

/// Judge a self-test report and the dark readings (pure; the limits above). `before`: the
/// device's status before the self-test (where the arms stood), if read.
pub fn judge(
    info: &DeviceInfo,
    before: Option<&Status>,
    report: &SelfTestReport,
    dark: &[Reading],
) -> SelfTest {
    let mut checks = Vec::new();
    checks.push(Check::new(
        "reset-cause",
        info.reset_cause.to_string(),
        "power-on, reset pin or software reset".into(),
        !matches!(info.reset_cause, ResetCause::Watchdog | ResetCause::Fault(_)),
        "the last reset was the firmware's own: read the board's log (probe-rs attach) and report it",
    ));
    checks.push(match report.resets_since_power_on {
        None => Check::not_measured("resets", "no watchdog or fault reset since power-on".into()),
        Some(counts) => Check::new(
            "resets",
            format!(
                "since power-on: {} watchdog, {} fault, {} reset pin, {} software",
                counts.watchdog, counts.fault, counts.pin, counts.software
            ),
            "no watchdog or fault reset since power-on".into(),
            counts.watchdog == 0 && counts.fault == 0,
            "the firmware hung or faulted since the instrument was switched on, though it runs now: report it with the boot log",
        ),
    });
    checks.push(clock_check(
        "crystal",
        report.hse_measured_hz,
        report.hse_expected_hz,
        HSE_LIMIT_PCT,
        "the crystal is not the one this firmware was built for (a 25 MHz and an 8 MHz Black Pill need different builds), or HSI is failing",
    ));
    checks.push(clock_check(
        "sysclk",
        report.sysclk_measured_hz,
        report.sysclk_expected_hz,
        SYSCLK_LIMIT_PCT,
        "the core clock is not what the PLL settings give: a wrong build for this board",
    ));
    checks.extend(pulse_checks("source", &report.pulses_source));
    checks.extend(pulse_checks("detector", &report.pulses_detector));
    let expected = f64::from(report.blocks_expected);
    checks.push(Check::new(
        "adc-pace",
        format!("{} blocks", report.blocks_counted),
        format!("{} ± {BLOCK_COUNT_LIMIT_PCT} % + 2 blocks", report.blocks_expected),
        (f64::from(report.blocks_counted) - expected).abs()
            <= expected * BLOCK_COUNT_LIMIT_PCT / 100.0 + 2.0,
        "the detector's blocks do not come at their period: the ADC's trigger or clock divider is wrong, or its interrupt is starved",
    ));
    checks.push(Check::new(
        "sample-losses",
        report.sample_losses.to_string(),
        "0".into(),
        report.sample_losses == 0,
        "detector samples were lost (an ADC or DMA overrun): interrupts held off too long",
    ));
    checks.extend(timing_checks(report));
    checks.extend(line_checks(report, at_switch(info, before)));
    checks.extend(dark_checks(info, dark));
    // The ADC's reference (VREFINT against VDDA) is not read by this firmware: the ADC
    // converts the detector continuously for the blocks, and an injected conversion
    // would shift their timing. Listed, so that nobody takes its absence for a pass.
    checks.push(Check::not_measured(
        "vrefint",
        "1.18 – 1.24 V (DS10314 Table 74); measure the 3.3 V rail with a multimeter".into(),
    ));
    SelfTest {
        serial_number: info.serial_number.to_string(),
        firmware_version: info.firmware_version.to_string(),
        checks,
    }
}

/// The interrupts' timing and the stack, against the step deadline and the stack's size.
fn timing_checks(report: &SelfTestReport) -> Vec<Check> {
    let mut checks = Vec::new();
    let deadline = f64::from(report.step_deadline_us);
    let allowed = deadline * DEADLINE_FRACTION;
    checks.push(Check::new(
        "step-lateness",
        format!("{} µs", report.worst_step_late_us),
        format!("≤ {allowed:.0} µs (half the {deadline:.0} µs deadline)"),
        f64::from(report.worst_step_late_us) <= allowed,
        "a step interrupt came close to its deadline: something holds interrupts off; a stop may end in StepLate",
    ));
    let irq_limit = format!("≤ {allowed:.0} µs (half the step deadline)");
    checks.push(match report.longest_interrupts_off_us {
        None => Check::not_measured("interrupts-off", irq_limit),
        Some(us) => Check::new(
            "interrupts-off",
            format!("{us} µs"),
            irq_limit,
            f64::from(us) <= allowed,
            "a critical section is longer than the step interrupt can wait",
        ),
    });
    let stack_limit = format!("≤ {:.0} % of the stack", STACK_LIMIT_FRACTION * 100.0);
    checks.push(match report.stack_used_bytes {
        Some(used) if report.stack_size_bytes > 0 => Check::new(
            "stack",
            format!("{used} of {} bytes", report.stack_size_bytes),
            stack_limit,
            f64::from(used) <= f64::from(report.stack_size_bytes) * STACK_LIMIT_FRACTION,
            "the stack came close to its end: a deeper path may overflow it",
        ),
        _ => Check::not_measured("stack", stack_limit),
    });
    checks
}

/// What the pins read: switches, the drivers' fault lines, the range lines.
fn line_checks(report: &SelfTestReport, at_switch: [bool; 2]) -> Vec<Check> {
    let mut checks = Vec::new();
    for (arm, pressed, at_switch) in [
        ("source", report.switch_source, at_switch[0]),
        ("detector", report.switch_detector, at_switch[1]),
    ] {
        if at_switch {
            // Pressed is what it should read there, and released proves nothing either (the
            // arm, without torque, may have sprung off the trip point): not judged.
            checks.push(Check {
                measured: format!(
                    "{}, the arm homed at its switch: not judged (move it into the working range and run again)",
                    if pressed { "pressed" } else { "released" }
                ),
                ..Check::not_measured(
                    &format!("switch-{arm}"),
                    "released (arm off its switch)".into(),
                )
            });
            continue;
        }
        checks.push(Check::new(
            &format!("switch-{arm}"),
            if pressed { "pressed" } else { "released" }.into(),
            "released (arm off its switch)".into(),
            !pressed,
            "the home switch reads pressed: move the arm off it by hand (drivers are off) and run again; if it stays pressed, the switch or its wiring is at fault (a normally-closed contact wired where the firmware expects one that closes to GND when pressed)",
        ));
    }
    for (arm, fault) in [
        ("source", report.driver_fault_source),
        ("detector", report.driver_fault_detector),
    ] {
        checks.push(Check::new(
            &format!("driver-{arm}"),
            if fault { "fault" } else { "no fault" }.into(),
            "no fault with the driver disabled".into(),
            !fault,
            "the driver's fault line reads a fault with the driver disabled: a missing or dead module, DIAG wired wrong, or a driver whose fault output has the other polarity",
        ));
    }
    checks.push(match report.range_read_back {
        None => Check::not_measured("range-lines", format!("range {}", report.range_selected)),
        Some(read) => Check::new(
            "range-lines",
            if read == u8::MAX {
                "not one-hot".into()
            } else {
                format!("range {read}")
            },
            format!("range {}", report.range_selected),
            read == report.range_selected,
            "the amplifier's range lines do not read back what was selected: a short or an open line",
        ),
    });
    checks
}

/// The dark readings, one per range, against the detector's full scale.
fn dark_checks(info: &DeviceInfo, dark: &[Reading]) -> Vec<Check> {
    let mut checks = Vec::new();
    for (index, reading) in dark.iter().enumerate() {
        let full_scale = info
            .detector_ranges
            .get(index)
            .map_or(65_535.0, |r| f64::from(r.full_scale_counts));
        let mean = f64::from(reading.mean_counts) / full_scale;
        checks.push(Check::new(
            &format!("dark-mean-{index}"),
            format!("{:.3} % of full scale", 100.0 * mean),
            format!(
                "{:.2} – {:.1} % of full scale",
                100.0 * DARK_MEAN_LIMITS.0,
                100.0 * DARK_MEAN_LIMITS.1
            ),
            (DARK_MEAN_LIMITS.0..=DARK_MEAN_LIMITS.1).contains(&mean) && !reading.saturated,
            "light reaches the detector with the lamp off, or the amplifier's offset is wrong (none: the ADC clips its noise)",
        ));
        let samples = f64::from(reading.samples.max(1));
        let noise_100ms = f64::from(reading.std_counts) / samples.sqrt()
            * (f64::from(reading.integration_ms) / 100.0).sqrt()
            / full_scale;
        checks.push(Check::new(
            &format!("dark-noise-{index}"),
            format!("{:.4} % of full scale (mean, at 100 ms)", 100.0 * noise_100ms),
            format!("≤ {:.2} % of full scale", 100.0 * DARK_NOISE_LIMIT),
            noise_100ms <= DARK_NOISE_LIMIT,
            "the detector is noisier than it should be: grounding, the amplifier's supply, or light leaking in",
        ));
    }
    checks
}
