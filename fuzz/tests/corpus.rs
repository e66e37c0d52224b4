//! The seeded corpus of every fuzz target, and seeded random mutations of it, run as a normal
//! test: no input may panic (an error is a fine answer). The long fuzzing runs use the same
//! targets through `cargo fuzz` (fuzz/README.md); inputs they found are added to the corpus.

use std::path::Path;

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use slam_fuzz::{SEPARATOR, Target};

/// Mutations of each seed per target.
const MUTATIONS: usize = 40;

/// Values that break numbers: huge, tiny, negative, not finite, not numbers.
const ODD_VALUES: [&str; 14] = [
    "1e300",
    "-1e300",
    "1e-320",
    "-0",
    "0",
    "nan",
    "inf",
    "-inf",
    "99999999999999999999",
    "-1",
    "4294967296",
    "18446744073709551616",
    "x",
    "",
];

/// The corpus files of `target`.
fn seeds(target: Target) -> Vec<Vec<u8>> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("corpus")
        .join(target.name());
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    files.iter().map(|f| std::fs::read(f).unwrap()).collect()
}

/// One random change of `data`: a byte flipped, inserted or removed, a number replaced by an
/// odd value, a line doubled or dropped, a separator inserted, or a chunk cut.
fn mutate(data: &mut Vec<u8>, rng: &mut ChaCha8Rng) {
    let at = |rng: &mut ChaCha8Rng, len: usize| rng.random_range(0..len.max(1));
    match rng.random_range(0..8) {
        0 if !data.is_empty() => {
            let i = at(rng, data.len());
            data[i] ^= 1 << rng.random_range(0..8);
        }
        1 => {
            let i = at(rng, data.len() + 1).min(data.len());
            data.insert(i, rng.random());
        }
        2 if !data.is_empty() => {
            let i = at(rng, data.len());
            data.remove(i);
        }
        3 => replace_number(data, rng),
        4 => {
            let lines: Vec<&[u8]> = data.split(|b| *b == b'\n').collect();
            let k = at(rng, lines.len());
            let mut out = Vec::new();
            for (i, line) in lines.iter().enumerate() {
                let copies = if i == k { rng.random_range(0..3) } else { 1 };
                for _ in 0..copies {
                    out.extend_from_slice(line);
                    out.push(b'\n');
                }
            }
            *data = out;
        }
        5 => {
            let i = at(rng, data.len() + 1).min(data.len());
            data.splice(i..i, SEPARATOR.iter().copied());
        }
        6 if data.len() > 1 => {
            let i = at(rng, data.len());
            let j = (i + rng.random_range(1..64)).min(data.len());
            data.drain(i..j);
        }
        _ => replace_number(data, rng),
    }
}

/// Replaces a run of digits (with its sign, point and exponent) by one of [`ODD_VALUES`].
fn replace_number(data: &mut Vec<u8>, rng: &mut ChaCha8Rng) {
    let starts: Vec<usize> = (0..data.len())
        .filter(|&i| data[i].is_ascii_digit() && (i == 0 || !data[i - 1].is_ascii_digit()))
        .collect();
    if starts.is_empty() {
        return;
    }
    let start = starts[rng.random_range(0..starts.len())];
    let number = |b: u8| b.is_ascii_digit() || matches!(b, b'.' | b'e' | b'E' | b'-' | b'+');
    let end = (start..data.len())
        .find(|&i| !number(data[i]))
        .unwrap_or(data.len());
    let value = ODD_VALUES[rng.random_range(0..ODD_VALUES.len())];
    data.splice(start..end, value.bytes());
}

fn run_target(target: Target) {
    let seeds = seeds(target);
    assert!(!seeds.is_empty(), "{}: empty corpus", target.name());
    let accepted = seeds.iter().filter(|s| target.run(s)).count();
    // The corpus holds valid inputs besides odd ones: the target is not just failing early.
    assert!(accepted > 0, "{}: no seed is accepted", target.name());
    let mut rng = ChaCha8Rng::seed_from_u64(20);
    for seed in &seeds {
        let mut data = seed.clone();
        for _ in 0..MUTATIONS {
            mutate(&mut data, &mut rng);
            let input = data.clone();
            let outcome = std::panic::catch_unwind(|| target.run(&input));
            if outcome.is_err() {
                let file = std::env::temp_dir().join(format!("slam-fuzz-crash-{}", target.name()));
                let _ = std::fs::write(&file, &input);
                panic!(
                    "{}: a mutated input panicked; kept in {}",
                    target.name(),
                    file.display()
                );
            }
            // Now and then start again from the seed, so that mutations stay near valid input.
            if rng.random_range(0..4) == 0 {
                data = seed.clone();
            }
        }
    }
}

#[test]
fn rb2d_corpus() {
    run_target(Target::Rb2d);
}

#[test]
fn carmen_corpus() {
    run_target(Target::Carmen);
}

#[test]
fn mcap_corpus() {
    run_target(Target::Mcap);
}

#[test]
fn victoria_park_corpus() {
    run_target(Target::VictoriaPark);
}

#[test]
fn mrclam_corpus() {
    run_target(Target::Mrclam);
}

#[test]
fn tum_corpus() {
    run_target(Target::Tum);
}

#[test]
fn world_corpus() {
    run_target(Target::World);
}

#[test]
fn config_corpus() {
    run_target(Target::Config);
}

#[test]
fn priorlet_corpus() {
    run_target(Target::Priorlet);
}

#[test]
fn every_target_has_a_test_and_a_cargo_fuzz_target() {
    let targets = Path::new(env!("CARGO_MANIFEST_DIR")).join("targets/fuzz_targets");
    for target in Target::ALL {
        let file = targets.join(format!("{}.rs", target.name()));
        assert!(file.is_file(), "{} is missing", file.display());
    }
}
