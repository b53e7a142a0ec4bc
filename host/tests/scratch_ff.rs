mod common;
use common::*;
use host::analysis::fit::{FitOptions, fit};
#[test]
fn ff() {
    for (name, g, label) in [("G", strategy2(2), "s2(2)"), ("SG", strategy2(5), "s2(5)"), ("G", full_grid(), "full"), ("J2", full_grid(), "full"), ("PPC", strategy1_m12(), "m12"), ("G", strategy1_m12(), "m12")] {
        let inst = Instrument::issue();
        let t = truth(&Sheet::ideal(reference(name)), &g, &inst);
        let (mut chi, mut st, mut both, mut nost) = (0, 0, 0, 0);
        let n = 400;
        for seed in 0..n {
            let (obs, _) = draw(&t, &inst, 50_000 + seed);
            let r = fit(&obs, &FitOptions::default()).unwrap();
            let a = r.gof_p.is_some_and(|p| p < 0.005);
            let b = r.structure.is_some_and(|s| s.p_value < 0.005);
            chi += a as usize; st += b as usize; both += (a || b) as usize; nost += r.structure.is_none() as usize;
        }
        println!("{name} {label}: χ² {chi} structure {st} either {both} of {n} (no structure test {nost})");
    }
}
