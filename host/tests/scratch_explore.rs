mod common;
use common::*;
use host::analysis::classify::classify;
use host::analysis::fit::{FitOptions, fit, fit_with_shared};
#[test]
fn explore() {
    let grid = full_grid();
    for (name, lobe, g, label) in [("G", Lobe::Ggx, grid.clone(), "full"), ("G", Lobe::Cauchy, grid.clone(), "full"), ("SG", Lobe::Ggx, grid.clone(), "full"), ("G", Lobe::Ggx, strategy2(2), "s2(2)"), ("G", Lobe::Cauchy, strategy2(2), "s2(2)"),("SG", Lobe::Cauchy, strategy2(3), "s2(3)")] {
        let sheet = Sheet { params: reference(name), lobe, bump: None };
        for with_std in [true, false] {
            let inst = Instrument { with_std, ..Instrument::issue() };
            let t = truth(&sheet, &g, &inst);
            let (mut flagged, mut right, mut confident_wrong) = (0, 0, 0);
            let mut sig = vec![];
            for seed in 0..30 {
                let (obs, _) = draw(&t, &inst, seed);
                let r = fit(&obs, &FitOptions::default()).unwrap();
                let c = classify(&r);
                flagged += r.lack_of_fit as usize;
                let truth_class = host::analysis::classify::REFERENCES.iter().find(|x| x.name == name).unwrap().class;
                right += (c.class == Some(truth_class)) as usize;
                confident_wrong += (c.class.is_some() && c.class != Some(truth_class) && c.confidence >= 0.95) as usize;
                sig.push(r.params.sigma_deg);
            }
            println!("{name} {lobe:?} {label} std {with_std}: flagged {flagged}/30 right {right}/30 confident-wrong {confident_wrong} σ {:.3}..{:.3}", sig.iter().cloned().fold(f64::INFINITY, f64::min), sig.iter().cloned().fold(0.0, f64::max));
        }
    }
    // ideal false flags and coverage
    for (name, g, label) in [("G", grid.clone(), "full"), ("PPC", grid.clone(), "full"), ("J1", grid.clone(), "full"), ("G", strategy2(2), "s2"), ("MC", strategy1_m12(), "m12")] {
        for inst in [Instrument::issue(), Instrument::quiet(), Instrument { with_std: false, ..Instrument::issue() }] {
            let sheet = Sheet::ideal(reference(name));
            let t = truth(&sheet, &g, &inst);
            let p = reference(name).to_array();
            let (mut flagged, mut cov) = (0, [0; 3]);
            let n = 100;
            for seed in 0..n {
                let (obs, _) = draw(&t, &inst, 10_000 + seed);
                let r = fit(&obs, &FitOptions::default()).unwrap();
                flagged += r.lack_of_fit as usize;
                for i in 0..3 { cov[i] += covers(r.ci95[i], p[i]) as usize; }
            }
            println!("ideal {name} {label} {:?}: false flags {flagged}/{n}, coverage {:?}", (inst.rel, inst.with_std), cov);
        }
    }
    // shared errors
    for name in ["G", "PPC"] {
        let inst = Instrument { white_rel: 0.005, tile_rel: 0.01, ..Instrument::issue() };
        let sheet = Sheet::ideal(reference(name));
        let t = truth(&sheet, &grid, &inst);
        let p = reference(name).to_array();
        let (mut cov_with, mut cov_without, mut fl_with, mut fl_without) = ([0; 3], [0; 3], 0, 0);
        let n = 100;
        for seed in 0..n {
            let (obs, shared) = draw(&t, &inst, 20_000 + seed);
            let a = fit_with_shared(&obs, &shared, &FitOptions::default()).unwrap();
            let b = fit(&obs, &FitOptions::default()).unwrap();
            fl_with += a.lack_of_fit as usize; fl_without += b.lack_of_fit as usize;
            for i in 0..3 { cov_with[i] += covers(a.ci95[i], p[i]) as usize; cov_without[i] += covers(b.ci95[i], p[i]) as usize; }
        }
        println!("shared {name}: with {cov_with:?} flags {fl_with}, without {cov_without:?} flags {fl_without}");
    }
}
