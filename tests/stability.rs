//! Stability where methods fail (issue: speed against accuracy): on a coarse film index x
//! thickness grid, filmscope is within tolerance or flags the pixel (silent failures <= 0.5 %),
//! and is at least as accurate as the paper's method wherever that works.
//!
//! Measured (16 x 12 px, substrate 1.52, paper's noise): filmscope solves 7 of the 9 cells
//! (MAE 0.12-4.1 nm, index error <= 0.0082) and flags every pixel of the other two (n 1.38 at
//! 150 nm: no fringe pair in the band; n 2.35 at 150 nm: no model explains the spectra). The
//! paper's method reports every pixel and is more than 90 % silently wrong in 8 of the 9.

use filmscope::chart::{index_thickness_grid, settings, Cell};

fn grid() -> Vec<Cell> {
    let chosen: Vec<_> = settings(true)
        .into_iter()
        .filter(|s| s.label == "filmscope" || s.label == "paper")
        .collect();
    index_thickness_grid(&[1.38, 1.8, 2.35], &[150.0, 500.0, 1500.0], &chosen).expect("grid")
}

#[test]
fn filmscope_is_accurate_or_flags_and_never_worse_than_paper_where_paper_works() {
    let cells = grid();
    for c in &cells {
        let p = &c.point;
        eprintln!(
            "n {:.2} d {:>6.0} {:<10} n err {:.4} MAE {:>8.2} valid {:>5.1}% silent {:.2}%",
            c.index,
            c.thickness_nm,
            p.method,
            p.index_error_abs,
            p.thickness_mae_nm,
            100.0 * p.valid_fraction,
            100.0 * p.silent_failure_rate
        );
    }
    for c in cells.iter().filter(|c| c.point.method == "filmscope") {
        let p = &c.point;
        let at = format!("n {} d {}", c.index, c.thickness_nm);
        assert!(
            p.silent_failure_rate <= 0.005,
            "{at}: silent {}",
            p.silent_failure_rate
        );
        // 192 pixels pool a noisier index than the paper scenes' 6144 (measured here: n 1.38
        // d 500 gives index error 0.0065, MAE 4.1 nm), hence 5 nm rather than 3.
        if p.valid_fraction > 0.0 {
            assert!(
                p.thickness_mae_nm <= 5.0,
                "{at}: MAE {}",
                p.thickness_mae_nm
            );
            assert!(
                p.index_error_abs <= 0.01,
                "{at}: index {}",
                p.index_error_abs
            );
        }
        // Where the paper's method works (index within 0.01, MAE within 10 nm, most pixels
        // valid), filmscope must be at least as accurate and solve as many pixels.
        let paper = cells
            .iter()
            .find(|o| {
                o.point.method == "paper" && o.index == c.index && o.thickness_nm == c.thickness_nm
            })
            .expect("paper cell");
        let q = &paper.point;
        if q.index_error_abs <= 0.01 && q.thickness_mae_nm <= 10.0 && q.valid_fraction >= 0.9 {
            assert!(
                p.thickness_mae_nm <= q.thickness_mae_nm,
                "{at}: MAE {} vs paper {}",
                p.thickness_mae_nm,
                q.thickness_mae_nm
            );
            assert!(p.valid_fraction >= 0.9, "{at}: valid {}", p.valid_fraction);
        }
    }
}
