//! The whole-device scenarios of `firmware::scenarios` (the ones the on-target tests run
//! under QEMU), here on the host.

#[test]
fn every_scenario_passes_on_the_host() {
    let mut failures = Vec::new();
    for scenario in firmware::scenarios::SCENARIOS {
        match (scenario.run)() {
            Ok(digest) => println!("scenario {} ok digest {digest:08x}", scenario.name),
            Err(failure) => failures.push(format!(
                "{}: {} (scenarios.rs:{})",
                scenario.name, failure.what, failure.line
            )),
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn the_scenarios_see_what_they_check() {
    // A scenario's checks can fail: the device's answers differ when the hardware does.
    use firmware::hardware::ResetCause;
    use protocol::{DeviceError, ErrorCode, Geometry};
    let expected = DeviceError::with_detail(ErrorCode::Panic, 1);
    let wrong = firmware::scenarios::report_after_reset(
        Geometry::from_whole_deg(30, 30),
        ResetCause::PowerOn,
        expected,
    );
    assert!(wrong.is_err(), "a power-on reported as a panic");
    let right = firmware::scenarios::report_after_reset(
        Geometry::from_whole_deg(30, 30),
        ResetCause::Fault(expected),
        expected,
    );
    assert!(right.is_ok(), "{right:?}");
}
