//! `fuzz TARGET SECONDS [SEED]`: mutates `corpus/TARGET/*` for SECONDS seconds, saving
//! inputs that panic (or take over a second) to `crashes/TARGET-*.bin`; `fuzz list` names the
//! targets. Prints one line of figures at the end; exits 1 if anything crashed.

use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use filmscope_fuzz::{mutate, run_caught, target, Rng, TARGETS};

const MAX_LEN: usize = 4096;
const POOL: usize = 512;
const SLOW: Duration = Duration::from_secs(1);

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.first().map(String::as_str) == Some("list") {
        for t in TARGETS {
            println!("{}", t.name);
        }
        return;
    }
    let (Some(name), Some(secs)) = (
        args.first(),
        args.get(1).and_then(|s| s.parse::<f64>().ok()),
    ) else {
        eprintln!("usage: fuzz TARGET SECONDS [SEED] | fuzz list");
        std::process::exit(2);
    };
    let seed = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(1);
    let Some(t) = target(name) else {
        eprintln!("fuzz: unknown target `{name}` (try `fuzz list`)");
        std::process::exit(2);
    };
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut pool = read_dir(&root.join("corpus").join(name));
    if pool.is_empty() {
        pool.push(Vec::new());
    }
    let seeds = pool.len();
    let crashes_dir = root.join("crashes");
    std::panic::set_hook(Box::new(|_| {}));
    let mut rng = Rng::new(seed);
    let mut seen = HashSet::new();
    let (mut cases, mut crashes, mut accepted, mut slow) = (0u64, 0u64, 0u64, 0u64);
    let start = Instant::now();
    let deadline = start + Duration::from_secs_f64(secs.max(0.0));
    while Instant::now() < deadline {
        for _ in 0..64 {
            let a = rng.below(pool.len());
            let b = rng.below(pool.len());
            let input = mutate(&mut rng, &pool[a], &pool[b], t.dict, MAX_LEN);
            let t0 = Instant::now();
            let result = run_caught(t, &input);
            let took = t0.elapsed();
            cases += 1;
            match result {
                Ok(ok) => {
                    if took > SLOW {
                        slow += 1;
                        save(&crashes_dir, name, "slow", &input);
                    }
                    if ok {
                        accepted += 1;
                        if pool.len() < POOL {
                            pool.push(input);
                        } else {
                            let i = seeds + rng.below(POOL - seeds);
                            pool[i] = input;
                        }
                    }
                }
                Err(msg) => {
                    crashes += 1;
                    // One file per distinct panic (the message's first 24 characters, digits dropped).
                    let key: String = msg
                        .chars()
                        .filter(|c| !c.is_ascii_digit())
                        .take(24)
                        .collect();
                    if seen.insert(key) {
                        let path = save(&crashes_dir, name, "crash", &input);
                        eprintln!("{name}: crash saved to {}: {msg}", path.display());
                    }
                }
            }
        }
    }
    // The envi_file target's scratch folder.
    let _ = std::fs::remove_dir_all(
        std::env::temp_dir().join(format!("filmscope-fuzz-{}", std::process::id())),
    );
    let elapsed = start.elapsed().as_secs_f64();
    println!(
        "{name}: {cases} cases in {elapsed:.0} s ({:.0}/s), {accepted} accepted, {crashes} crashing ({} distinct), {slow} slow, seed {seed}",
        cases as f64 / elapsed.max(1e-9),
        seen.len()
    );
    if crashes > 0 || slow > 0 {
        std::process::exit(1);
    }
}

fn read_dir(dir: &Path) -> Vec<Vec<u8>> {
    let mut paths: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|d| d.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    paths.sort();
    paths.iter().filter_map(|p| std::fs::read(p).ok()).collect()
}

fn save(dir: &Path, name: &str, what: &str, input: &[u8]) -> PathBuf {
    let hash = input.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    });
    let path = dir.join(format!("{name}-{what}-{hash:016x}.bin"));
    let _ = std::fs::create_dir_all(dir);
    let _ = std::fs::write(&path, input);
    path
}
