//! # slam-fuzz
//!
//! The fuzz harness of the project: every dataset reader, the run configuration, the world
//! description and the priorlet parser, each fed arbitrary bytes through its public API. A
//! target passes when it returns (an error is a fine answer to bad input); a panic, a hang or
//! an allocation without bound is a bug.
//!
//! The same [`Target::run`] is called by the `cargo fuzz` targets in `fuzz/targets/` (nightly,
//! libFuzzer) and by `cargo test -p slam-fuzz`, which runs the seeded corpus of
//! `fuzz/corpus/<target>/` and a few thousand seeded mutations of it. See `fuzz/README.md`.
//!
//! Readers that take a folder (Victoria Park, MR.CLAM) get their files from one input split
//! at lines `----` ([`SEPARATOR`]), in the order of [`Target::files`].

#![warn(missing_docs)]

use std::cell::RefCell;
use std::path::{Path, PathBuf};

use slam_runtime::{Config, Start};
use slam_sensors::data::{
    CarmenOptions, McapOptions, MrclamOptions, VictoriaParkOptions, read_tum, stream_carmen,
    stream_mcap, stream_mrclam, stream_rb2d, stream_victoria_park,
};
use slam_sensors::{EventStream, sim::World};

/// Links the example crate, whose registrations the config may name.
use slam_examples as _;

/// At most this many events of a stream are read (the readers stream: a longer input is not
/// a different case).
pub const MAX_EVENTS: usize = 5_000;

/// At most this many events of a simulated world are generated (a step may be costly).
pub const MAX_SIMULATED_EVENTS: usize = 40;

/// The line that separates the files of a multi-file input.
pub const SEPARATOR: &[u8] = b"\n----\n";

/// One fuzz target.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Target {
    /// `stream_rb2d`.
    Rb2d,
    /// `stream_carmen`.
    Carmen,
    /// `stream_mcap` (a ROS 2 bag; reference poses on `/reference_pose`).
    Mcap,
    /// `stream_victoria_park` (four files).
    VictoriaPark,
    /// `stream_mrclam` (four files).
    Mrclam,
    /// `read_tum`.
    Tum,
    /// `World::from_toml`, then a few simulated steps.
    World,
    /// `Config::from_toml`, `validate`, and building the estimator, front-end and stages.
    Config,
    /// `slam_priors::parse_prior` (parse and compile a priorlet file).
    Priorlet,
}

impl Target {
    /// Every target.
    pub const ALL: [Target; 9] = [
        Target::Rb2d,
        Target::Carmen,
        Target::Mcap,
        Target::VictoriaPark,
        Target::Mrclam,
        Target::Tum,
        Target::World,
        Target::Config,
        Target::Priorlet,
    ];

    /// The target's name (its corpus folder and its `cargo fuzz` target).
    pub fn name(self) -> &'static str {
        match self {
            Target::Rb2d => "rb2d",
            Target::Carmen => "carmen",
            Target::Mcap => "mcap",
            Target::VictoriaPark => "victoria_park",
            Target::Mrclam => "mrclam",
            Target::Tum => "tum",
            Target::World => "world",
            Target::Config => "config",
            Target::Priorlet => "priorlet",
        }
    }

    /// The file names an input is written to (split at [`SEPARATOR`] for several).
    pub fn files(self) -> &'static [&'static str] {
        match self {
            Target::Rb2d => &["log.rb2d"],
            Target::Carmen => &["log.carmen"],
            Target::Mcap => &["bag.mcap"],
            Target::VictoriaPark => &[
                "odometry.csv",
                "laser_frame_times.csv",
                "tree_detections.csv",
                "gps.csv",
            ],
            Target::Mrclam => &[
                "Barcodes.dat",
                "Landmark_Groundtruth.dat",
                "Robot1_Odometry.dat",
                "Robot1_Measurement.dat",
            ],
            Target::Tum => &["trajectory.tum"],
            Target::World | Target::Config | Target::Priorlet => &[],
        }
    }

    /// Runs the target on `data`. Returns whether the input was accepted (`false`: an error,
    /// which is a fine answer); panics only on a bug.
    pub fn run(self, data: &[u8]) -> bool {
        match self {
            Target::World => world(data),
            Target::Config => config(data),
            Target::Priorlet => {
                slam_priors::parse_prior(&String::from_utf8_lossy(data), "fuzz").is_ok()
            }
            _ => with_files(self, data, |dir| read(self, dir)),
        }
    }
}

thread_local! {
    /// One folder per thread for the files of the inputs.
    static FOLDER: RefCell<Option<tempfile::TempDir>> = const { RefCell::new(None) };
}

/// Writes `data` as the target's files into this thread's folder and calls `read` on it.
fn with_files(target: Target, data: &[u8], read: impl FnOnce(&Path) -> bool) -> bool {
    FOLDER.with(|folder| {
        let mut folder = folder.borrow_mut();
        if folder.is_none() {
            *folder = tempfile::Builder::new().prefix("slam-fuzz-").tempdir().ok();
        }
        let Some(dir) = folder.as_ref().map(|d| d.path().to_path_buf()) else {
            return false;
        };
        let names = target.files();
        let mut parts = split(data, names.len());
        for name in names {
            let part = parts.next().unwrap_or_default();
            if std::fs::write(dir.join(name), part).is_err() {
                return false;
            }
        }
        read(&dir)
    })
}

/// `data` in `n` parts at the first `n - 1` separators (missing parts are empty).
fn split(data: &[u8], n: usize) -> impl Iterator<Item = &[u8]> {
    let mut rest = Some(data);
    (0..n).map(move |k| {
        let Some(text) = rest else {
            return &[][..];
        };
        if k + 1 == n {
            rest = None;
            return text;
        }
        match text.windows(SEPARATOR.len()).position(|w| w == SEPARATOR) {
            Some(at) => {
                rest = Some(&text[at + SEPARATOR.len()..]);
                &text[..at]
            }
            None => {
                rest = None;
                text
            }
        }
    })
}

/// Opens the reader of `target` on the files in `dir` and reads its stream.
fn read(target: Target, dir: &Path) -> bool {
    let file = |name: &str| -> PathBuf { dir.join(name) };
    let stream = match target {
        Target::Rb2d => stream_rb2d(&file("log.rb2d")),
        Target::Carmen => stream_carmen(&file("log.carmen"), &CarmenOptions::default()),
        Target::Mcap => stream_mcap(
            &file("bag.mcap"),
            &McapOptions {
                reference_topic: "/reference_pose".into(),
                ..McapOptions::default()
            },
        ),
        Target::VictoriaPark => stream_victoria_park(dir, &VictoriaParkOptions::default()),
        Target::Mrclam => stream_mrclam(dir, 1, &MrclamOptions::default()),
        Target::Tum => return read_tum(&file("trajectory.tum")).is_ok(),
        _ => return false,
    };
    stream.is_ok_and(drain)
}

/// Reads up to [`MAX_EVENTS`] events; whether none was an error.
fn drain(stream: EventStream) -> bool {
    let mut ok = true;
    for event in stream.take(MAX_EVENTS) {
        ok &= event.is_ok();
    }
    ok
}

fn world(data: &[u8]) -> bool {
    let Ok(world) = World::from_toml(&String::from_utf8_lossy(data), "fuzz") else {
        return false;
    };
    match slam_sensors::sim::simulate_stream(&world, 1) {
        Ok(run) => run.events.take(MAX_SIMULATED_EVENTS).all(|e| e.is_ok()),
        Err(_) => false,
    }
}

fn config(data: &[u8]) -> bool {
    let Ok(config) = Config::from_toml(&String::from_utf8_lossy(data), "fuzz") else {
        return false;
    };
    if config.validate().is_err() || config.data.data_spec().is_err() {
        return false;
    }
    let start = Start {
        pose: slam_core::Pose2::identity(),
        covariance: slam_core::nalgebra::DMatrix::zeros(3, 3),
    };
    let built = config.estimator.build(&start).is_ok()
        && config.frontend.build(&Default::default()).is_ok();
    built && config.postprocess.iter().all(|stage| stage.build().is_ok())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inputs_split_into_files() {
        let parts: Vec<&[u8]> = split(b"a\n----\nb\n----\nc", 4).collect();
        assert_eq!(parts, [&b"a"[..], b"b", b"c", b""]);
        let parts: Vec<&[u8]> = split(b"a\n----\nb", 1).collect();
        assert_eq!(parts, [&b"a\n----\nb"[..]]);
    }
}
