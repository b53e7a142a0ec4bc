//! The simulated instrument's promises (hil-sim issue), through the host's link client:
//! repeatability by seed, readings that match the scene within the noise, and every
//! injected fault producing what the firmware promises.

use hil_sim::{SimConfig, SimInstrument};
use host::analysis::model;
use host::instrument::link::{Client, LinkError, RetryPolicy};
use host::instrument::sim::{SimOptions, sample_params};
use protocol::*;
use std::time::Duration;

fn options(seed: u64, faults: &str) -> SimOptions {
    SimOptions {
        seed,
        acceptance: 1.0,
        faults: faults.to_owned(),
        ..SimOptions::default()
    }
}

fn connect(instrument: SimInstrument) -> (Client<SimInstrument>, DeviceInfo) {
    let mut client = Client::new(instrument, RetryPolicy::default());
    let info = client.hello().expect("handshake");
    (client, info)
}

fn homed(sample: &str, opts: &SimOptions) -> (Client<SimInstrument>, DeviceInfo) {
    let (mut client, info) = connect(opts.instrument(sample).unwrap());
    assert!(matches!(client.request(Command::Home), Ok(Reply::Homed(_))));
    ack(&mut client, Command::SetLamp { on: true });
    (client, info)
}

/// Ask for something that is answered with a plain acknowledgement.
fn ack(client: &mut Client<SimInstrument>, command: Command) {
    let what = format!("{command:?}");
    match client.request(command) {
        Ok(Reply::Ack) => {}
        other => panic!("{what}: {other:?}"),
    }
}

/// Run a schedule and collect its stream.
fn run(client: &mut Client<SimInstrument>, run: RunSchedule) -> (Vec<StreamReading>, ScheduleDone) {
    assert!(matches!(
        client.request(Command::RunSchedule(run)),
        Ok(Reply::ScheduleStarted { .. })
    ));
    let mut readings = Vec::new();
    loop {
        match client
            .next_unsolicited(Duration::from_secs(10))
            .expect("link")
        {
            Some(DeviceMessage::Reading(r)) => readings.push(r),
            Some(DeviceMessage::ScheduleDone(done)) => return (readings, done),
            other => panic!("unexpected {other:?}"),
        }
    }
}

fn strategy1(client: &mut Client<SimInstrument>) -> (Vec<StreamReading>, ScheduleDone) {
    let spec = RunSchedule {
        schedule_id: 1,
        source: ScheduleSource::Strategy1,
        integration_ms: 100,
        target: Target::Sample,
    };
    run(client, spec)
}

/// Standard deviation of a reading's mean, from the reading itself.
fn sigma_of_mean(r: &Reading) -> f64 {
    f64::from(r.std_counts) / f64::from(r.samples).sqrt()
}

#[test]
fn same_seed_repeats_exactly_and_another_seed_differs_by_the_noise() {
    let (mut a, _) = homed("G", &options(5, ""));
    let (mut b, _) = homed("G", &options(5, ""));
    let (mut c, _) = homed("G", &options(6, ""));
    let (ra, da) = strategy1(&mut a);
    let (rb, db) = strategy1(&mut b);
    let (rc, _) = strategy1(&mut c);
    assert_eq!(ra.len(), 12);
    let bytes = |rs: &[StreamReading]| {
        rs.iter()
            .map(|r| postcard::to_allocvec(r).unwrap())
            .collect::<Vec<_>>()
    };
    assert_eq!(bytes(&ra), bytes(&rb), "same seed, different readings");
    assert_eq!(da, db);
    // Another seed: every reading differs, by what the readings' own spread says.
    let z: Vec<f64> = ra
        .iter()
        .zip(&rc)
        .filter(|(x, y)| x.reading.range == y.reading.range)
        .map(|(x, y)| {
            let sigma =
                (sigma_of_mean(&x.reading).powi(2) + sigma_of_mean(&y.reading).powi(2)).sqrt();
            (f64::from(x.reading.mean_counts) - f64::from(y.reading.mean_counts)) / sigma
        })
        .collect();
    assert!(z.len() >= 10);
    assert!(z.iter().all(|z| *z != 0.0));
    let rms = (z.iter().map(|z| z * z).sum::<f64>() / z.len() as f64).sqrt();
    assert!(
        (0.4..2.0).contains(&rms),
        "differences of {rms} σ in rms: not the stated noise"
    );
}

/// Mean and standard error of the radiance factor from `n` readings of the sample
/// against `n` of the white tile, at one geometry, dark-corrected per range.
fn measured_radiance_factor(
    client: &mut Client<SimInstrument>,
    info: &DeviceInfo,
    g: Geometry,
    n: usize,
) -> (f64, f64) {
    let Ok(Reply::Dark(dark)) = client.request(Command::TakeDark {
        integration_ms: 100,
    }) else {
        panic!("dark")
    };
    ack(client, Command::SetLamp { on: true });
    ack(client, Command::MoveTo(g));
    let mut per_gain = |target| -> Vec<f64> {
        (0..n)
            .map(|_| {
                let Ok(Reply::Reading(r)) = client.request(Command::TakeReading {
                    integration_ms: 100,
                    target,
                    range: None,
                }) else {
                    panic!("reading")
                };
                assert!(!r.saturated);
                let range = usize::from(r.range);
                (f64::from(r.mean_counts) - f64::from(dark[range].mean_counts))
                    / f64::from(info.detector_ranges[range].relative_gain)
            })
            .collect()
    };
    let white = per_gain(Target::WhiteReference);
    let sample = per_gain(Target::Sample);
    let white_mean = white.iter().sum::<f64>() / n as f64;
    let values: Vec<f64> = sample
        .iter()
        .map(|s| s / white_mean * hil_sim::scene::WHITE_TILE_RADIANCE_FACTOR)
        .collect();
    let mean = values.iter().sum::<f64>() / n as f64;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    let white_var = white.iter().map(|w| (w - white_mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    // Standard error: the sample's scatter and the white mean's.
    let se =
        (var / n as f64 + mean * mean * white_var / (n as f64 * white_mean * white_mean)).sqrt();
    (mean, se)
}

#[test]
fn white_tile_and_every_paper_read_their_radiance_factor_within_the_noise() {
    // A geometry on the diffuse part and one on the specular peak.
    let geometries = [
        Geometry::from_whole_deg(45, 0),
        Geometry::from_whole_deg(45, 45),
    ];
    for sample in [
        "G",
        "SG",
        "PPC",
        "MC",
        "J1",
        "J2",
        "J3",
        "J4",
        "custom:5,1,0.99,1.5",
    ] {
        let (mut client, info) = homed(sample, &options(11, ""));
        let params = sample_params(sample).unwrap();
        for g in geometries {
            let (theta_i, theta_r) = (g.theta_i.deg(), g.theta_r.deg());
            // What the detector sees: the scene through its 1° acceptance.
            let expected = (0..1000)
                .map(|k| {
                    model::radiance_factor(
                        &params,
                        theta_i,
                        theta_r - 0.5 + (k as f64 + 0.5) / 1000.0,
                    )
                })
                .sum::<f64>()
                / 1000.0;
            let (mean, se) = measured_radiance_factor(&mut client, &info, g, 20);
            let z = (mean - expected) / se;
            assert!(
                z.abs() < 4.5,
                "{sample} at {g}: measured {mean:.5} ± {se:.5}, scene {expected:.5} ({z:.1} σ)"
            );
            // And the noise is the instrument's, not zero and not gross.
            assert!(
                se / expected > 1e-5 && se / expected < 1e-2,
                "{sample} at {g}: relative standard error {}",
                se / expected
            );
        }
    }
}

#[test]
fn lost_steps_show_up_as_the_step_error_of_the_next_homing() {
    let (mut client, _) = homed("PPC", &options(1, "lose-steps=detector:37"));
    ack(
        &mut client,
        Command::MoveTo(Geometry::from_whole_deg(40, 50)),
    );
    let Ok(Reply::Homed(report)) = client.request(Command::Home) else {
        panic!("re-home")
    };
    assert_eq!(
        report,
        HomeReport {
            step_error_i: Some(0),
            step_error_r: Some(-37)
        }
    );
}

#[test]
fn a_switch_that_never_triggers_fails_homing_with_its_arm() {
    let (mut client, _) = connect(options(1, "no-switch=source").instrument("MC").unwrap());
    match client.request(Command::Home) {
        Err(LinkError::Device { error, .. }) => assert_eq!(
            error,
            DeviceError::with_detail(ErrorCode::HomeSwitchNotFound, 0)
        ),
        other => panic!("expected a homing failure, got {other:?}"),
    }
    assert!(
        matches!(client.request(Command::MoveTo(Geometry::from_whole_deg(30, 30))), Err(LinkError::Device { error, .. }) if error.code == ErrorCode::NotHomed)
    );
}

#[test]
fn the_link_recovers_from_corruption_and_loss_without_a_panic() {
    let (mut client, _) = homed("J2", &options(3, "corrupt=0.003,drop=0.03"));
    for _ in 0..200 {
        assert!(matches!(
            client.request(Command::GetStatus),
            Ok(Reply::Status(_))
        ));
    }
    let (readings, done) = strategy1(&mut client);
    // Streamed readings can be lost on such a link (the session re-measures them); what
    // arrives is intact and in order.
    assert!(done.error.is_none() && done.readings == 12);
    assert!(readings.windows(2).all(|w| w[0].index < w[1].index));
    let stats = client.stats();
    assert!(stats.retries > 0 && stats.bad_frames > 0, "{stats:?}");
}

#[test]
fn a_pulled_cable_stops_the_arms_and_lamp_and_a_new_session_must_say_hello() {
    let mut config = SimConfig {
        seed: 2,
        ..SimConfig::default()
    };
    config.faults.unplugs = vec![hil_sim::Unplug::new(20.0, 5.0)];
    let params = sample_params("SG").unwrap();
    let port = hil_sim::scene::SamplePort::new(std::sync::Arc::new(move |i: f64, r: f64| {
        model::radiance_factor(&params, i, r)
    }));
    let (mut client, _) = connect(SimInstrument::new(port, config));
    assert!(matches!(client.request(Command::Home), Ok(Reply::Homed(_))));
    ack(&mut client, Command::SetLamp { on: true });
    // Keep going until the cable comes out.
    let error = loop {
        match client.request(Command::GetStatus) {
            Ok(_) => client.transport_mut().advance_ms(100),
            Err(error) => break error,
        }
    };
    assert!(
        matches!(&error, LinkError::Io(e) if e.kind() == std::io::ErrorKind::NotConnected),
        "{error}"
    );
    let sim = client.transport_mut();
    assert!(sim.is_unplugged());
    // The host is gone: after the heartbeat timeout the lamp goes off and the arms stop.
    sim.advance_ms(2_100);
    assert!(!sim.hardware().mechanics().lamp_on());
    sim.advance_ms(3_000);
    assert!(!sim.is_unplugged());
    // Plugged back: the device wants a new handshake, then tells why it stopped.
    assert!(
        matches!(client.request(Command::GetStatus), Err(LinkError::Device { error, .. }) if error.code == ErrorCode::VersionMismatch)
    );
    client.hello().expect("handshake after replug");
    let Ok(Reply::Status(status)) = client.request(Command::GetStatus) else {
        panic!("status")
    };
    assert_eq!(status.fault, Some(ErrorCode::HeartbeatLost));
    // The arms stood still when the stop came: they keep their homing (firmware device.rs).
    assert!(!status.lamp_on && status.homed_i && status.homed_r);
    assert_eq!(status.state, protocol::DeviceState::Idle);
}

#[test]
fn strategy1_takes_the_device_time_of_the_instrument() {
    let (mut client, _) = homed("G", &options(9, ""));
    let wall = std::time::Instant::now();
    let (readings, done) = strategy1(&mut client);
    eprintln!(
        "Strategy 1 on the simulator: {:.2} device s in {:.3} wall s",
        done.device_us as f64 * 1e-6,
        wall.elapsed().as_secs_f64()
    );
    assert_eq!(readings.len(), 12);
    // the reference instrument: on the order of 10 s (moves, settling, 100 ms integrations, re-takes).
    assert!(
        (5e6..20e6).contains(&(done.device_us as f64)),
        "{} µs",
        done.device_us
    );
    // Every reading carries the geometry reached, which is the schedule's.
    let mut reached: Vec<Geometry> = readings.iter().map(|r| r.geometry).collect();
    reached.sort();
    assert_eq!(
        reached,
        protocol::schedules::strategy1(12).unwrap().to_vec()
    );
    // The paper's refinement: Strategy 2 at δ = 1°, uploaded in chunks, in the given order.
    let refinement = protocol::schedules::strategy2(1).unwrap();
    let total = refinement.len() as u16;
    for (k, chunk) in refinement.chunks(SCHEDULE_CHUNK_LEN).enumerate() {
        let offset = (k * SCHEDULE_CHUNK_LEN) as u16;
        let upload = ScheduleChunk {
            schedule_id: 2,
            total_len: total,
            offset,
            geometries: heapless::Vec::from_slice(chunk).unwrap(),
        };
        assert!(matches!(
            client.request(Command::UploadSchedule(upload)),
            Ok(Reply::ScheduleLoaded { .. })
        ));
    }
    let spec = RunSchedule {
        schedule_id: 2,
        source: ScheduleSource::Uploaded,
        integration_ms: 100,
        target: Target::Sample,
    };
    let (refined, refined_done) = run(&mut client, spec);
    assert_eq!(
        refined.iter().map(|r| r.geometry).collect::<Vec<_>>(),
        refinement.to_vec()
    );
    eprintln!(
        "plus Strategy 2 at δ = 1° ({} geometries): {:.2} device s; both in {:.3} wall s",
        refined.len(),
        refined_done.device_us as f64 * 1e-6,
        wall.elapsed().as_secs_f64()
    );
    // the reference instrument: about half a minute.
    assert!(
        (15e6..60e6).contains(&(refined_done.device_us as f64)),
        "{} µs",
        refined_done.device_us
    );
}

/// Two independent implementations of the method's TSL model: the simulator's sheet
/// (hil_sim::sheet) and the fit's model (host::analysis::model).
#[test]
fn the_simulators_gaussian_sheet_is_the_fits_model_at_the_reference_vectors() {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../host/tests/data/tsl-vectors.csv"
    ))
    .unwrap();
    let mut worst: f64 = 0.0;
    for line in text.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let n = |k: usize| f[k].parse::<f64>().unwrap();
        let stock = hil_sim::sheet::Stock {
            sigma_deg: n(1),
            rho_s: n(2),
            rho_d: n(3),
            eta: n(4),
        };
        let params = model::Params {
            sigma_deg: n(1),
            rho_s: n(2),
            rho_d: n(3),
            eta: n(4),
        };
        let sheet = hil_sim::sheet::SheetSpec::tsl(stock).spot(1, 0);
        let (simulated, fitted) = (
            hil_sim::scene::Scene::radiance_factor(&sheet, n(5), n(6)),
            model::radiance_factor(&params, n(5), n(6)),
        );
        let relative = (simulated / fitted - 1.0).abs();
        worst = worst.max(relative);
        assert!(
            relative <= 1e-12,
            "{line}: sheet {simulated:.15e}, model {fitted:.15e}"
        );
    }
    eprintln!("sheet vs model at the reference vectors: largest relative difference {worst:.1e}");
    // And the names map to the same stock on both sides.
    for sample in [
        "G",
        "SG",
        "PPC",
        "MC",
        "J1",
        "J2",
        "J3",
        "J4",
        "custom:2.5,10,0.8,1.5",
    ] {
        let p = sample_params(sample).unwrap();
        let spot = SimOptions::default().sheet(sample).unwrap().spot(1, 0);
        for (i, r) in [(20.0, 0.0), (45.0, 44.0), (60.0, 61.5), (30.0, 70.0)] {
            let (a, b) = (
                hil_sim::scene::Scene::radiance_factor(&spot, i, r),
                model::radiance_factor(&p, i, r),
            );
            assert!(
                (a / b - 1.0).abs() <= 1e-12,
                "{sample} at ({i}, {r}): {a} vs {b}"
            );
        }
    }
}

/// Counts above dark over the nominal gain of the reading's range, at `g`.
fn gain_normalised_signal(
    client: &mut Client<SimInstrument>,
    info: &DeviceInfo,
    dark: &[Reading],
    g: Geometry,
    target: Target,
) -> f64 {
    ack(client, Command::MoveTo(g));
    let Ok(Reply::Reading(r)) = client.request(Command::TakeReading {
        integration_ms: 100,
        target,
        range: None,
    }) else {
        panic!("reading")
    };
    let range = usize::from(r.range);
    (f64::from(r.mean_counts) - f64::from(dark[range].mean_counts))
        / f64::from(info.detector_ranges[range].relative_gain)
}

/// Centroid in believed θr of SG's lobe at θi = 30°, scanned at 1° from 14° to 46°.
fn measured_lobe_centroid(opts: &SimOptions) -> f64 {
    let (mut client, info) = homed("SG", opts);
    let Ok(Reply::Dark(dark)) = client.request(Command::TakeDark {
        integration_ms: 100,
    }) else {
        panic!("dark")
    };
    ack(&mut client, Command::SetLamp { on: true });
    let scan: Vec<(f64, f64)> = (14..=46)
        .map(|r| {
            (
                f64::from(r),
                gain_normalised_signal(
                    &mut client,
                    &info,
                    &dark,
                    Geometry::from_whole_deg(30, r),
                    Target::Sample,
                ),
            )
        })
        .collect();
    // The diffuse part: the mean of the scan's ends (the lobe is 4 standard deviations down).
    let base = 0.5 * (scan[0].1 + scan[scan.len() - 1].1);
    let weight: f64 = scan.iter().map(|(_, s)| s - base).sum();
    scan.iter().map(|(r, s)| r * (s - base)).sum::<f64>() / weight
}

#[test]
fn an_arm_offset_moves_the_measured_peak_by_its_size() {
    for seed in 0..8u64 {
        // Offsets spread over ±0.5°, a different one for each seed.
        let offset = ((seed * 37 + 11) % 101) as f64 / 100.0 - 0.5;
        let plain = SimOptions {
            seed,
            ..SimOptions::default()
        };
        let shifted = SimOptions {
            seed,
            arm_offset: Some(offset),
            ..SimOptions::default()
        };
        let moved = measured_lobe_centroid(&shifted) - measured_lobe_centroid(&plain);
        // The detector truly looks from θr + offset, so the lobe shows up offset earlier.
        assert!(
            (moved + offset).abs() < 0.02,
            "seed {seed}: offset {offset:+.2}° moved the peak by {moved:+.4}°"
        );
    }
}

#[test]
fn gain_and_tile_errors_show_in_the_measured_radiance_factor_as_drawn() {
    // G's peak at 45° is read on a less sensitive range than the white tile (range 0): the
    // measured radiance factor is off by that range's true gain over its nominal (range 0
    // is the reference), and by certificate / true tile.
    let g = Geometry::from_whole_deg(45, 45);
    let params = sample_params("G").unwrap();
    let expected = (0..1000)
        .map(|k| model::radiance_factor(&params, 45.0, 44.5 + (f64::from(k) + 0.5) / 1000.0))
        .sum::<f64>()
        / 1000.0;
    let mut offs = Vec::new();
    for seed in 0..24 {
        let opts = SimOptions {
            seed,
            gain_error: Some(2.0),
            tile_error: Some(1.0),
            ..SimOptions::default()
        };
        let (mut client, info) = homed("G", &opts);
        let truth = client.transport_mut().truth().clone();
        let (mean, se) = measured_radiance_factor(&mut client, &info, g, 10);
        // The range the peak was read on (the white tile is read on range 0 there).
        let Ok(Reply::Reading(peak)) = client.request(Command::TakeReading {
            integration_ms: 100,
            target: Target::Sample,
            range: None,
        }) else {
            panic!()
        };
        let range = usize::from(peak.range);
        assert!(
            range > 0,
            "the peak is read on a less sensitive range than the tile"
        );
        let gain_error =
            truth.relative_gains[range] / f64::from(info.detector_ranges[range].relative_gain);
        let predicted = expected
            * gain_error
            * (hil_sim::scene::WHITE_TILE_RADIANCE_FACTOR / truth.tile_radiance_factor);
        let z = (mean - predicted) / se;
        assert!(
            z.abs() < 4.5,
            "seed {seed}: measured {mean:.4} ± {se:.4}, drawn errors predict {predicted:.4} ({z:.1} σ)"
        );
        offs.push(mean / expected - 1.0);
    }
    // The errors are real: the seeds disagree with the scene by percents.
    let spread = (offs.iter().map(|o| o * o).sum::<f64>() / offs.len() as f64).sqrt();
    assert!((0.01..0.06).contains(&spread), "rms error {spread}");
}

#[test]
fn a_scene_file_made_from_a_paper_replays_its_readings() {
    let dir = std::env::temp_dir().join(format!("gonio-replay-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut worst = Vec::new();
    for (sample, tolerance) in [("J1", 0.006), ("PPC", 0.006), ("SG", 0.006)] {
        let mut sample_worst: f64 = 0.0;
        let params = sample_params(sample).unwrap();
        let mut text = String::from("theta_i,theta_r,radiance_factor\n");
        for theta_i in [20, 30, 45, 60] {
            for theta_r in 0..=70 {
                text.push_str(&format!(
                    "{theta_i},{theta_r},{}\n",
                    model::radiance_factor(&params, f64::from(theta_i), f64::from(theta_r))
                ));
            }
        }
        let path = dir.join(format!("{sample}.csv"));
        std::fs::write(&path, text).unwrap();
        for seed in [1, 2, 3] {
            let built_in = SimOptions {
                seed,
                ..SimOptions::default()
            };
            let replay = SimOptions {
                seed,
                scene_file: Some(path.clone()),
                ..SimOptions::default()
            };
            let (mut a, _) = homed(sample, &built_in);
            let (mut b, _) = homed("replay", &replay);
            let (ra, _) = strategy1(&mut a);
            let (rb, _) = strategy1(&mut b);
            assert_eq!(ra.len(), rb.len());
            for (x, y) in ra.iter().zip(&rb) {
                assert_eq!((x.geometry, x.reading.range), (y.geometry, y.reading.range));
                let relative =
                    f64::from(y.reading.mean_counts) / f64::from(x.reading.mean_counts) - 1.0;
                // Same seed, same noise: what differs is the table between its nodes,
                // inside the detector's 1° window.
                assert!(
                    relative.abs() < tolerance,
                    "{sample} seed {seed} at {}: {relative:+.4}",
                    x.geometry
                );
                sample_worst = sample_worst.max(relative.abs());
            }
        }
        worst.push((sample, sample_worst));
    }
    eprintln!(
        "Strategy 1 replayed from a 1° table vs the built-in sheet, largest relative difference: {worst:?}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
