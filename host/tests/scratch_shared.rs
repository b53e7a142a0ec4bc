mod common;
use common::*;
use host::analysis::fit::{FitOptions, fit_with_shared};
#[test]
fn shared() {
    for (white, tile) in [(0.0, 0.01), (0.005, 0.0)] {
        let inst = Instrument { white_rel: white, tile_rel: tile, ..Instrument::issue() };
        let sheet = Sheet::ideal(reference("G"));
        let t = truth(&sheet, &full_grid(), &inst);
        let mut z = vec![];
        for seed in 0..40 {
            let (obs, shared) = draw(&t, &inst, 20_000 + seed);
            let a = fit_with_shared(&obs, &shared, &FitOptions::default()).unwrap();
            let ratio: f64 = obs.iter().zip(&t).filter(|(_, tt)| (tt.1 - tt.0).abs() > 15.0).map(|(o, tt)| o.radiance_factor / tt.2).sum::<f64>() / obs.iter().zip(&t).filter(|(_, tt)| (tt.1 - tt.0).abs() > 15.0).count() as f64;
            z.push((a.params.rho_d - 0.855) / a.std_error(2).unwrap());
            if seed < 5 { println!("white {white} tile {tile}: ρd {:.5} expected≈{:.5} se {:.5} z {:.2} budget {:?}", a.params.rho_d, 0.855 * ratio, a.std_error(2).unwrap(), z[z.len()-1], a.budget.iter().map(|b| (b.name.clone(), b.variance[2].sqrt())).collect::<Vec<_>>()); }
        }
        let m: f64 = z.iter().sum::<f64>() / z.len() as f64;
        let sd = (z.iter().map(|v| (v - m).powi(2)).sum::<f64>() / z.len() as f64).sqrt();
        println!("z mean {m:.2} sd {sd:.2}");
    }
}
