mod common;
use host::analysis::fit::{FitOptions, fit};
#[test]
fn timing() {
    let name = std::env::var("PAPER").unwrap_or("G".into());
    let obs = common::synthetic(&common::reference(&name), &common::full_grid(), 1.0, 0.01, 0.003, 3, true);
    for (label, opts) in [("default", FitOptions::default()), ("no arm", FitOptions { arm_offset: false, ..FitOptions::default() }), ("no window no arm", FitOptions { arm_offset: false, acceptance_deg: None, ..FitOptions::default() })] {
        let t0 = std::time::Instant::now();
        for _ in 0..200 {
            std::hint::black_box(fit(&obs, &opts).unwrap());
        }
        println!("{name} {label}: {:.3} ms/fit  stat {:?}", t0.elapsed().as_secs_f64() * 1e3 / 200.0, fit(&obs, &opts).unwrap().arm_offset_statistic);
    }
}
