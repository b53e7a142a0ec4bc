mod common;
use common::*;
use host::analysis::classify::classify;
use host::analysis::fit::{FitOptions, fit};
use host::analysis::model::Params;
#[test]
fn eta() {
    let p = Params { sigma_deg: 10.0, rho_s: 5.0, rho_d: 0.5, eta: 1.001 };
    for (g, label) in [(full_grid(), "full"), (strategy1_m12(), "m12"), (strategy2(3), "s2")] {
        for with_std in [true, false] {
            let inst = Instrument { with_std, ..Instrument::issue() };
            let t = truth(&Sheet::ideal(p), &g, &inst);
            for seed in 0..3 {
                let (obs, _) = draw(&t, &inst, seed);
                let r = fit(&obs, &FitOptions::default()).unwrap();
                let c = classify(&r);
                println!("{label} std {with_std}: conf {:.2} ρs ci {:?} η ci {:?} ρs {:?} raw {:.1} η {:.4} σ {:?} class {:?} undecided {:?} nearest {} notes {:?}", c.confidence, r.ci95[1], r.ci95[3], r.reported(1), r.params.rho_s, r.params.eta, r.sigma_deg(), c.class, c.undecided, c.nearest_reference, r.notes);
            }
        }
    }
}
