mod common;
use common::*;
use host::analysis::classify::classify;
use host::analysis::fit::{FitOptions, fit};
#[test]
fn bump() {
    for (amp, sb) in [(0.3, 1.0), (1.0, 0.5), (0.1, 2.0)] {
        for (g, label) in [(full_grid(), "full"), (strategy2(2), "s2(2)"), (strategy1_m12(), "m12")] {
            let sheet = Sheet { params: reference("J2"), lobe: Lobe::Gaussian, bump: Some((amp, sb)) };
            let inst = Instrument::issue();
            let t = truth(&sheet, &g, &inst);
            let p = reference("J2").to_array();
            let (mut flagged, mut honest, mut right, mut cw) = (0, 0, 0, 0);
            let mut rd = vec![];
            for seed in 0..40 {
                let (obs, _) = draw(&t, &inst, 70_000 + seed);
                let r = fit(&obs, &FitOptions::default()).unwrap();
                let c = classify(&r);
                flagged += r.lack_of_fit as usize;
                let cov = (0..3).all(|i| covers(r.ci95[i], p[i]));
                honest += (r.lack_of_fit || cov) as usize;
                right += (c.class == Some(host::analysis::classify::Class::RoughI)) as usize;
                cw += (c.class.is_some_and(|k| k != host::analysis::classify::Class::RoughI) && c.confidence >= 0.95) as usize;
                rd.push(r.params.rho_d);
            }
            println!("J2 bump ({amp}, {sb}) {label}: flagged {flagged}/40 flagged-or-covering {honest}/40 class right {right} confident-wrong {cw} ρd {:.4}..{:.4}", rd.iter().cloned().fold(9.0, f64::min), rd.iter().cloned().fold(0.0, f64::max));
        }
    }
    for name in ["G", "SG", "PPC", "J1"] {
        for (g, label) in [(full_grid(), "full"), (strategy2(2), "s2(2)")] {
            let sheet = Sheet::ideal(reference(name));
            let inst = Instrument { arm_offset_deg: 0.3, ..Instrument::issue() };
            let t = truth(&sheet, &g, &inst);
            let p = reference(name).to_array();
            let (mut detected, mut d_cov, mut s_cov, mut flagged) = (0, 0, 0, 0);
            let mut sig = vec![];
            for seed in 0..40 {
                let (obs, _) = draw(&t, &inst, 80_000 + seed);
                let r = fit(&obs, &FitOptions::default()).unwrap();
                detected += r.arm_offset.is_some() as usize;
                d_cov += r.arm_offset.is_some_and(|a| a.ci95.0 <= 0.3 && 0.3 <= a.ci95.1) as usize;
                s_cov += covers(r.ci95[0], p[0]) as usize;
                flagged += r.lack_of_fit as usize;
                sig.push(r.params.sigma_deg / p[0] - 1.0);
            }
            let m = sig.iter().sum::<f64>() / sig.len() as f64;
            println!("{name} offset 0.3 {label}: detected {detected}/40, δ covered {d_cov}, σ covered {s_cov}, flagged {flagged}, σ mean error {:+.2} %", 100.0 * m);
        }
    }
}
