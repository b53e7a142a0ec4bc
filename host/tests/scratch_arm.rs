mod common;
use host::analysis::fit::{FitOptions, fit};
#[test]
fn arm() {
    for name in ["G", "PPC", "J1"] {
        let mut s = vec![];
        let mut chi = vec![];
        for seed in 0..200 {
            let obs = common::synthetic(&common::reference(name), &common::full_grid(), 1.0, 0.01, 0.003, 1000 + seed, true);
            let r = fit(&obs, &FitOptions::default()).unwrap();
            s.push(r.arm_offset_statistic.unwrap_or(-1.0));
            chi.push(r.chi2.unwrap() / r.dof as f64);
        }
        let over = s.iter().filter(|&&v| v > 6.635).count();
        let screened = s.iter().filter(|&&v| v < 1.0).count();
        let mean: f64 = s.iter().sum::<f64>() / s.len() as f64;
        let mchi: f64 = chi.iter().sum::<f64>() / chi.len() as f64;
        println!("{name}: mean stat {mean:.2} over {over}/200 screened {screened} mean chi2/dof {mchi:.3}");
    }
}
