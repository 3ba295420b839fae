//! Criterion benchmarks of filmscope's hot kernels, each reported as elements per second.
//!
//! - `track/push`: the per-pixel extremum tracker over 1024 pixels x 151 bands of a thin-film
//!   fringe spectrum, band-major as the pipeline streams it (throughput: pixel-band samples).
//! - `track/row`: the same spectra through the row kernel the pipeline uses
//!   (`track::row::push_row`, one row of 1024 pixels per band; into whole lists here, the
//!   workers keep most pixels' last four, `ExtremaHead`).
//! - `refine/gn_sums_add`: the full-spectrum Gauss-Newton sums over the same 1024 x 151
//!   samples, band models built once, computed per sample (throughput: samples).
//! - `refine/gn_sums_add_tabled`: the same from the tabulated band models.
//! - `refine/band_coef_new`: building one angle's 151 band models (throughput: bands).
//! - `refine/tabulate`: tabulating them over 30-2500 nm (throughput: bands).
//! - `calibrate/*`: raw counts + dark + white to reflectance on a 2048 x 16 block
//!   (throughput: samples).
//! - `solve/end_angle_*`: the solver's angle-end passes (`SweepSolver::end_angle_all`, one
//!   shard, one thread) over the software camera's `paper-sample1` scene, after the rows of
//!   that angle were fed (throughput: pixels).
//! - `solve/feed_row_*`: a whole refining angle of that scene through `Shard::feed_row`
//!   (tracker plus Gauss-Newton sums; throughput: pixel-band samples).
//!
//! `track/*` and `refine/*` call the kernels directly: the portable build (SSE2 on x86-64).
//! `solve/feed_row_*` goes through `Shard::feed_row`, which the workers call, and so runs
//! compiled for AVX2 and FMA where the CPU has them (`filmscope_core::simd::wide`;
//! `filmscope bench` prints both builds' figures).
//!
//! Run with `cargo bench --bench kernels`.

use std::f64::consts::PI;
use std::hint::black_box;
use std::path::Path;
use std::time::Duration;

use criterion::measurement::WallTime;
use criterion::{criterion_main, BatchSize, BenchmarkGroup, Criterion, SamplingMode, Throughput};
use filmscope::calibrate::calibrate_row;
use filmscope::optics::Polarization;
use filmscope::pipeline::{BandModels, ShardState};
use filmscope::solve::fit_row::{self, FitLanes, IndexLanes, IndexSampling};
use filmscope::solve::refine::{BandCoef, FilmTerms, GnSums, Knot};
use filmscope::solve::sweep::SolverOptions;
use filmscope::solve::{IndexModel, SweepSolver};
use filmscope::source::calibrate_block;
use filmscope::source::{Samples, SimSource, Source};
use filmscope::track::row::{blocks_for, push_row, TrackerLanes, LANES};
use filmscope::track::{ExtremaList, PixelTracker, MAX_EXTREMA};
use firmware_sim::{Scene, SoftwareCamera};

/// Pixels per row of the synthetic spectra.
const PIXELS: usize = 1024;
/// Bands 420..720 nm in 2 nm steps, as the paper's LCTF.
const BANDS: usize = 151;
/// Film index of the synthetic spectra.
const N_FILM: f64 = 1.38;
/// Incidence angle of the synthetic band models, degrees.
const ANGLE_DEG: f64 = 30.0;

fn wavelength(band: usize) -> f64 {
    420.0 + 2.0 * band as f64
}

/// Thickness of synthetic pixel `p`: 300..700 nm across the row.
fn thickness(p: usize) -> f64 {
    300.0 + 400.0 * p as f64 / (PIXELS - 1) as f64
}

/// A small deterministic pseudo-random generator (xorshift64*), uniform in `[-1, 1)`.
struct Noise(u64);

impl Noise {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let x = self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11;
        x as f64 / (1u64 << 52) as f64 - 1.0
    }
}

/// Band-major fringe spectra `0.04 + 0.03 cos(4 pi n d / lambda)` plus uniform noise of
/// +-0.004 (about 0.0023 RMS, the paper scene's shot noise at this reflectance).
fn fringe_spectra() -> Vec<f32> {
    let mut noise = Noise(0x9e37_79b9_7f4a_7c15);
    let mut v = Vec::with_capacity(BANDS * PIXELS);
    for b in 0..BANDS {
        let l = wavelength(b);
        for p in 0..PIXELS {
            let r = 0.04 + 0.03 * (4.0 * PI * N_FILM * thickness(p) / l).cos();
            v.push((r + 0.004 * noise.next()) as f32);
        }
    }
    v
}

fn band_coefs() -> Vec<BandCoef> {
    (0..BANDS)
        .map(|b| {
            BandCoef::new(
                IndexModel::constant(N_FILM),
                FilmTerms::NONE,
                1.0,
                1.65,
                0.0,
                filmscope_core::optics::BackFace::None,
                Polarization::S,
                ANGLE_DEG,
                wavelength(b),
                4.0,
                2000.0,
            )
            .expect("a 1.38 film at 30 degrees propagates")
        })
        .collect()
}

fn short<'a>(c: &'a mut Criterion, name: &str) -> BenchmarkGroup<'a, WallTime> {
    let mut g = c.benchmark_group(name);
    g.sample_size(20)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(3));
    g
}

fn bench_tracker(c: &mut Criterion) {
    let spectra = fringe_spectra();
    let mut trackers = vec![PixelTracker::default(); PIXELS];
    let mut lists = vec![ExtremaList::new(); PIXELS];
    let sweep = |trackers: &mut [PixelTracker], lists: &mut [ExtremaList]| {
        for (t, l) in trackers.iter_mut().zip(lists.iter_mut()) {
            t.reset();
            l.clear();
        }
        for (b, row) in spectra.chunks_exact(PIXELS).enumerate() {
            for ((t, l), &v) in trackers.iter_mut().zip(lists.iter_mut()).zip(row) {
                t.push(b as u16, v, true, l);
            }
        }
    };
    // The spectra must look like fringes to the tracker (300..700 nm: 2-6 extrema each).
    sweep(&mut trackers, &mut lists);
    let found: usize = lists.iter().map(|l| l.len()).sum();
    assert!(
        found > 2 * PIXELS && lists.iter().all(|l| l.len() < MAX_EXTREMA),
        "the tracker found {found} extrema in {PIXELS} synthetic spectra"
    );

    let mut g = short(c, "track");
    g.throughput(Throughput::Elements((PIXELS * BANDS) as u64));
    g.bench_function("push_1024px_x_151b", |bench| {
        bench.iter(|| {
            sweep(&mut trackers, &mut lists);
            black_box(&lists);
        });
    });

    let mut blocks = vec![TrackerLanes::EMPTY; blocks_for(1, PIXELS)];
    let mut row_lists = vec![ExtremaList::new(); PIXELS];
    let rows = |blocks: &mut [TrackerLanes], lists: &mut [ExtremaList]| {
        blocks.iter_mut().for_each(TrackerLanes::reset);
        lists.iter_mut().for_each(ExtremaList::clear);
        for (b, row) in spectra.chunks_exact(PIXELS).enumerate() {
            push_row(blocks, b as u16, row, true, lists);
        }
    };
    rows(&mut blocks, &mut row_lists);
    assert_eq!(
        row_lists, lists,
        "the row kernel finds what the scalar tracker finds"
    );
    g.bench_function("row_1024px_x_151b", |bench| {
        bench.iter(|| {
            rows(&mut blocks, &mut row_lists);
            black_box(&row_lists);
        });
    });
    g.finish();
}

fn bench_refine(c: &mut Criterion) {
    let coefs = band_coefs();
    // One order of the film at mid-band: lambda / (2 n cos theta_film).
    let sin = ANGLE_DEG.to_radians().sin();
    let order_step = 570.0 / (2.0 * (N_FILM * N_FILM - sin * sin).sqrt());
    let mut noise = Noise(0x2545_f491_4f6c_dd1d);
    let measured: Vec<f32> = coefs
        .iter()
        .flat_map(|c| {
            (0..PIXELS)
                .map(|p| (c.model(thickness(p)) + 0.002 * noise.next()) as f32)
                .collect::<Vec<_>>()
        })
        .collect();
    // Linearisation points a nm off the truth, as after the first refinement step.
    let lin: Vec<f64> = (0..PIXELS).map(|p| thickness(p) + 1.0).collect();
    let mut sums = vec![GnSums::default(); PIXELS];

    let mut g = short(c, "refine");
    // About 30 ms an iteration: flat sampling keeps it within the measurement time.
    g.sampling_mode(SamplingMode::Flat);
    g.throughput(Throughput::Elements((PIXELS * BANDS) as u64));
    g.bench_function("gn_sums_add_1024px_x_151b", |bench| {
        bench.iter(|| {
            sums.fill(GnSums::default());
            for (coef, row) in coefs.iter().zip(measured.chunks_exact(PIXELS)) {
                for ((s, &d), &v) in sums.iter_mut().zip(&lin).zip(row) {
                    s.add(coef, &[], d, order_step, f64::from(v));
                }
            }
            black_box(&sums);
        });
    });
    let range = [30.0, 2500.0];
    let knots_needed: usize = coefs
        .iter()
        .filter_map(|c| c.knots_for(range))
        .map(|(_, n)| n)
        .sum();
    let mut knots = vec![Knot::default(); knots_needed];
    let tabulate = |coefs: &mut [BandCoef], knots: &mut [Knot]| {
        let mut used = 0;
        for c in coefs.iter_mut() {
            let n = c.knots_for(range).map_or(0, |(_, n)| n);
            c.tabulate(range, used, &mut knots[used..used + n]);
            used += n;
        }
    };
    let mut tabled = coefs.clone();
    tabulate(&mut tabled, &mut knots);
    assert!(tabled.iter().all(BandCoef::tabulated));
    g.bench_function("gn_sums_add_tabled_1024px_x_151b", |bench| {
        bench.iter(|| {
            sums.fill(GnSums::default());
            for (coef, row) in tabled.iter().zip(measured.chunks_exact(PIXELS)) {
                for ((s, &d), &v) in sums.iter_mut().zip(&lin).zip(row) {
                    s.add(coef, &knots, d, order_step, f64::from(v));
                }
            }
            black_box(&sums);
        });
    });
    // What the pipeline runs: the same sums over row blocks of lanes (`FitLanes`).
    let mut blocks = vec![FitLanes::default(); PIXELS.div_ceil(LANES)];
    let seed = |blocks: &mut [FitLanes]| {
        for (i, &d) in lin.iter().enumerate() {
            let b = &mut blocks[i / LANES];
            let mut p = b.pixel(i % LANES, [0.0; 8]);
            p.thickness_nm = d as f32;
            p.order_step_nm = order_step as f32;
            b.set_pixel(i % LANES, &p);
        }
    };
    // Every pixel keeping the index's sums (a small sensor), one in 16 (a 1 Mpix one: two
    // lanes of every block), one in 64 (4 Mpix: one lane of every other block) and none
    // (the index held).
    for (name, stride) in [
        ("fit_lanes_tabled_1024px_x_151b", Some(1)),
        ("fit_lanes_tabled_1024px_x_151b_index_1_in_16", Some(16)),
        ("fit_lanes_tabled_1024px_x_151b_index_1_in_64", Some(64)),
        ("fit_lanes_tabled_1024px_x_151b_index_held", None),
    ] {
        let sampling = stride.map(IndexSampling::one_in);
        let per_row = sampling.map_or(0, |s| s.blocks_per_row(PIXELS));
        let mut index = vec![IndexLanes::EMPTY; per_row];
        g.bench_function(name, |bench| {
            bench.iter(|| {
                blocks.fill(FitLanes::default());
                index.fill(IndexLanes::EMPTY);
                seed(&mut blocks);
                for (coef, row) in tabled.iter().zip(measured.chunks_exact(PIXELS)) {
                    let model = Some((coef, &knots[..]));
                    let index = sampling.map(|s| (s, 0, &mut index[..]));
                    fit_row::push_row(&mut blocks, row, model, index, false);
                }
                black_box((&blocks, &index));
            });
        });
    }
    g.throughput(Throughput::Elements(BANDS as u64));
    g.bench_function("tabulate_151b", |bench| {
        let mut scratch = coefs.clone();
        bench.iter(|| {
            tabulate(&mut scratch, &mut knots);
            black_box(&knots);
        });
    });

    g.sampling_mode(SamplingMode::Auto);
    g.throughput(Throughput::Elements(BANDS as u64));
    g.bench_function("band_coef_new_151b", |bench| {
        bench.iter(|| {
            for b in 0..BANDS {
                black_box(BandCoef::new(
                    IndexModel::constant(black_box(N_FILM)),
                    FilmTerms::NONE,
                    1.0,
                    1.65,
                    0.0,
                    filmscope_core::optics::BackFace::None,
                    Polarization::S,
                    ANGLE_DEG,
                    wavelength(b),
                    4.0,
                    2000.0,
                ));
            }
        });
    });
    g.finish();
}

fn bench_calibrate(c: &mut Criterion) {
    const WIDTH: usize = 2048;
    const ROWS: usize = 16;
    const SATURATION: f32 = 4095.0;
    let mut noise = Noise(0x0123_4567_89ab_cdef);
    let n = WIDTH * ROWS;
    let dark: Vec<f32> = (0..n).map(|_| (64.0 + 0.5 * noise.next()) as f32).collect();
    let white: Vec<f32> = (0..n)
        .map(|i| {
            // Vignetted white reference; every 997th pixel dead (no usable reference).
            let x = (i % WIDTH) as f64 / WIDTH as f64 - 0.5;
            let w = if i % 997 == 0 {
                64.0
            } else {
                64.0 + 3000.0 * (1.0 - 0.3 * x * x)
            };
            w as f32
        })
        .collect();
    let counts: Vec<f32> = (0..n)
        .map(|i| {
            // Reflectance 0.01..0.07 plus read noise; every 1009th pixel hot (saturated).
            let r = 0.04 + 0.03 * (i as f64 * 0.01).sin();
            let c = f64::from(dark[i]) + r * f64::from(white[i] - dark[i]) + 3.0 * noise.next();
            if i % 1009 == 0 {
                SATURATION
            } else {
                c.round().clamp(0.0, f64::from(SATURATION)) as f32
            }
        })
        .collect();
    let samples = Samples::Raw {
        counts: counts.clone(),
        dark: Some(dark.clone()),
        white: white.clone(),
        white_reflectance: 0.99,
        saturation_counts: SATURATION,
    };

    let mut g = short(c, "calibrate");
    g.throughput(Throughput::Elements(n as u64));
    g.bench_function("calibrate_row_2048px_x_16rows", |bench| {
        let mut out = vec![0f32; n];
        bench.iter(|| {
            for (k, o) in out.chunks_exact_mut(WIDTH).enumerate() {
                let s = k * WIDTH..(k + 1) * WIDTH;
                calibrate_row(
                    &counts[s.clone()],
                    Some(&dark[s.clone()]),
                    &white[s],
                    0.99,
                    SATURATION,
                    o,
                );
            }
            black_box(&out);
        });
    });
    // The pipeline's stage: takes the message's buffers and returns a new one (the input
    // clone is setup, not timed).
    g.bench_function("calibrate_block_2048px_x_16rows", |bench| {
        bench.iter_batched(
            || samples.clone(),
            |s| calibrate_block(s, ROWS, WIDTH),
            BatchSize::LargeInput,
        );
    });
    g.finish();
}

/// The paper-sample1 scene's sweep (96 x 64 pixels, 151 bands, angles 10..50 degrees) as
/// the pipeline would see it with one shard: raw counts calibrated on the fly, fed row by row.
struct Prepared {
    /// Pixels per row.
    width: usize,
    /// The solver options of the sweep.
    options: SolverOptions,
    /// Solver and states after `begin_angle` of angle `upto`, before its rows.
    before_rows: (SweepSolver, ShardState),
    /// The band models of angle `upto`.
    models: BandModels,
    /// Calibrated rows of angle `upto`, band-major then row-major.
    rows: Vec<f32>,
    /// Solver and states after every row of angle `upto`, before its end.
    before_end: (SweepSolver, ShardState),
}

impl Prepared {
    /// Angle `upto` of paper-sample1 (96 x 64), the index's sums kept by one pixel in
    /// `stride` (1: every pixel, as on a sensor this small; 16: as on a 1 Mpix one).
    fn new(upto: usize, stride: usize) -> Self {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/scenes/paper-sample1.toml");
        let scene = Scene::load(&path).expect("config/scenes/paper-sample1.toml loads");
        let camera = SoftwareCamera::new(scene);
        let source = SimSource::new(camera.clone(), false, 1).expect("a valid sweep spec");
        let mut spec = source.spec().clone();
        spec.options.index_pixels = spec.width * spec.height / stride;
        let (w, h) = (spec.width, spec.height);
        let nb = spec.bands_nm.len();
        let options = spec.options;
        let sat = camera.scene().sensor.saturation_counts() as f32;
        let angles = camera.scene().angles_deg.clone();
        assert!(upto < angles.len(), "the scene has {} angles", angles.len());
        let mut states = ShardState::empty(h, w, spec.index_sampling());
        let mut solver = SweepSolver::new(spec, None);
        let (mut raw16, mut raw, mut white, mut dark) =
            (vec![0u16; w], vec![0f32; w], vec![0f32; w], vec![0f32; w]);
        let mut models = BandModels::default();
        let mut rows = vec![0f32; nb * h * w];
        let mut before_rows = None;
        for (a, &deg) in angles.iter().enumerate().take(upto + 1) {
            solver.begin_angle(deg);
            models = BandModels::of(&solver, 1);
            states.shard(0, w).begin_angle();
            if a == upto {
                before_rows = Some((solver.clone(), states.clone()));
            }
            let mut shard = states.shard(0, w);
            for (b, band) in rows.chunks_exact_mut(h * w).enumerate() {
                for (r, refl) in band.chunks_exact_mut(w).enumerate() {
                    camera.raw_row(a, b, r, &mut raw16);
                    for (o, &c) in raw.iter_mut().zip(&raw16) {
                        *o = f32::from(c);
                    }
                    camera.white_row(a, b, r, &mut white);
                    camera.dark_row(a, b, r, &mut dark);
                    calibrate_row(&raw, Some(&dark), &white, 1.0, sat, refl);
                    shard.feed_row(options, models.view(), b, r, refl);
                }
            }
            if a < upto {
                solver.end_angle_all(&mut [shard]);
            }
        }
        Self {
            width: w,
            options,
            before_rows: before_rows.expect("angle `upto` was started"),
            models,
            rows,
            before_end: (solver, states),
        }
    }

    /// Feeds every row of the angle into `states`.
    fn feed(&self, states: &mut ShardState) {
        let w = self.width;
        let mut shard = states.shard(0, w);
        let h = shard.rows();
        for (b, band) in self.rows.chunks_exact(h * w).enumerate() {
            for (r, row) in band.chunks_exact(w).enumerate() {
                shard.feed_row(self.options, self.models.view(), b, r, row);
            }
        }
    }
}

/// Angle-end phase `k` (0 tally, 1 sums, 2 update) of `before_end`'s state, the earlier
/// phases run in the set-up.
fn bench_phase(
    g: &mut BenchmarkGroup<'_, WallTime>,
    name: &str,
    (solver, states): &(SweepSolver, ShardState),
    k: usize,
) {
    let w = solver.spec().width;
    g.bench_function(name, |bench| {
        bench.iter_batched(
            || {
                let (mut s, mut st) = (solver.clone(), states.clone());
                if k > 0 {
                    s.end_tally(&[st.shard(0, w)]);
                }
                if k > 1 {
                    s.end_sums(&[st.shard(0, w)]);
                }
                (s, st)
            },
            |(mut s, mut st): (SweepSolver, ShardState)| {
                match k {
                    0 => s.end_tally(&[st.shard(0, w)]),
                    1 => s.end_sums(&[st.shard(0, w)]),
                    _ => {
                        black_box(s.end_update(&mut [st.shard(0, w)]));
                    }
                }
                (s, st)
            },
            BatchSize::LargeInput,
        );
    });
}

fn bench_solve(c: &mut Criterion) {
    let mut g = short(c, "solve");
    // In this scene the 20 and 30 degree pairs give no clear ratio mode (as in the
    // pipeline): the index first comes at 40 degrees' end, so every pixel's order is chosen
    // there; at 50 degrees the full-spectrum sums refine (Schur index step, thickness steps).
    for (upto, name) in [
        (3, "end_angle_40deg_first_index_6144px"),
        (4, "end_angle_50deg_refine_6144px"),
    ] {
        let prep = Prepared::new(upto, 1);
        let (solver, states) = &prep.before_end;
        let w = prep.width;
        // The state must be what the bench claims.
        {
            let (mut s, mut st) = (solver.clone(), states.clone());
            let report = s.end_angle_all(&mut [st.shard(0, w)]);
            let shard = st.shard(0, w);
            let resolved = (0..shard.pixels.len())
                .filter(|&i| shard.fit(i).thickness_nm.is_finite())
                .count();
            assert!(report.index.is_some(), "{name}: no index");
            assert!(
                resolved * 2 > st.pixels.len(),
                "{name}: {resolved} pixels resolved"
            );
            assert!(upto < 4 || report.refined, "{name}: not refined");
        }
        g.throughput(Throughput::Elements(states.pixels.len() as u64));
        g.bench_function(name, |bench| {
            bench.iter_batched(
                || (solver.clone(), states.clone()),
                |(mut s, mut st): (SweepSolver, ShardState)| {
                    let report = s.end_angle_all(&mut [st.shard(0, w)]);
                    (report, s, st)
                },
                BatchSize::LargeInput,
            );
        });
        if upto == 4 {
            // The three phases apart (each on its own: the earlier ones run in the setup).
            let phases: [(&str, usize); 3] = [
                ("end_tally_50deg_6144px", 0),
                ("end_sums_50deg_6144px", 1),
                ("end_update_50deg_6144px", 2),
            ];
            for (phase, k) in phases {
                bench_phase(&mut g, phase, &prep.before_end, k);
            }
            // As on a large sensor, one pixel in 4 keeps the index's sums and walks more than
            // the others (in 16 as on a 1 Mpix sensor, the 384 pixels' first index moved
            // enough at 50 degrees that every pixel chose its order again).
            let sampled = Prepared::new(upto, 4);
            g.throughput(Throughput::Elements(states.pixels.len() as u64));
            for (phase, k) in [
                ("end_tally_50deg_6144px_1in4", 0),
                ("end_sums_50deg_6144px_1in4", 1),
                ("end_update_50deg_6144px_1in4", 2),
            ] {
                bench_phase(&mut g, phase, &sampled.before_end, k);
            }
            // The worker's per-sample path at a refining angle: tracker push plus the
            // Gauss-Newton sums, through `Shard::feed_row`.
            let states = &prep.before_rows.1;
            let mut check = states.clone();
            prep.feed(&mut check);
            let shard = check.shard(0, w);
            let refined = (0..shard.pixels.len())
                .filter(|&i| shard.fit(i).gn.samples > 0)
                .count();
            assert!(refined * 2 > shard.pixels.len(), "the feed does not refine");
            g.throughput(Throughput::Elements(prep.rows.len() as u64));
            // About 0.3 s an iteration: 10 flat samples.
            g.sample_size(10)
                .sampling_mode(SamplingMode::Flat)
                .measurement_time(Duration::from_secs(4));
            g.bench_function("feed_row_50deg_6144px_x_151b", |bench| {
                bench.iter_batched(
                    || states.clone(),
                    |mut st| {
                        prep.feed(&mut st);
                        st
                    },
                    BatchSize::LargeInput,
                );
            });
        }
    }
    g.finish();
}

/// The group `criterion_main!` runs (in a private module: the macro's `pub fn` has no doc).
mod group {
    use super::{bench_calibrate, bench_refine, bench_solve, bench_tracker};

    criterion::criterion_group!(
        kernels,
        bench_tracker,
        bench_refine,
        bench_calibrate,
        bench_solve
    );
}

criterion_main!(group::kernels);
