//! A device that answers only noise (issue 30): the reconnection must end, with the reason
//! stated, instead of greeting it for ever. Noise is heard, so the silence deadline alone
//! never ended it.
use host::instrument::link::{Client, RetryPolicy, Transport};
use host::instrument::sim::SimOptions;
use host::session::{
    DiscardRecorder, LinkLoss, Plan, Policy, PolicyChoice, Session, SessionError, SimulatedOperator,
};
use std::time::Duration;

/// Device time after the noise began past which the test calls the session unbounded
/// (far past the bound the session states).
const HOPELESS_S: f64 = 900.0;

/// The simulated instrument whose every byte, from `noise_from_s` of device time on,
/// arrives as noise (what the firmware sends is replaced by random bytes).
struct TurnsToNoise {
    sim: hil_sim::SimInstrument,
    noise_from_s: f64,
    state: u64,
}

impl TurnsToNoise {
    fn noisy(&self) -> bool {
        self.now().as_secs_f64() >= self.noise_from_s
    }

    fn check_bounded(&self) {
        let since = self.now().as_secs_f64() - self.noise_from_s;
        assert!(
            since < HOPELESS_S,
            "still talking to a device of noise {since:.0} s after the noise began"
        );
    }
}

impl Transport for TurnsToNoise {
    fn write_all(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        self.check_bounded();
        self.sim.write(bytes)
    }

    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> std::io::Result<usize> {
        self.check_bounded();
        let n = self.sim.read(buf, timeout)?;
        if self.noisy() {
            for byte in &mut buf[..n] {
                // xorshift64: noise, zero bytes (frame ends) included.
                self.state ^= self.state << 13;
                self.state ^= self.state >> 7;
                self.state ^= self.state << 17;
                *byte = self.state as u8;
            }
        }
        Ok(n)
    }

    fn pause(&mut self, duration: Duration) {
        self.sim.advance_ms(duration.as_millis() as u64);
    }

    fn now(&self) -> Duration {
        Duration::from_micros(self.sim.device_time_us())
    }

    fn first_seq(&self) -> u32 {
        1
    }
}

#[test]
fn a_device_that_turns_to_noise_is_given_up_within_the_stated_bound_saying_why() {
    for (seed, noise_from_s) in [(1, 20.0), (7, 35.5), (42, 14.2)] {
        let sim = SimOptions {
            seed,
            ..SimOptions::default()
        }
        .instrument("G")
        .expect("sim");
        let transport = TurnsToNoise {
            sim,
            noise_from_s,
            state: 0x9E37_79B9_7F4A_7C15 ^ seed,
        };
        let mut client = Client::new(transport, RetryPolicy::default());
        let info = client.hello().expect("hello before the noise");
        let plan = Plan {
            sample: "G".into(),
            integration_ms: info.default_integration_ms,
            policy: Policy::from(PolicyChoice::Paper),
            acceptance_deg: f64::from(info.acceptance_deg),
            white_check: false,
            white_drift_limit: 0.005,
        };
        let (mut recorder, mut operator) = (DiscardRecorder, SimulatedOperator);
        let result = Session::new(&mut client, info, plan, &mut recorder, &mut operator).run();
        let ended_s = client.transport().now().as_secs_f64();
        match result {
            Err(error @ SessionError::Lost { .. }) => {
                let text = error.to_string();
                let SessionError::Lost { loss, .. } = &error else {
                    unreachable!()
                };
                assert!(
                    matches!(loss, LinkLoss::Unreadable { garbled } if *garbled > 0),
                    "seed {seed}: {loss:?}: {text}"
                );
                assert!(text.contains("nothing could be read"), "{text}");
            }
            Err(other) => panic!("seed {seed}: ended otherwise: {other}"),
            Ok(_) => panic!("seed {seed}: a session on a device of noise finished"),
        }
        // The stated bound: a minute of greetings, and the one under way (32 s).
        assert!(
            ended_s - noise_from_s <= 100.0,
            "seed {seed}: ended {:.1} s after the noise began",
            ended_s - noise_from_s
        );
    }
}
