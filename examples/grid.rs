//! Temporary: writes a GridScene as a scene file.
fn main() {
    let a: Vec<f64> = std::env::args().skip(1).map(|s| s.parse().unwrap()).collect();
    let s = filmscope::chart::GridScene { index: a[0], thickness_nm: a[1], seed: a[2] as u64, noise_percent: a.get(3).copied(), ..Default::default() };
    print!("{}", s.toml());
}
