//! The input policy of the readers (`slam_sensors::data`): a syntax error is an error with
//! `file:line:column`; a physically impossible reading is skipped and counted by reason; a
//! log in the wrong units is an error naming the file and the unit; a file with no record is
//! an error, not an empty run.

use std::path::{Path, PathBuf};

use slam_sensors::data::carmen::carmen_text;
use slam_sensors::data::rb2d::rb2d_text;
use slam_sensors::data::{CarmenOptions, read_carmen, read_rb2d, stream_rb2d};
use slam_sensors::sim::{World, simulate};
use slam_sensors::{Dataset, Event};

fn world(name: &str) -> World {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../worlds")
        .join(name);
    World::from_file(&path).unwrap()
}

/// The rb2d log of the range-bearing circle world (1000 steps, 50 landmarks), as text.
fn circle_rb2d() -> String {
    let world = world("rb2d-circle.toml");
    let run = simulate(&world, 1).unwrap();
    rb2d_text(&run.dataset, &world.rb2d_params(), "policy test").unwrap()
}

/// `text` with field `index` of every line starting with `record` changed by `change`.
fn map_field(text: &str, record: &str, index: usize, change: impl Fn(f64) -> f64) -> String {
    let mut out = String::new();
    for line in text.lines() {
        let mut fields: Vec<String> = line.split_whitespace().map(String::from).collect();
        if fields.first().map(String::as_str) == Some(record) {
            let value: f64 = fields[index].parse().unwrap();
            fields[index] = format!("{}", change(value));
        }
        out.push_str(&fields.join(" "));
        out.push('\n');
    }
    out
}

fn write(dir: &Path, name: &str, text: impl AsRef<[u8]>) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

fn rb2d_error(dir: &Path, name: &str, text: &str) -> String {
    stream_rb2d(&write(dir, name, text))
        .unwrap_err()
        .to_string()
}

/// The error of reading `path` as CARMEN (empty when it reads).
fn carmen_error(path: &Path) -> String {
    read_carmen(path, &CarmenOptions::default())
        .err()
        .map(|e| e.to_string())
        .unwrap_or_default()
}

fn observations(data: &Dataset) -> usize {
    data.counts().observations
}

#[test]
fn an_impossible_rb2d_range_is_skipped_and_counted_not_the_whole_log() {
    let dir = tempfile::tempdir().unwrap();
    let text = circle_rb2d();
    let whole = read_rb2d(&write(dir.path(), "whole.rb2d", &text)).unwrap();
    // One slightly negative range and one far beyond the sensor, as other tools write them.
    let mut glitched = String::new();
    let mut changed = 0;
    for line in text.lines() {
        let mut fields: Vec<&str> = line.split_whitespace().collect();
        if fields.first() == Some(&"OBS") && changed < 2 && fields[1] == "7" {
            fields[3] = if changed == 0 { "-0.01" } else { "500" };
            changed += 1;
        }
        glitched.push_str(&fields.join(" "));
        glitched.push('\n');
    }
    let data = read_rb2d(&write(dir.path(), "glitch.rb2d", &glitched)).unwrap();
    assert_eq!(observations(&data), observations(&whole) - 2);
    assert_eq!(data.skipped_readings["rb2d OBS: range not positive"], 1);
    assert_eq!(
        data.skipped_readings["rb2d OBS: range beyond max_range + 5 sigma_r"],
        1
    );
    assert!(whole.skipped_readings.is_empty());
}

#[test]
fn rb2d_syntax_errors_name_file_line_and_column() {
    let dir = tempfile::tempdir().unwrap();
    let text = circle_rb2d().replacen("OBS 0 ", "OBS 0 x", 1);
    let e = read_rb2d(&write(dir.path(), "syntax.rb2d", &text))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("syntax.rb2d:") && e.contains(":7: field 3 (landmark id): expected an integer"),
        "{e}"
    );
}

#[test]
fn an_empty_rb2d_file_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    for (name, text) in [("empty.rb2d", ""), ("comments.rb2d", "# nothing\n\n")] {
        let e = rb2d_error(dir.path(), name, text);
        assert!(e.contains(name) && e.contains("no rb2d record"), "{e}");
    }
}

#[test]
fn rb2d_angles_in_degrees_are_errors_naming_the_unit() {
    let dir = tempfile::tempdir().unwrap();
    let text = circle_rb2d();
    let cases = [
        (
            "bearings.rb2d",
            map_field(&text, "OBS", 4, f64::to_degrees),
            "OBS bearings",
        ),
        (
            "headings.rb2d",
            map_field(&text, "GT", 4, f64::to_degrees),
            "GT headings",
        ),
        (
            "turns.rb2d",
            map_field(&text, "ODOM", 5, f64::to_degrees),
            "ODOM turns",
        ),
    ];
    for (name, text, what) in cases {
        let e = rb2d_error(dir.path(), name, &text);
        assert!(
            e.contains(name) && e.contains(what) && e.contains("degrees"),
            "{e}"
        );
    }
}

#[test]
fn rb2d_lengths_in_centimetres_are_errors_naming_the_unit() {
    let dir = tempfile::tempdir().unwrap();
    let text = circle_rb2d();
    // Ranges in centimetres: beyond max_range.
    let ranges = map_field(&text, "OBS", 3, |r| r * 100.0);
    let e = rb2d_error(dir.path(), "ranges.rb2d", &ranges);
    assert!(
        e.contains("ranges.rb2d") && e.contains("centimetres"),
        "{e}"
    );
    // ... and with max_range and sigma_r in centimetres too: against the truth.
    let all: String = ranges
        .lines()
        .map(|line| match line.strip_prefix("PARAM ") {
            Some(rest) if rest.starts_with("max_range") || rest.starts_with("sigma_r") => {
                let (name, value) = rest.split_once(' ').unwrap();
                format!("PARAM {name} {}\n", value.parse::<f64>().unwrap() * 100.0)
            }
            _ => format!("{line}\n"),
        })
        .collect();
    let e = rb2d_error(dir.path(), "all.rb2d", &all);
    assert!(e.contains("all.rb2d") && e.contains("centimetres"), "{e}");
    // Odometry in centimetres.
    let odometry = map_field(&text, "ODOM", 3, |d| d * 100.0);
    let e = rb2d_error(dir.path(), "odometry.rb2d", &odometry);
    assert!(
        e.contains("ODOM distances") && e.contains("centimetres"),
        "{e}"
    );
}

/// A CARMEN log of the default world's laser (a short drive).
fn default_world_carmen() -> String {
    let mut world = World::default_world();
    world.camera = None;
    world.robot.waypoints.truncate(3);
    let run = simulate(&world, 1).unwrap();
    carmen_text(&run.dataset, &slam_core::Pose2::identity(), "policy test").unwrap()
}

#[test]
fn carmen_garbage_or_an_empty_file_is_an_error_not_an_empty_run() {
    let dir = tempfile::tempdir().unwrap();
    // Bytes that are not a log: a few thousand pseudo-random bytes, some line breaks.
    let mut state = 0x2545_f491_4f6c_dd1d_u64;
    let garbage: Vec<u8> = (0..20_000)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 56) as u8
        })
        .collect();
    let options = CarmenOptions::default();
    let e = carmen_error(&write(dir.path(), "garbage.log", &garbage));
    assert!(
        e.contains("garbage.log") && e.contains("no CARMEN record"),
        "{e}"
    );
    let e = carmen_error(&write(dir.path(), "empty.log", ""));
    assert!(e.contains("empty.log") && e.contains("empty"), "{e}");
    // Words that are no message name are counted under one key.
    let text = "\u{1}\u{2}x 1\nNEFF 1\n!!! 2\nODOM 0 0 0 0 0 0 1 h 1\n";
    let data = read_carmen(&write(dir.path(), "words.log", text), &options).unwrap();
    assert_eq!(data.skipped.len(), 2, "{:?}", data.skipped);
    assert_eq!(data.skipped["(not a CARMEN message)"], 2);
}

#[test]
fn carmen_glitches_are_counted_and_units_checked() {
    let dir = tempfile::tempdir().unwrap();
    let text = default_world_carmen();
    let options = CarmenOptions::default();
    let whole = read_carmen(&write(dir.path(), "whole.log", &text), &options).unwrap();
    assert!(whole.skipped_readings.is_empty() && whole.warnings.is_empty());
    // A reading written as nan or negative is a beam without return, counted.
    let mut glitched = String::new();
    for (k, line) in text.lines().enumerate() {
        let mut fields: Vec<String> = line.split_whitespace().map(String::from).collect();
        if fields.first().map(String::as_str) == Some("ROBOTLASER1") {
            fields[9] = if k % 2 == 0 { "nan" } else { "-0.5" }.into();
        }
        glitched.push_str(&fields.join(" "));
        glitched.push('\n');
    }
    let data = read_carmen(&write(dir.path(), "glitch.log", &glitched), &options).unwrap();
    let counted: usize = data.skipped_readings.values().sum();
    assert_eq!(counted, whole.counts().scans);
    assert_eq!(data.counts(), whole.counts());
    // Readings in centimetres: an error naming the unit.
    let mut centimetres = String::new();
    for line in text.lines() {
        let mut fields: Vec<String> = line.split_whitespace().map(String::from).collect();
        if fields.first().map(String::as_str) == Some("ROBOTLASER1") {
            let n: usize = fields[8].parse().unwrap();
            for field in &mut fields[9..9 + n] {
                *field = format!("{}", field.parse::<f64>().unwrap() * 100.0);
            }
            fields[5] = format!("{}", fields[5].parse::<f64>().unwrap() * 100.0);
        }
        centimetres.push_str(&fields.join(" "));
        centimetres.push('\n');
    }
    let e = carmen_error(&write(dir.path(), "cm.log", &centimetres));
    assert!(e.contains("cm.log:") && e.contains("centimetres"), "{e}");
    // Angles in degrees.
    let degrees = map_field(&text, "ROBOTLASER1", 4, f64::to_degrees);
    let degrees = map_field(&degrees, "ROBOTLASER1", 2, f64::to_degrees);
    let e = carmen_error(&write(dir.path(), "deg.log", &degrees));
    assert!(e.contains("deg.log:") && e.contains("degrees"), "{e}");
}

#[test]
fn scans_all_at_their_maximum_range_are_a_warning_naming_the_setting() {
    let dir = tempfile::tempdir().unwrap();
    let text = default_world_carmen();
    // Every reading at the line's maximum range: no return at all, as when the maximum
    // range or the unit is wrong.
    let mut blind = String::new();
    for line in text.lines() {
        let mut fields: Vec<String> = line.split_whitespace().map(String::from).collect();
        if fields.first().map(String::as_str) == Some("ROBOTLASER1") {
            let n: usize = fields[8].parse().unwrap();
            let max_range = fields[5].clone();
            for field in &mut fields[9..9 + n] {
                *field = max_range.clone();
            }
        }
        blind.push_str(&fields.join(" "));
        blind.push('\n');
    }
    let data = read_carmen(
        &write(dir.path(), "blind.log", &blind),
        &CarmenOptions::default(),
    )
    .unwrap();
    assert_eq!(data.warnings.len(), 1, "{:?}", data.warnings);
    let warning = &data.warnings[0];
    assert!(
        warning.contains("blind.log")
            && warning.contains("no reading below their maximum range")
            && warning.contains("maximum_range"),
        "{warning}"
    );
    // Not a glitch: nothing is counted as an impossible reading, and the scans are kept.
    assert!(data.skipped_readings.is_empty());
    // The whole log as simulated has no such warning.
    let whole = read_carmen(
        &write(dir.path(), "whole.log", &text),
        &CarmenOptions::default(),
    )
    .unwrap();
    assert!(whole.warnings.is_empty(), "{:?}", whole.warnings);
    assert_eq!(data.counts().scans, whole.counts().scans);
}

#[test]
fn a_line_without_end_is_an_error_not_a_whole_file_in_memory() {
    let dir = tempfile::tempdir().unwrap();
    let long = vec![b'7'; slam_sensors::data::MAX_LINE_BYTES + 10];
    let e = carmen_error(&write(dir.path(), "long.log", &long));
    assert!(e.contains("long.log:1") && e.contains("longer than"), "{e}");
}

#[test]
#[cfg_attr(
    not(slam_data),
    ignore = "needs the real datasets (DATASETS.md, SLAM_DATA_DIR)"
)]
fn the_real_logs_have_no_impossible_reading_and_no_unit_warning() {
    let dir = Path::new(option_env!("SLAM_DATA").unwrap_or("the real datasets are absent"));
    for log in ["intel", "fhw"] {
        let path = dir.join(format!("radish-carmen-corrected/{log}-corrected.log.gz"));
        let data = read_carmen(&path, &CarmenOptions::default()).unwrap();
        // Their stamps are usable. A warning counts the ODOM lines of the corrected pose
        // stamped 0 after each scan, read as odometry resets (one per scan); another may
        // count repaired stamps (the Intel log's odometry stamps jitter).
        assert_eq!(data.clock, slam_sensors::Clock::Seconds, "{log}");
        let scans = data.counts().scans;
        let resets = format!("{scans} ODOM lines right after a scan repeat its reference pose");
        assert!(
            data.warnings.iter().any(|w| w.contains(&resets)),
            "{log}: {:?}",
            data.warnings
        );
        assert!(
            data.warnings
                .iter()
                .all(|w| w.contains(&resets) || w.contains("logger timestamps repaired")),
            "{log}: {:?}",
            data.warnings
        );
        assert!(
            data.skipped_readings.is_empty(),
            "{log}: {:?}",
            data.skipped_readings
        );
    }
    let events =
        slam_sensors::data::stream_mrclam(&dir.join("utias-mrclam1"), 1, &Default::default())
            .unwrap();
    let mut events = events;
    for event in events.by_ref() {
        if let Event::Scan { .. } = event.unwrap().event {
            unreachable!("MR.CLAM has no scans");
        }
    }
    assert!(events.warnings().is_empty());
}
