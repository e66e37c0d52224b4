//! The streaming readers, simulator and adapters give exactly the events of the in-memory
//! versions they replaced: fingerprints of every event (its time's bits and its `Debug`
//! rendering) equal those taken with the in-memory code before the rewrite, on small inputs
//! and, when the real datasets are present (DATASETS.md), on the real data. Also: streams yield their
//! first events before a malformed line further down, and report it as an `Err` item.
//!
//! The CARMEN fingerprints of logs with usable logger timestamps were taken again when event
//! times became those stamps (instead of line numbers): without the times and the clock, the
//! fingerprints of every input, and laser odometry's, were checked equal before and after.

use std::io::Write;
use std::path::{Path, PathBuf};

use slam_sensors::data::{
    CarmenOptions, MrclamOptions, NO_RETURN_BAND, PoseOdometryParams, VictoriaParkOptions,
    odometry_from_poses, read_carmen, read_mrclam, read_rb2d, read_victoria_park, stream_carmen,
    stream_mrclam, stream_rb2d, stream_victoria_park,
};
use slam_sensors::laser_odometry::{
    LaserOdometryParams, LaserOdometryReport, laser_odometry, laser_odometry_stream,
};
use slam_sensors::sim::{World, simulate, simulate_stream};
use slam_sensors::{Dataset, Event, EventStream, SkipCounter, TimedEvent};

/// FNV-1a, 64 bits: a hash that does not change between Rust versions.
fn fnv(hash: &mut u64, bytes: &[u8]) {
    for b in bytes {
        *hash ^= u64::from(*b);
        *hash = hash.wrapping_mul(0x0000_0100_0000_01b3);
    }
}

/// The line of one event in a fingerprint.
fn render(e: &TimedEvent) -> String {
    format!("{:016x} {:?}\n", e.time.to_bits(), e.event)
}

/// `"<events> <hash>"` over the name, clock, landmarks, every event and the skip counts.
fn fingerprint(d: &Dataset) -> String {
    let mut h = 0xcbf2_9ce4_8422_2325_u64;
    fnv(
        &mut h,
        format!("{:?} {:?} {:?}\n", d.name, d.clock, d.landmarks).as_bytes(),
    );
    for e in &d.events {
        fnv(&mut h, render(e).as_bytes());
    }
    fnv(&mut h, format!("{:?}", d.skipped).as_bytes());
    format!("{} {:016x}", d.events.len(), h)
}

/// [`fingerprint`] of a stream, consumed one event at a time (never collected).
fn stream_fingerprint(mut stream: EventStream) -> String {
    let info = stream.info.clone();
    let mut h = 0xcbf2_9ce4_8422_2325_u64;
    fnv(
        &mut h,
        format!("{:?} {:?} {:?}\n", info.name, info.clock, info.landmarks).as_bytes(),
    );
    let mut n = 0;
    for e in stream.by_ref() {
        fnv(&mut h, render(&e.unwrap()).as_bytes());
        n += 1;
    }
    fnv(&mut h, format!("{:?}", stream.skipped()).as_bytes());
    format!("{n} {h:016x}")
}

/// The real datasets folder (DATASETS.md, `SLAM_DATA_DIR`). Tests that read it carry
/// `cfg_attr(not(slam_data), ignore)`: sensors/build.rs finds the folder.
fn datasets() -> PathBuf {
    PathBuf::from(option_env!("SLAM_DATA").unwrap_or("the real datasets are absent"))
}

/// Which reader, on what.
enum Input {
    Carmen(PathBuf, CarmenOptions),
    Rb2d(PathBuf),
    VictoriaPark(PathBuf),
    Mrclam(PathBuf, u8),
}

fn read(input: &Input) -> slam_sensors::Result<Dataset> {
    match input {
        Input::Carmen(path, options) => read_carmen(path, options),
        Input::Rb2d(path) => read_rb2d(path),
        Input::VictoriaPark(dir) => read_victoria_park(dir, &pinned_victoria_park()),
        Input::Mrclam(dir, robot) => read_mrclam(dir, *robot, &MrclamOptions::default()),
    }
}

/// The Victoria Park options the fingerprints were taken with (the reader's defaults until
/// the range and radius deviations became 0.5 m and 0.15 m), so that a change of the defaults
/// does not change them.
fn pinned_victoria_park() -> VictoriaParkOptions {
    VictoriaParkOptions {
        sigma_range: 0.2,
        sigma_radius: 0.05,
        ..VictoriaParkOptions::default()
    }
}

fn stream(input: &Input) -> slam_sensors::Result<EventStream> {
    match input {
        Input::Carmen(path, options) => stream_carmen(path, options),
        Input::Rb2d(path) => stream_rb2d(path),
        Input::VictoriaPark(dir) => stream_victoria_park(dir, &pinned_victoria_park()),
        Input::Mrclam(dir, robot) => stream_mrclam(dir, *robot, &MrclamOptions::default()),
    }
}

/// Checks the stream and the collected reader against the fingerprint of the in-memory
/// reader.
fn check(label: &str, input: &Input, expected: &str) {
    assert_eq!(
        stream_fingerprint(stream(input).unwrap()),
        expected,
        "{label}: streamed"
    );
    assert_eq!(
        fingerprint(&read(input).unwrap()),
        expected,
        "{label}: collected"
    );
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

/// Small inputs (those of the unit tests, doctests and `readers.rs`, and a few more) written
/// into `dir`, with their labels.
fn small_inputs(dir: &Path) -> Vec<(&'static str, Input)> {
    use slam_sensors::data::carmen::write_carmen;
    use slam_sensors::data::rb2d::write_rb2d;
    let defaults = CarmenOptions::default;
    let carmen_doc = "# a comment\n\
        ODOM 0 0 0 0 0 0 1.0 host 1.0\n\
        FLASER 3 1.0 2.0 5.0 0.1 0 0 0.1 0 0 1.5 host 1.5\n\
        ODOM 0.1 0 0 0 0 0 2.0 host 2.0\n";
    let mounts = "RLASER 2 1.0 2.0 1 2 0.5 1 2 0.5 0 h 0\n\
        ROBOTLASER1 0 -1.5 3.0 0.5 30 0.01 0 3 1 2 3 0 2 1 0.5 1 0 0 0 0 0 0 0 0 h 0\n";
    let mixed = "PARAM robot x\n\nNEFF 3\nFLASER 3 1.0 7.5 2.0 0 0 0 0 0 0 0 h 0\r\n\
        ODOM 0 0 0 0 0 0 0 h 0\nSYNC\nODOM 0.5 0.1 0.2 0 0 0 0 h 0\n\
        ROBOTLASER1 0 -1.5 3.0 0.5 0 0.01 0 3 1 9 3 0 2 1 0.5 1 0 0 0 0 0 0 0 0 h 0\n\
        RLASER 2 1.0 2.0 1 2 0.5 1 2 0.5 0 h 0\n# end";
    let gz = dir.join("mixed.log.gz");
    {
        use std::io::Write;
        let mut encoder = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        encoder.write_all(mixed.as_bytes()).unwrap();
        std::fs::write(&gz, encoder.finish().unwrap()).unwrap();
    }
    let mut world = World::default_world();
    world.robot.waypoints.truncate(1);
    world.camera = None;
    let run = simulate(&world, 2).unwrap();
    let simulated_carmen = dir.join("sim.log");
    write_carmen(
        &simulated_carmen,
        &run.dataset,
        &slam_core::Pose2::identity(),
        "sim",
    )
    .unwrap();

    let rb2d_doc = "# a tiny log\n\
        PARAM dt 0.1\nPARAM sigma_v 0.05\nPARAM sigma_w 0.01\nPARAM sigma_r 0.1\nPARAM sigma_b 0.02\n\
        LM 3 5.0 0.0\n\
        OBS 0 3 5.0 0.0\n\
        ODOM 1 0.1 0.1 0.0 0.0\n\
        OBS 1 3 4.9 0.0\nOBS 1 -1 7.0 1.0\n\
        GT 1 0.1 0.0 0.0\n";
    let rb2d_header = "# test log\nPARAM dt 0.1\nPARAM sigma_v 0.05\nPARAM sigma_w 0.02\n\
        PARAM sigma_r 0.1\nPARAM sigma_b 0.01\nPARAM max_range 10\n";
    let rb2d_body = "LM 0 3.0 0.0\nLM 1 0.0 3.0\n\
        OBS 0 0 3.0 0.0\nGT 0 0 0 0\n\
        ODOM 1 0.1 0.1 0.0 0.05\nOBS 1 0 2.9 0.0\nOBS 1 -1 3.0 1.6\nGT 1 0.1 0.0 0.05\n\
        ODOM 2 0.1 0.1 0.01 0.0\n\
        ODOM 3 0.1 0.1 0.0 0.0\nOBS 3 1 2.8 1.5\n";
    // Landmarks after the records, and observations at the very end.
    let rb2d_late = "PARAM dt 0.5\nPARAM sigma_v 0\nPARAM sigma_w 0.1\nPARAM sigma_r 0.2\n\
        PARAM sigma_b 0.05\nOBS 0 7 1.0 0.5\n# c\nODOM 1 0.5 0.2 0 0.1\nGT 1 0.2 0 0.1\n\
        LM 7 1.0 0.4\nODOM 2 0.5 0.2 0 0.1\nOBS 2 7 0.9 0.3\nOBS 2 8 2.0 -0.3\nLM 8 2.0 -1.0\n";
    let circle =
        World::from_file(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../worlds/rb2d-circle.toml"))
            .unwrap();
    let run = simulate(&circle, 7).unwrap();
    let circle_rb2d = dir.join("circle.rb2d");
    write_rb2d(&circle_rb2d, &run.dataset, &circle.rb2d_params(), "circle").unwrap();

    let vp = |name: &str, files: [(&str, &str); 4], converted: bool| -> PathBuf {
        let root = dir.join(name);
        let folder = if converted {
            root.join("converted")
        } else {
            root.clone()
        };
        std::fs::create_dir_all(&folder).unwrap();
        for (file, text) in files {
            write(&folder, file, text);
        }
        root
    };
    let vp_unit = vp(
        "vp-unit",
        [
            (
                "odometry.csv",
                "time_ms,speed_mps,steering_rad\n1000,2.0,0.0\n2000,2.0,0.1\n3000,0.0,0.0\n",
            ),
            ("laser_frame_times.csv", "frame,time_s\n0,1.5\n1,2.0\n"),
            (
                "tree_detections.csv",
                "frame,time_s,range_m,bearing_rad,diameter_m\n0,1.5,10.0,1.5707963267948966,0.4\n",
            ),
            ("gps.csv", "time_ms,Lo_m,La_m\n500,1.0,2.0\n"),
        ],
        true,
    );
    let vp_readers = vp(
        "vp-readers",
        [
            (
                "odometry.csv",
                "time_ms,speed_mps,steering_rad\n1000,1.0,0.0\n2000,1.0,0.0\n",
            ),
            ("laser_frame_times.csv", "frame,time_s\n0,1.5\n"),
            (
                "tree_detections.csv",
                "frame,time_s,range_m,bearing_rad,diameter_m\n0,1.5,5.0,1.0,0.3\n",
            ),
            ("gps.csv", "time_ms,Lo_m,La_m\n1000,0.0,0.0\n"),
        ],
        false,
    );
    // Ties between frames, GPS fixes and odometry times; points before the first and after
    // the last interval; several detections per frame; a frame without detections; a BOM.
    let vp_ties = vp(
        "vp-ties",
        [
            (
                "odometry.csv",
                "\u{feff}time_ms,speed_mps,steering_rad\n1000,1.0,0.0\n1000,1.5,0.1\n\n\
                 2000,1.0,-0.1\n3000,2.0,0.05\n3500,0.0,0.0\n",
            ),
            (
                "laser_frame_times.csv",
                "frame,time_s\n0,0.5\n1,1.0\n2,1.5\n3,1.5\n4,2.0\n5,2.75\n6,4.0\n",
            ),
            (
                "tree_detections.csv",
                "frame,time_s,range_m,bearing_rad,diameter_m\n0,0.5,5.0,1.0,0.3\n\
                 1,1.0,6.0,1.2,0.2\n1,1.0,7.0,2.2,0.25\n3,1.5,4.0,1.6,0.3\n\
                 4,2.0,3.0,0.6,0.1\n6,4.0,9.0,1.6,0.3\n6,4.0,9.5,1.7,0.31\n",
            ),
            (
                "gps.csv",
                "time_ms,Lo_m,La_m\n500,1.0,2.0\n1500,1.5,2.5\n1500,1.6,2.6\n2500,2.0,3.0\n\
                 3500,3.0,4.0\n5000,5.0,6.0\n",
            ),
        ],
        true,
    );

    let header = "# UTIAS\n# produced by\n# Format:\n# columns\n";
    let mrclam = |name: &str, files: [(&str, &str); 4]| -> PathBuf {
        let root = dir.join(name);
        std::fs::create_dir_all(&root).unwrap();
        for (file, body) in files {
            write(&root, file, &format!("{header}{body}"));
        }
        root
    };
    let mrclam_unit = mrclam(
        "mrclam-unit",
        [
            (
                "Barcodes.dat",
                "  1 \t   5 \n  2 \t  14 \n  6 \t  72 \n  7 \t  27 \n 30 \t 44 \n",
            ),
            (
                "Landmark_Groundtruth.dat",
                "  6 \t 5.7 \t 4.9 \t 0.0002 \t 0.0004 \n  7 \t 5.2 \t 5.5 \t 0.0001 \t 0.0003 \n",
            ),
            (
                "Robot1_Odometry.dat",
                "10.000 \t 0.1 \t 0.0 \n10.500 \t 0.2 \t 0.1 \n11.000 \t 0.0 \t 0.0 \n",
            ),
            (
                "Robot1_Measurement.dat",
                "9.5 \t 72 \t 2.0 \t 0.1 \n10.250 \t 72 \t 2.0 \t 0.1 \n10.250 \t 27 \t 3.0 \t -0.1 \n\
                 10.250 \t 14 \t 1.0 \t 0.0 \n10.500 \t 99 \t 1.0 \t 0.0 \n10.500 \t 44 \t 1.0 \t 0.0 \n\
                 10.750 \t 5 \t 1.0 \t 0.0 \n10.750 \t 27 \t 3.0 \t 0.2 \n11.0 \t 27 \t 3.0 \t 0.2 \n\
                 12.0 \t 72 \t 3.0 \t 0.2 \n",
            ),
        ],
    );
    let mrclam_readers = mrclam(
        "mrclam-readers",
        [
            ("Barcodes.dat", "1 5\n6 72\n"),
            ("Landmark_Groundtruth.dat", "6 1.0 2.0 0.001 0.001\n"),
            ("Robot1_Odometry.dat", "10.0 0.1 0.0\n10.5 0.1 0.0\n"),
            ("Robot1_Measurement.dat", "10.2 72 2.0 0.1\n"),
        ],
    );

    let with_max = CarmenOptions {
        max_range: Some(2.5),
        ..defaults()
    };
    vec![
        (
            "carmen doc",
            Input::Carmen(write(dir, "doc.log", carmen_doc), defaults()),
        ),
        (
            "carmen mounts",
            Input::Carmen(write(dir, "mounts.log", mounts), defaults()),
        ),
        (
            "carmen mixed",
            Input::Carmen(write(dir, "mixed.log", mixed), defaults()),
        ),
        (
            "carmen mixed max",
            Input::Carmen(dir.join("mixed.log"), with_max),
        ),
        ("carmen gzip", Input::Carmen(gz, defaults())),
        (
            "carmen simulated",
            Input::Carmen(simulated_carmen, defaults()),
        ),
        ("rb2d doc", Input::Rb2d(write(dir, "doc.rb2d", rb2d_doc))),
        (
            "rb2d readers",
            Input::Rb2d(write(
                dir,
                "readers.rb2d",
                &format!("{rb2d_header}{rb2d_body}"),
            )),
        ),
        ("rb2d late", Input::Rb2d(write(dir, "late.rb2d", rb2d_late))),
        ("rb2d circle", Input::Rb2d(circle_rb2d)),
        ("vp unit", Input::VictoriaPark(vp_unit)),
        ("vp readers", Input::VictoriaPark(vp_readers)),
        ("vp ties", Input::VictoriaPark(vp_ties)),
        ("mrclam unit", Input::Mrclam(mrclam_unit, 1)),
        ("mrclam readers", Input::Mrclam(mrclam_readers, 1)),
    ]
}

/// Fingerprints of the in-memory readers (before streaming) on [`small_inputs`].
const SMALL: [(&str, &str); 15] = [
    ("carmen doc", "3 aa32acaede20b0e9"),
    ("carmen mounts", "4 0b8ce924538f683b"),
    ("carmen mixed", "7 61c4c9d7b896a56f"),
    ("carmen mixed max", "7 808bb6cdb3e83df2"),
    ("carmen gzip", "7 12525c1af66fc560"),
    ("carmen simulated", "1155 2044abbbde28f667"),
    ("rb2d doc", "4 c83dad1e23032894"),
    ("rb2d readers", "8 7bce0d3c4db6a1f8"),
    ("rb2d late", "5 1f514598094eb87a"),
    ("rb2d circle", "3002 7e7cdd3b540d7d7f"),
    ("vp unit", "6 895209b5299ecab4"),
    ("vp readers", "4 910606c8a28bb55f"),
    ("vp ties", "20 d9596c4007600a2a"),
    ("mrclam unit", "9 70bf1bb06af59997"),
    ("mrclam readers", "3 c8b81ebce807d804"),
];

#[test]
fn small_inputs_stream_the_events_of_the_in_memory_readers() {
    let dir = tempfile::tempdir().unwrap();
    let inputs = small_inputs(dir.path());
    assert_eq!(inputs.len(), SMALL.len());
    for ((label, input), (expected_label, expected)) in inputs.iter().zip(SMALL) {
        assert_eq!(*label, expected_label);
        check(label, input, expected);
    }
}

#[test]
#[cfg_attr(
    not(slam_data),
    ignore = "needs the real datasets (DATASETS.md, SLAM_DATA_DIR)"
)]
fn real_data_streams_the_events_of_the_in_memory_readers() {
    let root = datasets();
    let carmen = root.join("radish-carmen-corrected");
    let cases = [
        ("intel-corrected.log.gz", "15450 05627d6f963939cf"),
        ("acapulco-corrected.log.gz", "13002 5bf9354587289c8c"),
        ("fhw-corrected.log.gz", "14422 3945fbd51f609c4a"),
        ("freiburg-079-corrected.log.gz", "14518 3dfc3afde29ad818"),
    ];
    for (file, expected) in cases {
        check(
            file,
            &Input::Carmen(carmen.join(file), CarmenOptions::default()),
            expected,
        );
    }
    let vp = Input::VictoriaPark(root.join("victoria-park"));
    check("Victoria Park", &vp, "84893 e2be6091822f2eb9");
    let mrclam = root.join("utias-mrclam1");
    let robots = [
        (1, "104700 85647e4741c11842"),
        (2, "102666 8459a5b79bc6dbb0"),
        (3, "106392 8bfec6caed15320b"),
    ];
    for (robot, expected) in robots {
        check(
            &format!("MR.CLAM {robot}"),
            &Input::Mrclam(mrclam.clone(), robot),
            expected,
        );
    }
}

/// The default world to its first waypoint.
fn short_world() -> World {
    let mut world = World::default_world();
    world.robot.waypoints.truncate(1);
    world
}

#[test]
fn the_simulation_streams_the_events_of_the_in_memory_simulator() {
    // Seed 1, the camera on: the fingerprint of the in-memory simulator.
    let run = simulate_stream(&short_world(), 1).unwrap();
    assert_eq!(run.trajectory.len(), 578);
    assert_eq!(stream_fingerprint(run.events), "1813 325c3e19e3a9c052");
}

#[test]
fn simulate_stream_equals_simulate() {
    let mut world = World::default_world();
    world.robot.waypoints.truncate(2);
    assert!(world.camera.is_some() && world.laser.is_some());
    let whole = simulate(&world, 3).unwrap();
    let streamed = simulate_stream(&world, 3).unwrap();
    assert_eq!(streamed.trajectory, whole.trajectory);
    assert_eq!(streamed.truth, whole.truth);
    assert_eq!(streamed.events.info.name, whole.dataset.name);
    assert_eq!(streamed.events.info.clock, whole.dataset.clock);
    assert_eq!(streamed.events.info.landmarks, whole.dataset.landmarks);
    let mut n = 0;
    let mut images = 0;
    for (a, b) in streamed.events.zip(&whole.dataset.events) {
        let a = a.unwrap();
        assert_eq!(render(&a), render(b), "event {n}");
        images += usize::from(matches!(a.event, Event::Image { .. }));
        n += 1;
    }
    assert_eq!(n, whole.dataset.events.len());
    assert!(images > 0);
}

/// The first `n` events of `make()`, as a stream with the skip counts of the whole input
/// (as the in-memory reference: the whole dataset, its events truncated).
fn first(make: &impl Fn() -> EventStream, n: usize) -> EventStream {
    let whole = make().into_dataset().unwrap().skipped;
    let stream = make();
    EventStream::new(stream.info.clone(), stream.take(n)).with_skipped(SkipCounter::new(whole))
}

/// Laser odometry on the first `n` events, streamed and collected, against the fingerprint
/// and report of the in-memory version.
fn check_laser_odometry(
    make: impl Fn() -> EventStream,
    n: usize,
    expected: &str,
    report: LaserOdometryReport,
) {
    let params = LaserOdometryParams::default();
    let (mut streamed, counts) = laser_odometry_stream(first(&make, n), &params).unwrap();
    // The counts grow while the stream is read.
    let total: usize = expected.split(' ').next().unwrap().parse().unwrap();
    let early: Vec<_> = streamed.by_ref().take(total / 2).collect();
    let during = counts.report();
    assert!(
        during.matched > 0 && during.matched < report.matched,
        "{during:?}"
    );
    let (info, skipped) = (streamed.info.clone(), streamed.skip_counter());
    let rest = EventStream::new(info, early.into_iter().chain(streamed)).with_skipped(skipped);
    assert_eq!(stream_fingerprint(rest), expected);
    assert_eq!(counts.report(), report);
    let dataset = first(&make, n).into_dataset().unwrap();
    let (collected, collected_report) = laser_odometry(dataset, &params).unwrap();
    assert_eq!(fingerprint(&collected), expected);
    assert_eq!(collected_report, report);
}

#[test]
fn laser_odometry_streams_the_events_of_the_in_memory_version() {
    let mut world = short_world();
    world.camera = None;
    check_laser_odometry(
        || simulate_stream(&world, 1).unwrap().events,
        300,
        "182 b4738ad0ba391339",
        LaserOdometryReport {
            matched: 59,
            retried: 0,
            ambiguous: 0,
            refused: 0,
            truth_between_scans: 59,
        },
    );
}

#[test]
#[cfg_attr(
    not(slam_data),
    ignore = "needs the real datasets (DATASETS.md, SLAM_DATA_DIR)"
)]
fn laser_odometry_streams_the_events_of_the_in_memory_version_on_the_intel_log() {
    let intel = datasets().join("radish-carmen-corrected/intel-corrected.log.gz");
    check_laser_odometry(
        || stream_carmen(&intel, &CarmenOptions::default()).unwrap(),
        2000,
        "662 dcade4aeb0a2d9a6",
        LaserOdometryReport {
            matched: 83,
            retried: 0,
            ambiguous: 0,
            refused: 11,
            truth_between_scans: 0,
        },
    );
}

/// The `slam` command's in-memory `odometry_from_poses` (cli/src/data.rs) before it moved
/// here as a stream adapter, kept as the reference.
fn reference_odometry_from_poses(
    dataset: Dataset,
    noise: &PoseOdometryParams,
    seed: u64,
) -> Result<Dataset, String> {
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};
    use slam_core::Pose2;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(0x0D0_0E7);
    let Dataset {
        name,
        events,
        clock,
        landmarks,
        skipped,
        ..
    } = dataset;
    let mut out = Vec::with_capacity(events.len());
    let mut previous: Option<Pose2> = None;
    let mut iter = events.into_iter().peekable();
    let mut motions = 0usize;
    while let Some(timed) = iter.next() {
        match &timed.event {
            Event::Motion(_) => continue,
            Event::Scan { .. } => {
                let pose = iter.peek().and_then(|next| match &next.event {
                    Event::GroundTruth { pose, .. } if next.time == timed.time => Some(*pose),
                    _ => None,
                });
                if let Some(pose) = pose {
                    if let Some(before) = previous {
                        let relative = before.inverse().compose(&pose);
                        let d = relative.translation().norm();
                        let a = relative.theta.abs();
                        let sigma_t = noise.translation_per_metre * d + noise.floor_translation;
                        let sigma_r = noise.rotation_per_radian * a
                            + noise.rotation_per_metre * d
                            + noise.floor_rotation;
                        let mut draw = || -> f64 { StandardNormal.sample(&mut rng) };
                        let noisy = Pose2::new(
                            relative.x + sigma_t * draw(),
                            relative.y + sigma_t * draw(),
                            relative.theta + sigma_r * draw(),
                        );
                        let cov = slam_core::nalgebra::Matrix3::from_diagonal(
                            &slam_core::nalgebra::Vector3::new(
                                sigma_t * sigma_t,
                                sigma_t * sigma_t,
                                sigma_r * sigma_r,
                            ),
                        );
                        let increment = slam_sensors::odometry::PoseIncrement::new(noisy, cov)
                            .map_err(|e| e.to_string())?;
                        out.push(TimedEvent {
                            time: timed.time,
                            event: Event::Motion(Box::new(increment)),
                        });
                        motions += 1;
                    }
                    previous = Some(pose);
                }
            }
            _ => {}
        }
        out.push(timed);
    }
    if motions == 0 {
        return Err(format!(
            "[data.odometry_from_poses]: {name} has no scan with a reference pose"
        ));
    }
    let mut dataset = Dataset::new(name, clock);
    dataset.events = out;
    dataset.landmarks = landmarks;
    dataset.skipped = skipped;
    Ok(dataset)
}

#[test]
fn odometry_from_poses_streams_the_events_of_the_cli_version() {
    let dir = tempfile::tempdir().unwrap();
    let mut paths = vec![];
    for (label, input) in small_inputs(dir.path()) {
        if let Input::Carmen(path, _) = input
            && ["carmen simulated", "carmen mixed"].contains(&label)
        {
            paths.push(path);
        }
    }
    if cfg!(slam_data) {
        paths.push(datasets().join("radish-carmen-corrected/fhw-corrected.log.gz"));
    }
    let tight = PoseOdometryParams {
        translation_per_metre: 0.1,
        floor_rotation: 0.01,
        ..PoseOdometryParams::default()
    };
    for path in &paths {
        for (params, seed) in [(PoseOdometryParams::default(), 0), (tight.clone(), 9)] {
            let options = CarmenOptions::default();
            let expected =
                reference_odometry_from_poses(read_carmen(path, &options).unwrap(), &params, seed)
                    .unwrap();
            let streamed =
                odometry_from_poses(stream_carmen(path, &options).unwrap(), &params, seed).unwrap();
            assert_eq!(
                stream_fingerprint(streamed),
                fingerprint(&expected),
                "{}",
                path.display()
            );
        }
    }
    // Invalid parameters, and a log without two scans with reference poses.
    let bad = PoseOdometryParams {
        floor_translation: 0.0,
        ..PoseOdometryParams::default()
    };
    let doc = dir.path().join("doc.log");
    let e = odometry_from_poses(
        stream_carmen(&doc, &CarmenOptions::default()).unwrap(),
        &bad,
        1,
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.ends_with("[data.odometry_from_poses]: deviations must be finite and >= 0, floors > 0"),
        "{e}"
    );
    let mut out = odometry_from_poses(
        stream_carmen(&doc, &CarmenOptions::default()).unwrap(),
        &PoseOdometryParams::default(),
        1,
    )
    .unwrap();
    assert!(matches!(
        out.next().unwrap().unwrap().event,
        Event::Scan { .. }
    ));
    assert!(matches!(
        out.next().unwrap().unwrap().event,
        Event::GroundTruth { .. }
    ));
    let e = out.next().unwrap().unwrap_err().to_string();
    assert!(
        e.ends_with("[data.odometry_from_poses]: doc.log has no scan with a reference pose"),
        "{e}"
    );
    assert!(out.next().is_none());
}

/// Reads `n` events of `stream`, then appends `text` to `path` (which the stream holds
/// open), then returns the rest: the appended lines are seen only by a reader that had not
/// read the whole file when it yielded its first events.
fn read_then_append(
    mut stream: EventStream,
    n: usize,
    path: &Path,
    text: &str,
) -> (Vec<TimedEvent>, Vec<slam_sensors::Result<TimedEvent>>) {
    let head: Vec<TimedEvent> = stream.by_ref().take(n).map(Result::unwrap).collect();
    assert_eq!(head.len(), n);
    let mut file = std::fs::OpenOptions::new().append(true).open(path).unwrap();
    file.write_all(text.as_bytes()).unwrap();
    drop(file);
    (head, stream.collect())
}

/// The last item is an error whose message ends with `suffix`; the ones before are events.
fn assert_ends_with_error(rest: &[slam_sensors::Result<TimedEvent>], suffix: &str) {
    let (last, before) = rest.split_last().expect("an error item");
    assert!(before.iter().all(Result::is_ok));
    let message = last.as_ref().expect_err("an error").to_string();
    assert!(message.ends_with(suffix), "`{message}` vs `{suffix}`");
}

#[test]
fn streams_yield_events_before_a_malformed_line_further_down() {
    let dir = tempfile::tempdir().unwrap();

    // CARMEN: ODOM lines, then a bad one appended after the first events were read.
    let path = dir.path().join("long.log");
    let odom: String = (0..2000)
        .map(|k| format!("ODOM {} 0 0 0 0 0 {k} h {k}\n", f64::from(k) * 0.01))
        .collect();
    std::fs::write(&path, &odom).unwrap();
    let stream = stream_carmen(&path, &CarmenOptions::default()).unwrap();
    let (head, rest) = read_then_append(stream, 3, &path, "NEFF 1\nODOM 1 2 3\n");
    assert_eq!(head[0].time, 1.0); // the logger timestamp of line 2
    assert_eq!(rest.len(), 1999 - 3 + 1);
    assert_ends_with_error(&rest, "long.log:2002: ODOM: expected 10 fields, got 4");
    // The same without appending: the events of the lines before, then the error; the skip
    // counts cover the lines read so far.
    let mut stream = stream_carmen(&path, &CarmenOptions::default()).unwrap();
    let items: Vec<_> = stream.by_ref().collect();
    assert_eq!(items.len(), 2000);
    assert_ends_with_error(&items, "long.log:2002: ODOM: expected 10 fields, got 4");
    assert_eq!(stream.skipped()["NEFF"], 1);
    assert!(stream.next().is_none());
    assert!(read_carmen(&path, &CarmenOptions::default()).is_err());
    // With FLASER lines whose maximum range needs the whole file.
    let path = dir.path().join("laser.log");
    let flaser = "FLASER 3 1.0 2.0 5.0 0 0 0 0 0 0 0 h 0\n".repeat(500);
    std::fs::write(&path, &flaser).unwrap();
    let stream = stream_carmen(&path, &CarmenOptions::default()).unwrap();
    let (head, rest) = read_then_append(stream, 2, &path, "FLASER 3 1 2 x 0 0 0 0 0 0 0 h 0\n");
    let Event::Scan { scan, .. } = &head[0].event else {
        panic!("{:?}", head[0])
    };
    assert_eq!(scan.max_range, 5.0 * (1.0 - NO_RETURN_BAND)); // the largest reading, less the band
    assert_ends_with_error(
        &rest,
        "laser.log:501:14: field 5 (range): expected a number, got `x`",
    );

    // rb2d.
    let path = dir.path().join("long.rb2d");
    let mut text = String::from("PARAM dt 0.1\nPARAM sigma_v 0.1\nPARAM sigma_w 0.1\n");
    for k in 1..=1000 {
        text += &format!("ODOM {k} 0.1 0.1 0 0\nGT {k} 0 0 0\n");
    }
    std::fs::write(&path, &text).unwrap();
    let (head, rest) = read_then_append(stream_rb2d(&path).unwrap(), 2, &path, "GT 2000 0 0\n");
    assert!(matches!(head[1].event, Event::GroundTruth { .. }));
    assert_eq!(rest.len(), 2000 - 2 + 1);
    assert_ends_with_error(
        &rest,
        "long.rb2d:2004: GT k x y th: expected 5 fields, got 4",
    );

    // Victoria Park: a bad odometry line at the end.
    let vp = dir.path().join("vp");
    std::fs::create_dir_all(&vp).unwrap();
    let odometry: String = (0..1000)
        .map(|k| format!("{},1.0,0.0\n", 1000 + 10 * k))
        .collect();
    let files = [
        (
            "odometry.csv",
            format!("time_ms,speed_mps,steering_rad\n{odometry}"),
        ),
        ("laser_frame_times.csv", "frame,time_s\n0,1.5\n".to_string()),
        (
            "tree_detections.csv",
            "frame,time_s,range_m,bearing_rad,diameter_m\n0,1.5,5.0,1.0,0.3\n".to_string(),
        ),
        ("gps.csv", "time_ms,Lo_m,La_m\n1000,0.0,0.0\n".to_string()),
    ];
    for (file, text) in &files {
        std::fs::write(vp.join(file), text).unwrap();
    }
    let stream = stream_victoria_park(&vp, &VictoriaParkOptions::default()).unwrap();
    let (head, rest) = read_then_append(stream, 2, &vp.join("odometry.csv"), "20000,1\n");
    assert!(matches!(head[0].event, Event::Gps(_)));
    assert_ends_with_error(
        &rest,
        "odometry.csv:1002: time_ms,speed_mps,steering_rad: expected 3 fields, got 2",
    );
    let gps = vp.join("gps.csv");
    // A GPS fix going backwards cannot be merged by time: an error naming its line.
    std::fs::write(&gps, "time_ms,Lo_m,La_m\n1000,0.0,0.0\n900,0.0,0.0\n").unwrap();
    let items: Vec<_> = stream_victoria_park(&vp, &VictoriaParkOptions::default())
        .unwrap()
        .collect();
    assert_ends_with_error(&items, "gps.csv:3: time goes backwards: 0.9 after 1");
    // Detections out of frame order, likewise.
    std::fs::write(vp.join("gps.csv"), &files[3].1).unwrap();
    std::fs::write(
        vp.join("laser_frame_times.csv"),
        "frame,time_s\n0,1.5\n1,1.6\n",
    )
    .unwrap();
    std::fs::write(
        vp.join("tree_detections.csv"),
        "frame,time_s,range_m,bearing_rad,diameter_m\n1,1.6,5.0,1.0,0.3\n0,1.5,5.0,1.0,0.3\n",
    )
    .unwrap();
    let e = read_victoria_park(&vp, &VictoriaParkOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        e.ends_with(
            "tree_detections.csv:3: frame 0 after frame 1: detections must be in frame order"
        ),
        "{e}"
    );

    // MR.CLAM: a bad odometry line at the end.
    let mrclam = dir.path().join("mrclam");
    std::fs::create_dir_all(&mrclam).unwrap();
    let odometry: String = (0..1000)
        .map(|k| format!("{} 0.1 0.0\n", 10.0 + f64::from(k) * 0.01))
        .collect();
    for (file, text) in [
        ("Barcodes.dat", "1 5\n6 72\n".to_string()),
        (
            "Landmark_Groundtruth.dat",
            "6 1.0 2.0 0.001 0.001\n".to_string(),
        ),
        ("Robot1_Odometry.dat", odometry),
        (
            "Robot1_Measurement.dat",
            "# header\n10.005 72 2.0 0.1\n".to_string(),
        ),
    ] {
        std::fs::write(mrclam.join(file), text).unwrap();
    }
    let stream = stream_mrclam(&mrclam, 1, &MrclamOptions::default()).unwrap();
    assert_eq!(stream.info.landmarks.len(), 1);
    let odometry = mrclam.join("Robot1_Odometry.dat");
    let (head, rest) = read_then_append(stream, 3, &odometry, "20.0 fast 0.0\n");
    assert!(matches!(head[1].event, Event::Observations(_)));
    assert_ends_with_error(
        &rest,
        "Robot1_Odometry.dat:1001:6: field 2 (odometry): expected a number, got `fast`",
    );
}

#[test]
fn event_streams_round_trip_datasets_and_count_skipped_lines_as_they_go() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("skips.log");
    std::fs::write(
        &path,
        "NEFF 1\nODOM 0 0 0 0 0 0 0 h 0\nPARAM a b\nODOM 1 0 0 0 0 0 0 h 0\nPARAM c d\n",
    )
    .unwrap();
    let mut stream = stream_carmen(&path, &CarmenOptions::default()).unwrap();
    assert!(stream.skipped().is_empty());
    assert_eq!(stream.next().unwrap().unwrap().time, 4.0);
    assert_eq!(stream.skipped().len(), 2);
    assert_eq!(stream.skipped()["PARAM"], 1);
    let debug = format!("{stream:?}");
    assert!(
        debug.contains("skips.log") && debug.contains("PARAM"),
        "{debug}"
    );
    let rest = stream.into_dataset().unwrap();
    assert_eq!(rest.events.len(), 0);
    assert_eq!(rest.skipped["PARAM"], 2);

    let data = read_carmen(&path, &CarmenOptions::default()).unwrap();
    let expected = fingerprint(&data);
    assert_eq!(
        stream_fingerprint(EventStream::from_dataset(data)),
        expected
    );
    let data = read_carmen(&path, &CarmenOptions::default()).unwrap();
    let back = EventStream::from_dataset(data).into_dataset().unwrap();
    assert_eq!(fingerprint(&back), expected);
}

/// RMS translation error of `estimates` against `truths` after the best rigid planar
/// alignment (closed-form 2-D Kabsch), m.
fn aligned_rmse(estimates: &[slam_core::Pose2], truths: &[slam_core::Pose2]) -> f64 {
    let n = estimates.len() as f64;
    let mean = |poses: &[slam_core::Pose2]| {
        poses
            .iter()
            .fold((0.0, 0.0), |(x, y), p| (x + p.x / n, y + p.y / n))
    };
    let ((ex, ey), (tx, ty)) = (mean(estimates), mean(truths));
    let (mut dot, mut cross) = (0.0, 0.0);
    for (e, t) in estimates.iter().zip(truths) {
        let (ax, ay, bx, by) = (e.x - ex, e.y - ey, t.x - tx, t.y - ty);
        dot += ax * bx + ay * by;
        cross += ax * by - ay * bx;
    }
    let (sin, cos) = cross.atan2(dot).sin_cos();
    let sum: f64 = estimates
        .iter()
        .zip(truths)
        .map(|(e, t)| {
            let (ax, ay) = (e.x - ex, e.y - ey);
            let (x, y) = (cos * ax - sin * ay + tx, sin * ax + cos * ay + ty);
            (x - t.x).powi(2) + (y - t.y).powi(2)
        })
        .sum();
    (sum / n).sqrt()
}

/// The laser odometry of `configs/carmen-walls.toml` on the Intel lab with the log's own
/// odometry (15 `ODOM` lines per scan, heading drifting about 0.06 rad per metre): with
/// the odometry a weak prior over each scan interval (`interval_noise`, ten times the
/// default model) the path stays near the reference (0.19 m when measured); with the compound
/// of the 15 records' covariances as the prior it is lost (13.8 m).
#[test]
#[cfg_attr(
    not(slam_data),
    ignore = "needs the real datasets (DATASETS.md, SLAM_DATA_DIR)"
)]
fn a_weak_interval_prior_keeps_the_intel_lab_with_its_own_odometry() {
    use slam_sensors::odometry::OdometryNoise;
    let intel = datasets().join("radish-carmen-corrected/intel-corrected.log.gz");
    let drift = |interval_noise: Option<OdometryNoise>| {
        let dataset = stream_carmen(&intel, &CarmenOptions::default())
            .unwrap()
            .into_dataset()
            .unwrap();
        let params = LaserOdometryParams {
            local_map_scans: 50,
            keyframe_distance: 0.2,
            keyframe_angle: 0.1,
            normal_reach_per_metre: 0.1,
            heading_starts: 2,
            interval_noise,
            ..LaserOdometryParams::default()
        };
        let (matched, _) = laser_odometry(dataset, &params).unwrap();
        let (mut pose, mut estimates, mut truths) = (None, Vec::new(), Vec::new());
        for timed in &matched.events {
            match &timed.event {
                Event::Motion(motion) => {
                    if let Some(p) = pose.as_mut() {
                        *p = motion.predict(p).unwrap().pose;
                    }
                }
                Event::GroundTruth { pose: truth, .. } => {
                    estimates.push(*pose.get_or_insert(*truth));
                    truths.push(*truth);
                }
                _ => {}
            }
        }
        aligned_rmse(&estimates, &truths)
    };
    let model = OdometryNoise::default();
    let weak = OdometryNoise {
        translation_per_metre: 10.0 * model.translation_per_metre,
        translation_per_radian: 10.0 * model.translation_per_radian,
        rotation_per_radian: 10.0 * model.rotation_per_radian,
        rotation_per_metre: 10.0 * model.rotation_per_metre,
        floor_translation: 10.0 * model.floor_translation,
        floor_rotation: 10.0 * model.floor_rotation,
    };
    let (narrow, wide) = (drift(None), drift(Some(weak)));
    eprintln!("compound prior {narrow:.3} m, weak interval prior {wide:.3} m");
    assert!(wide < 0.4, "weak interval prior {wide:.3} m");
    assert!(narrow > 2.0, "compound prior {narrow:.3} m");
}
