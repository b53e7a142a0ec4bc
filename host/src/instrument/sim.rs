//! The simulated instrument from the host's side: the options shared by `gonio sim` and
//! `gonio measure --sim`, the samples it can hold, and the in-process [`Transport`].
//!
//! The simulator knows no reflectance model; the samples are TSL scenes made here from
//! [`crate::analysis::model`] and the reference papers of [`crate::analysis::classify::REFERENCES`].

use crate::analysis::classify::REFERENCES;
use crate::instrument::link::Transport;
use crate::analysis::model::{self, Params};
use firmware::hardware::Arm;
use hil_sim::scene::SamplePort;
use hil_sim::{Faults, SimConfig, SimInstrument};
use std::sync::Arc;
use std::time::Duration;

impl Transport for SimInstrument {
    fn write_all(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        self.write(bytes)
    }

    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> std::io::Result<usize> {
        SimInstrument::read(self, buf, timeout)
    }

    fn pause(&mut self, duration: Duration) {
        self.advance_ms(duration.as_millis() as u64);
    }

    /// Device time: waiting on the simulator runs it forward instead of sleeping.
    fn now(&self) -> Duration {
        Duration::from_micros(self.device_time_us())
    }

    /// The simulator in process lives and dies with this host process: no earlier host
    /// can have used its sequence numbers. A fixed start keeps a seed's run repeatable
    /// (the numbers' encoded length changes which bytes the link faults hit).
    fn first_seq(&self) -> u32 {
        1
    }

    fn name(&self) -> String {
        "the simulated instrument (in process)".to_string()
    }
}

/// Options of the simulated instrument (the same on `gonio sim` and `gonio measure --sim`).
#[derive(clap::Args, Clone, Debug)]
pub struct SimOptions {
    /// Seed of the simulated noise and link faults: the same seed repeats a run exactly.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Detector acceptance, full width, degrees.
    #[arg(long, value_name = "DEG", default_value_t = model::DEFAULT_ACCEPTANCE_DEG)]
    pub acceptance: f64,
    /// Scale of every detector noise term (1 = the reference instrument, 0 = noiseless).
    #[arg(long, value_name = "FACTOR", default_value_t = 1.0)]
    pub noise_scale: f64,
    /// Faults to inject: corrupt=P,drop=P,unplug-at=SECONDS,lose-steps=ARM:COUNT,no-switch=ARM
    /// (ARM is source or detector).
    #[arg(long, value_name = "LIST", default_value = "")]
    pub faults: String,
}

/// A bad simulator option.
#[derive(Debug, thiserror::Error)]
pub enum SimOptionError {
    /// Not a sample the simulator knows.
    #[error("unknown sample '{0}': use one of G, SG, PPC, MC, J1, J2, J3, J4 or custom:SIGMA,RHO_S,RHO_D,ETA")]
    UnknownSample(String),
    /// A custom sample with bad parameters.
    #[error("bad custom sample '{spec}': {why}")]
    BadCustom {
        /// What was given.
        spec: String,
        /// What is wrong.
        why: String,
    },
    /// A bad `--faults` item.
    #[error("bad fault '{item}' in --faults: {why}")]
    BadFault {
        /// The item.
        item: String,
        /// What is wrong.
        why: String,
    },
    /// A bad number option.
    #[error("--{option} must be {why}, got {value}")]
    BadOption {
        /// Which option.
        option: &'static str,
        /// What it must be.
        why: &'static str,
        /// What was given.
        value: f64,
    },
}

/// The TSL parameters of a sample name: a reference paper (any case) or
/// `custom:SIGMA,RHO_S,RHO_D,ETA`.
pub fn sample_params(name: &str) -> Result<Params, SimOptionError> {
    if let Some(spec) = name.strip_prefix("custom:") {
        let bad = |why: &str| SimOptionError::BadCustom { spec: spec.to_owned(), why: why.to_owned() };
        let values: Vec<f64> = spec
            .split(',')
            .map(|v| v.trim().parse::<f64>().map_err(|_| bad(&format!("'{}' is not a number", v.trim()))))
            .collect::<Result<_, _>>()?;
        let [sigma_deg, rho_s, rho_d, eta] = values[..] else {
            return Err(bad("four numbers are needed: SIGMA,RHO_S,RHO_D,ETA"));
        };
        if values.iter().any(|v| !v.is_finite()) {
            return Err(bad("every value must be finite"));
        }
        if !(sigma_deg > 0.0 && sigma_deg <= 90.0) {
            return Err(bad("SIGMA must be in (0, 90] degrees"));
        }
        if rho_s < 0.0 || rho_d < 0.0 {
            return Err(bad("RHO_S and RHO_D must not be negative"));
        }
        if !(1.0..=3.0).contains(&eta) {
            return Err(bad("ETA must be in [1, 3]"));
        }
        return Ok(Params { sigma_deg, rho_s, rho_d, eta });
    }
    REFERENCES
        .iter()
        .find(|r| r.name.eq_ignore_ascii_case(name))
        .map(|r| r.params)
        .ok_or_else(|| SimOptionError::UnknownSample(name.to_owned()))
}

fn parse_arm(item: &str, value: &str) -> Result<Arm, SimOptionError> {
    match value.to_ascii_lowercase().as_str() {
        "source" | "i" | "0" => Ok(Arm::Source),
        "detector" | "r" | "1" => Ok(Arm::Detector),
        _ => Err(SimOptionError::BadFault { item: item.to_owned(), why: "ARM is source or detector".into() }),
    }
}

/// Parse `--faults`.
pub fn parse_faults(spec: &str) -> Result<Faults, SimOptionError> {
    let mut faults = SimConfig::default().faults;
    for item in spec.split(',').map(str::trim).filter(|i| !i.is_empty()) {
        let bad = |why: &str| SimOptionError::BadFault { item: item.to_owned(), why: why.to_owned() };
        let (key, value) = item.split_once('=').ok_or_else(|| bad("expected KEY=VALUE"))?;
        let number = |v: &str| v.trim().parse::<f64>().ok().filter(|x| x.is_finite());
        match key.trim() {
            "corrupt" | "drop" => {
                let p = number(value).filter(|p| (0.0..=1.0).contains(p)).ok_or_else(|| bad("a probability in [0, 1]"))?;
                if key.trim() == "corrupt" { faults.corrupt = p } else { faults.drop = p }
            }
            "unplug-at" => {
                faults.unplug_at_s = Some(number(value).filter(|s| *s >= 0.0).ok_or_else(|| bad("seconds of device time, ≥ 0"))?);
            }
            "lose-steps" => {
                let (arm, count) = value.split_once(':').ok_or_else(|| bad("expected lose-steps=ARM:COUNT"))?;
                let count = count.trim().parse::<i32>().ok().filter(|c| *c > 0).ok_or_else(|| bad("COUNT is a positive whole number"))?;
                faults.lose_steps = Some((parse_arm(item, arm)?, count));
            }
            "no-switch" => faults.switch_missing = Some(parse_arm(item, value)?),
            _ => return Err(bad("known faults: corrupt, drop, unplug-at, lose-steps, no-switch")),
        }
    }
    Ok(faults)
}

impl SimOptions {
    /// The simulated instrument with `sample` on its port.
    pub fn instrument(&self, sample: &str) -> Result<SimInstrument, SimOptionError> {
        let params = sample_params(sample)?;
        if !(self.acceptance.is_finite() && (0.0..=10.0).contains(&self.acceptance)) {
            return Err(SimOptionError::BadOption { option: "acceptance", why: "between 0 and 10 degrees", value: self.acceptance });
        }
        if !(self.noise_scale.is_finite() && self.noise_scale >= 0.0) {
            return Err(SimOptionError::BadOption { option: "noise-scale", why: "a number ≥ 0", value: self.noise_scale });
        }
        let mut config = SimConfig { seed: self.seed, faults: parse_faults(&self.faults)?, ..SimConfig::default() };
        config.detector.acceptance_deg = self.acceptance;
        config.detector.noise_scale = self.noise_scale;
        // The detector applies its own acceptance to whatever the scene is.
        let scene = move |theta_i_deg: f64, theta_r_deg: f64| model::radiance_factor(&params, theta_i_deg, theta_r_deg);
        Ok(SimInstrument::new(SamplePort::new(Arc::new(scene)), config))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_by_name_and_custom() {
        assert_eq!(sample_params("g").unwrap().sigma_deg, 0.8);
        assert_eq!(sample_params("J4").unwrap().rho_d, 0.346);
        let p = sample_params("custom:2.5,10,0.8,1.5").unwrap();
        assert_eq!((p.sigma_deg, p.rho_s, p.rho_d, p.eta), (2.5, 10.0, 0.8, 1.5));
        for bad in ["XX", "custom:1,2,3", "custom:0,1,1,1.5", "custom:1,-1,1,1.5", "custom:1,1,1,4", "custom:1,a,1,2", "custom:nan,1,1,2"] {
            assert!(sample_params(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn faults_parse_and_refuse_nonsense() {
        let f = parse_faults("corrupt=0.001, drop=0.002,unplug-at=5,lose-steps=detector:37,no-switch=source").unwrap();
        assert_eq!((f.corrupt, f.drop, f.unplug_at_s), (0.001, 0.002, Some(5.0)));
        assert_eq!(f.lose_steps, Some((Arm::Detector, 37)));
        assert_eq!(f.switch_missing, Some(Arm::Source));
        assert_eq!(parse_faults("").unwrap(), SimConfig::default().faults);
        for bad in ["corrupt=2", "drop=x", "unplug-at=-1", "lose-steps=left:3", "lose-steps=source:0", "melt=1", "corrupt"] {
            let error = parse_faults(bad).unwrap_err().to_string();
            assert!(error.contains(bad.split(',').next().unwrap()), "{error}");
        }
    }
}
