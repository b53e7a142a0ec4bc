//! `gonio selftest`: every limit fails when its figure is outside it (on a report made to
//! break it, and through the simulated instrument with the fault that breaks it), the
//! healthy simulated instrument passes whatever its noise seed, and the exit code says so.
use crate::cli_support::gonio;

use host::instrument::link::{Client, RetryPolicy};
use host::instrument::selftest::{self, Check, SelfTest, Verdict};
use host::instrument::sim::SimOptions;
use protocol::{Command, DeviceInfo, Reading, Reply, ResetCause, SelfTestReport};

/// The simulated instrument's self-test with these faults (`--faults`) and noise scale.
fn simulated(
    faults: &str,
    noise_scale: f64,
    seed: u64,
) -> (DeviceInfo, SelfTestReport, Vec<Reading>, SelfTest) {
    let options = SimOptions {
        faults: faults.to_string(),
        noise_scale,
        seed,
        ..SimOptions::default()
    };
    let mut client = Client::new(options.instrument("G").unwrap(), RetryPolicy::default());
    let info = client.hello().unwrap();
    let Reply::SelfTest(report) = client.request(Command::SelfTest).unwrap() else {
        panic!("no report");
    };
    let Reply::Dark(dark) = client
        .request(Command::TakeDark {
            integration_ms: info.default_integration_ms,
        })
        .unwrap()
    else {
        panic!("no dark");
    };
    let dark = dark.to_vec();
    let judged = selftest::judge(&info, None, &report, &dark);
    (info, report, dark, judged)
}

fn failed(result: &SelfTest) -> Vec<&str> {
    result
        .checks
        .iter()
        .filter(|c| c.verdict == Verdict::Fail)
        .map(|c| c.name.as_str())
        .collect()
}

fn check<'a>(result: &'a SelfTest, name: &str) -> &'a Check {
    result
        .checks
        .iter()
        .find(|c| c.name == name)
        .unwrap_or_else(|| panic!("no check {name}"))
}

#[test]
fn the_healthy_simulated_instrument_passes_for_every_seed() {
    for seed in 1..=12 {
        let (_, _, dark, result) = simulated("", 1.0, seed);
        assert!(result.passed(), "seed {seed}: {:?}", failed(&result));
        assert_eq!(dark.len(), 3);
        // What the simulator cannot measure is said, not passed.
        for name in ["interrupts-off", "stack", "vrefint"] {
            assert_eq!(check(&result, name).verdict, Verdict::NotMeasured);
        }
    }
}

/// Each limit, broken alone on a healthy report: exactly that check fails.
#[test]
fn every_limit_fails_alone_when_its_figure_is_outside_it() {
    let (info, report, dark, healthy) = simulated("", 1.0, 3);
    assert!(healthy.passed());
    type Break = Box<dyn Fn(&mut DeviceInfo, &mut SelfTestReport, &mut Vec<Reading>)>;
    let cases: Vec<(&[&str], Break)> = vec![
        (
            &["reset-cause"],
            Box::new(|i, _, _| i.reset_cause = ResetCause::Watchdog),
        ),
        (
            &["resets"],
            Box::new(|_, r, _| r.resets_since_power_on.as_mut().unwrap().watchdog = 1),
        ),
        (
            &["resets"],
            Box::new(|_, r, _| r.resets_since_power_on.as_mut().unwrap().fault = 2),
        ),
        (
            &["crystal"],
            Box::new(|_, r, _| r.hse_measured_hz = Some(25_800_000)),
        ),
        (
            &["sysclk"],
            Box::new(|_, r, _| r.sysclk_measured_hz = Some(97_000_000)),
        ),
        (
            &["pulses-source"],
            Box::new(|_, r, _| r.pulses_source.steps_counted -= 1),
        ),
        (
            &["pulses-detector"],
            Box::new(|_, r, _| r.pulses_detector.steps_counted += 1),
        ),
        (
            &["pulse-rate-source"],
            Box::new(|_, r, _| r.pulses_source.duration_measured_us += 10_000),
        ),
        (
            &["pulse-rate-detector"],
            Box::new(|_, r, _| r.pulses_detector.duration_measured_us -= 10_000),
        ),
        (&["adc-pace"], Box::new(|_, r, _| r.blocks_counted -= 10)),
        (&["sample-losses"], Box::new(|_, r, _| r.sample_losses = 1)),
        (
            &["step-lateness"],
            Box::new(|_, r, _| r.worst_step_late_us = 7),
        ),
        (
            &["interrupts-off"],
            Box::new(|_, r, _| r.longest_interrupts_off_us = Some(7)),
        ),
        (
            &["stack"],
            Box::new(|_, r, _| {
                r.stack_size_bytes = 1000;
                r.stack_used_bytes = Some(751);
            }),
        ),
        (
            &["switch-source"],
            Box::new(|_, r, _| r.switch_source = true),
        ),
        (
            &["switch-detector"],
            Box::new(|_, r, _| r.switch_detector = true),
        ),
        (
            &["driver-source"],
            Box::new(|_, r, _| r.driver_fault_source = true),
        ),
        (
            &["driver-detector"],
            Box::new(|_, r, _| r.driver_fault_detector = true),
        ),
        (
            &["range-lines"],
            Box::new(|_, r, _| r.range_read_back = Some(u8::MAX)),
        ),
        (
            &["dark-mean-1"],
            Box::new(|_, _, d| d[1].mean_counts = 0.021 * 65_535.0),
        ),
        (&["dark-mean-2"], Box::new(|_, _, d| d[2].mean_counts = 0.0)),
        (&["dark-mean-0"], Box::new(|_, _, d| d[0].saturated = true)),
        (
            &["dark-noise-0"],
            Box::new(|_, _, d| d[0].std_counts *= 6.0),
        ),
    ];
    for (names, break_it) in cases {
        let (mut info, mut report, mut dark) = (info.clone(), report, dark.clone());
        break_it(&mut info, &mut report, &mut dark);
        let result = selftest::judge(&info, None, &report, &dark);
        assert_eq!(failed(&result), names.to_vec());
        let check = check(&result, names[0]);
        assert!(check.advice.is_some(), "{check:?}");
    }
    // At the limits themselves: still a pass.
    let (mut edge, mut dark_edge) = (report, dark.clone());
    edge.worst_step_late_us = 6;
    edge.longest_interrupts_off_us = Some(6);
    edge.stack_size_bytes = 1000;
    edge.stack_used_bytes = Some(750);
    edge.hse_measured_hz = Some(25_750_000);
    // Resets by the pin and by a debugger are no failure.
    edge.resets_since_power_on = Some(protocol::ResetCounts {
        pin: 3,
        software: 1,
        ..protocol::ResetCounts::default()
    });
    dark_edge[0].mean_counts = 0.0199 * 65_535.0;
    assert!(selftest::judge(&info, None, &edge, &dark_edge).passed());
}

/// The faults a builder meets, injected into the simulated instrument: the firmware's
/// report carries them and the named check fails.
#[test]
fn the_simulated_instruments_faults_fail_their_checks() {
    let cases: [(&str, f64, &[&str]); 7] = [
        ("stuck-switch=source", 1.0, &["switch-source"]),
        ("stuck-switch=detector", 1.0, &["switch-detector"]),
        ("diag-stuck=detector", 1.0, &["driver-detector"]),
        ("crystal=8000000", 1.0, &["crystal"]),
        (
            "step-timer=2",
            1.0,
            &["pulse-rate-source", "pulse-rate-detector"],
        ),
        ("range-lines=1", 1.0, &["range-lines"]),
        ("", 10.0, &["dark-noise-0", "dark-noise-1", "dark-noise-2"]),
    ];
    for (faults, noise_scale, names) in cases {
        for seed in [1, 7] {
            let (.., result) = simulated(faults, noise_scale, seed);
            assert_eq!(failed(&result), names.to_vec(), "{faults} seed {seed}");
        }
    }
}

#[test]
fn the_exit_code_says_whether_it_passed() {
    let out = gonio(&["selftest", "--sim", "--json"]);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let doc: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(doc["serial_number"], "SIM-0001");
    assert!(doc["checks"].as_array().unwrap().len() >= 20);
    let out = gonio(&["selftest", "--sim", "--faults", "diag-stuck=source"]);
    assert_eq!(out.status.code(), Some(3));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("FAIL  driver-source"), "{text}");
    assert!(text.contains("FAILED: 1 failed"), "{text}");
    let out = gonio(&["selftest", "--sim", "--faults", "crystal=abc"]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("crystal"));
}

/// A lab runs the self-test before a case, often after a session whose last `Home` left the
/// arms on their switches: pressed there is not a fault, and not a pass either.
#[test]
fn arms_homed_at_their_switches_are_not_judged_by_their_switches() {
    let mut client = Client::new(
        SimOptions::default().instrument("G").unwrap(),
        RetryPolicy::default(),
    );
    let info = client.hello().unwrap();
    let Reply::Homed(_) = client.request(Command::Home).unwrap() else {
        panic!("not homed");
    };
    let result = selftest::run(&mut client, &info).unwrap();
    assert!(result.passed(), "{:?}", failed(&result));
    for name in ["switch-source", "switch-detector"] {
        let check = check(&result, name);
        assert_eq!(check.verdict, Verdict::NotMeasured, "{check:?}");
        assert!(check.measured.contains("homed at its switch"), "{check:?}");
    }
    // Not homed any more (the self-test's drivers were off), the same pressed switches
    // fail: nothing says the arms are at them.
    let result = selftest::run(&mut client, &info).unwrap();
    assert_eq!(failed(&result), ["switch-source", "switch-detector"]);
    // Homed again and moved into the working range, the switches are judged, and pass.
    let Reply::Homed(_) = client.request(Command::Home).unwrap() else {
        panic!("not homed");
    };
    let at = protocol::Geometry::from_deg(45.0, 45.0).unwrap();
    assert_eq!(client.request(Command::MoveTo(at)).unwrap(), Reply::Ack);
    let result = selftest::run(&mut client, &info).unwrap();
    assert!(result.passed(), "{:?}", failed(&result));
    for name in ["switch-source", "switch-detector"] {
        assert_eq!(check(&result, name).verdict, Verdict::Pass);
    }
}
