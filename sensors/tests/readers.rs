//! The dataset readers on the real shared data (ignored when the
//! datasets are absent: DATASETS.md) and on small malformed files.

use std::collections::{BTreeSet, HashMap};
use std::path::{Path, PathBuf};

use slam_sensors::data::{
    CarmenOptions, MrclamOptions, NO_RETURN_BAND, VictoriaParkOptions, read_carmen, read_mrclam,
    read_rb2d, read_victoria_park,
};
use slam_sensors::{Dataset, Event, TruthKind};

/// The real datasets folder (DATASETS.md, `SLAM_DATA_DIR`). Tests that read it carry
/// `cfg_attr(not(slam_data), ignore)`: sensors/build.rs finds the folder.
fn datasets() -> PathBuf {
    PathBuf::from(option_env!("SLAM_DATA").unwrap_or("the real datasets are absent"))
}

/// A fresh folder for one test's files, removed when dropped.
fn temp_dir(name: &str) -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix(&format!("slam-sensors-readers-{name}-"))
        .tempdir()
        .unwrap()
}

fn assert_time_ordered(data: &Dataset) {
    for pair in data.events.windows(2) {
        assert!(
            pair[1].time >= pair[0].time,
            "{} after {}",
            pair[1].time,
            pair[0].time
        );
    }
}

/// Asserts that `result` is an error whose message contains `file:line` and `reason`.
fn assert_error<T: std::fmt::Debug>(result: slam_sensors::Result<T>, location: &str, reason: &str) {
    let message = result.expect_err("expected an error").to_string();
    assert!(
        message.contains(location),
        "`{message}` does not name `{location}`"
    );
    assert!(
        message.contains(reason),
        "`{message}` does not say `{reason}`"
    );
}

#[test]
#[cfg_attr(
    not(slam_data),
    ignore = "needs the real datasets (DATASETS.md, SLAM_DATA_DIR)"
)]
fn victoria_park_counts() {
    let root = datasets();
    let data =
        read_victoria_park(&root.join("victoria-park"), &VictoriaParkOptions::default()).unwrap();
    let counts = data.counts();
    assert_eq!(counts.observation_events, 7249);
    assert_eq!(counts.observations, 52974);
    assert_eq!(counts.gps, 4466);
    assert!(counts.motion >= 61944, "{counts:?}");
    let empty = data
        .events
        .iter()
        .filter(|e| matches!(&e.event, Event::Observations(o) if o.is_empty()))
        .count();
    assert_eq!(empty, 19);
    assert!(data.skipped.is_empty(), "{:?}", data.skipped);
    assert_time_ordered(&data);
    eprintln!("Victoria Park: {counts:?}");
}

#[test]
#[cfg_attr(
    not(slam_data),
    ignore = "needs the real datasets (DATASETS.md, SLAM_DATA_DIR)"
)]
fn radish_carmen_counts() {
    let root = datasets();
    let dir = root.join("radish-carmen-corrected");
    // ODOM lines, and those read as resets of the odometry frame (the corrected pose again
    // right after a scan, stamped 0 or garbage), which give no motion.
    let expected = [
        ("intel-corrected.log.gz", 910, 180, 14541, 910),
        ("acapulco-corrected.log.gz", 861, 181, 12142, 861),
        ("fhw-corrected.log.gz", 488, 180, 13935, 488),
        ("freiburg-079-corrected.log.gz", 4791, 360, 9725, 4788),
    ];
    for (file, scans, beams, odom, resets) in expected {
        let data = read_carmen(&dir.join(file), &CarmenOptions::default()).unwrap();
        let counts = data.counts();
        assert_eq!(counts.scans, scans, "{file}");
        assert_eq!(counts.ground_truth, scans, "{file}");
        assert_eq!(counts.motion, odom - 1 - resets, "{file}");
        assert_eq!(data.skipped.get("NEFF"), Some(&scans), "{file}");
        for event in &data.events {
            match &event.event {
                Event::Scan { scan, .. } => {
                    assert_eq!(scan.ranges.len(), beams, "{file}");
                    // The maximum range is the file's largest reading less the no-return
                    // band: no reading lies above that largest.
                    let largest = scan.max_range / (1.0 - NO_RETURN_BAND);
                    assert!(scan.ranges.iter().all(|&r| r <= largest + 1e-9), "{file}");
                }
                Event::GroundTruth { kind, .. } => assert_eq!(*kind, TruthKind::Reference),
                _ => {}
            }
        }
        assert_time_ordered(&data);
        let not_read = &data.skipped;
        eprintln!("{file}: {counts:?}, lines not read {not_read:?}");
    }
}

#[test]
#[cfg_attr(
    not(slam_data),
    ignore = "needs the real datasets (DATASETS.md, SLAM_DATA_DIR)"
)]
fn intel_max_range_readings_are_invalid() {
    let root = datasets();
    let path = root.join("radish-carmen-corrected/intel-corrected.log.gz");
    let data = read_carmen(&path, &CarmenOptions::default()).unwrap();
    let (mut total, mut valid) = (0, 0);
    for event in &data.events {
        if let Event::Scan { scan, .. } = &event.event {
            let expected = 81.83 * (1.0 - NO_RETURN_BAND);
            assert!(
                (scan.max_range - expected).abs() < 1e-9,
                "{}",
                scan.max_range
            );
            total += scan.ranges.len();
            valid += scan.points().len();
        }
    }
    assert_eq!(total, 910 * 180);
    assert!(valid < total && valid > total / 2, "{valid} of {total}");
}

/// The acapulco log codes "no return" as 51.15 m with a jitter (51.09-51.25 m): none of
/// those readings is a point (they drew arcs that the line extractor took for walls).
#[test]
fn acapulco_no_return_codes_with_jitter_are_invalid() {
    let root = datasets();
    let path = root.join("radish-carmen-corrected/acapulco-corrected.log.gz");
    let data = read_carmen(&path, &CarmenOptions::default()).unwrap();
    let (mut coded, mut valid_coded, mut valid) = (0, 0, 0);
    for event in &data.events {
        if let Event::Scan { scan, .. } = &event.event {
            coded += scan
                .ranges
                .iter()
                .filter(|r| (51.0..51.3).contains(*r))
                .count();
            let points = scan.points();
            valid_coded += points.iter().filter(|p| p.range >= 51.0).count();
            valid += points.len();
        }
    }
    assert!(coded > 12_000, "{coded} coded readings");
    assert_eq!(valid_coded, 0);
    assert!(valid > 861 * 181 / 2, "{valid} valid readings");
}

/// Data lines of an MR.CLAM file (not `#` headers, not blank), as whitespace-split fields.
fn mrclam_rows(path: &Path) -> Vec<Vec<String>> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter(|l| !l.trim().is_empty() && !l.trim_start().starts_with('#'))
        .map(|l| l.split_whitespace().map(String::from).collect())
        .collect()
}

/// `"1248272272.841"` as integer milliseconds.
fn millis(text: &str) -> i64 {
    text.replace('.', "").parse().unwrap()
}

#[test]
#[cfg_attr(
    not(slam_data),
    ignore = "needs the real datasets (DATASETS.md, SLAM_DATA_DIR)"
)]
fn mrclam_robot1_counts() {
    let root = datasets();
    let dir = root.join("utias-mrclam1");
    let data = read_mrclam(&dir, 1, &MrclamOptions::default()).unwrap();
    assert_eq!(data.landmarks.len(), 15);

    // Independent counts from the files.
    let subject_of: HashMap<String, u64> = mrclam_rows(&dir.join("Barcodes.dat"))
        .into_iter()
        .map(|r| (r[1].clone(), r[0].parse().unwrap()))
        .collect();
    let odometry = mrclam_rows(&dir.join("Robot1_Odometry.dat"));
    let odometry_times: Vec<i64> = odometry.iter().map(|r| millis(&r[0])).collect();
    let (first, last) = (odometry_times[0], *odometry_times.last().unwrap());
    let odometry_set: BTreeSet<i64> = odometry_times.iter().copied().collect();
    let landmark_rows: Vec<i64> = mrclam_rows(&dir.join("Robot1_Measurement.dat"))
        .iter()
        .filter(|r| subject_of.get(&r[1]).is_some_and(|s| (6..=20).contains(s)))
        .map(|r| millis(&r[0]))
        .collect();
    let group_times: BTreeSet<i64> = landmark_rows.iter().copied().collect();
    let splits = group_times
        .iter()
        .filter(|t| **t > first && **t < last && !odometry_set.contains(t))
        .count();

    let counts = data.counts();
    assert_eq!(counts.observations, landmark_rows.len());
    assert_eq!(counts.observation_events, group_times.len());
    assert_eq!(counts.motion, odometry.len() - 1 + splits);
    let ids: BTreeSet<u64> = data
        .events
        .iter()
        .filter_map(|e| match &e.event {
            Event::Observations(o) => Some(o.iter().map(|o| o.landmark_id.unwrap())),
            _ => None,
        })
        .flatten()
        .collect();
    assert!(ids.iter().all(|id| (6..=20).contains(id)));
    let skipped: usize = data.skipped.values().sum();
    assert_eq!(
        skipped + landmark_rows.len(),
        mrclam_rows(&dir.join("Robot1_Measurement.dat")).len()
    );
    assert_time_ordered(&data);
    eprintln!(
        "MR.CLAM robot 1: {} odometry rows, {} landmark measurements, {counts:?}, skipped {:?}",
        odometry.len(),
        landmark_rows.len(),
        data.skipped
    );
}

const RB2D_HEADER: &str = "# test log\nPARAM dt 0.1\nPARAM sigma_v 0.05\nPARAM sigma_w 0.02\n\
                           PARAM sigma_r 0.1\nPARAM sigma_b 0.01\nPARAM max_range 10\n";

#[test]
fn rb2d_valid_log() {
    let dir = temp_dir("rb2d-valid");
    let path = dir.path().join("valid.rb2d");
    let body = "LM 0 3.0 0.0\nLM 1 0.0 3.0\n\
                OBS 0 0 3.0 0.0\nGT 0 0 0 0\n\
                ODOM 1 0.1 0.1 0.0 0.05\nOBS 1 0 2.9 0.0\nOBS 1 -1 3.0 1.6\nGT 1 0.1 0.0 0.05\n\
                ODOM 2 0.1 0.1 0.01 0.0\n\
                ODOM 3 0.1 0.1 0.0 0.0\nOBS 3 1 2.8 1.5\n";
    std::fs::write(&path, format!("{RB2D_HEADER}{body}")).unwrap();
    let data = read_rb2d(&path).unwrap();
    let counts = data.counts();
    assert_eq!(counts.motion, 3);
    assert_eq!(counts.observation_events, 3);
    assert_eq!(counts.observations, 4);
    assert_eq!(counts.ground_truth, 2);
    assert_eq!(data.landmarks.len(), 2);
    assert_eq!(data.skipped["#"], 1);
    let times: Vec<f64> = data
        .events
        .iter()
        .map(|e| (e.time * 10.0).round())
        .collect();
    assert_eq!(times, [0.0, 0.0, 1.0, 1.0, 1.0, 2.0, 3.0, 3.0]);
    let Event::Observations(o) = &data.events[3].event else {
        panic!("{:?}", data.events[3])
    };
    assert_eq!((o[0].landmark_id, o[1].landmark_id), (Some(0), None));
    let Event::Motion(m) = &data.events[5].event else {
        panic!()
    };
    assert_eq!(m.control().len(), 3, "dy != 0 gives a pose increment");
    let Event::Motion(m) = &data.events[6].event else {
        panic!()
    };
    assert!(
        (m.control()[0] - 1.0).abs() < 1e-12,
        "dy == 0 gives a unicycle (v, w)"
    );
}

#[test]
fn rb2d_malformed_lines() {
    let dir = temp_dir("rb2d-bad");
    // (body after the 7-line header, line of the error, reason)
    let cases = [
        ("FOO 1 2\n", 8, "unknown record `FOO`"),
        ("ODOM 1 0.1 0.1 0.0\n", 8, "expected 6 fields, got 5"),
        ("OBS 0 1 2.0\n", 8, "expected 5 fields, got 4"),
        ("GT 0 0 0 0 0\n", 8, "expected 5 fields, got 6"),
        ("LM 1 2.0 abc\n", 8, "expected a number, got `abc`"),
        ("OBS 0 1 NaN 0.1\n", 8, "not finite"),
        ("GT 0 inf 0 0\n", 8, "not finite"),
        (
            "ODOM x 0.1 0.1 0 0\n",
            8,
            "expected a non-negative integer, got `x`",
        ),
        (
            "ODOM 2 0.1 0.1 0 0\nODOM 1 0.1 0.1 0 0\n",
            9,
            "step going backwards: step 1 after step 2",
        ),
        ("OBS 3 1 2.0 0.1\nGT 2 0 0 0\n", 9, "step going backwards"),
        (
            "GT 1 0 0 0\nODOM 1 0.1 0.1 0 0\n",
            9,
            "step going backwards: ODOM of step 1 after GT",
        ),
        (
            "ODOM 1 0.1 0.1 0 0\nODOM 1 0.1 0.1 0 0\n",
            9,
            "step going backwards",
        ),
        ("ODOM 0 0.1 0.1 0 0\n", 8, "at least 1"),
        ("ODOM 1 0 0.1 0 0\n", 8, "ODOM dt must be positive"),
        (
            "OBS 1 -2 2.0 0.1\n",
            8,
            "landmark id must be -1 or non-negative",
        ),
        ("PARAM dt 0.2\n", 8, "already set at line 2"),
        ("PARAM speed 0.2\n", 8, "unknown parameter `speed`"),
    ];
    for (k, (body, line, reason)) in cases.iter().enumerate() {
        let path = dir.path().join(format!("bad{k}.rb2d"));
        std::fs::write(&path, format!("{RB2D_HEADER}{body}")).unwrap();
        assert_error(read_rb2d(&path), &format!("bad{k}.rb2d:{line}:"), reason);
    }
    // A record before the parameter it needs.
    let path = dir.path().join("early.rb2d");
    std::fs::write(&path, "PARAM dt 0.1\nLM 1 0 0\nODOM 1 0.1 0.1 0 0\n").unwrap();
    assert_error(
        read_rb2d(&path),
        "early.rb2d:3:",
        "ODOM needs PARAM sigma_v",
    );
    std::fs::write(&path, "PARAM dt 0.1\nOBS 0 1 2.0 0.1\n").unwrap();
    assert_error(read_rb2d(&path), "early.rb2d:2:", "OBS needs PARAM sigma_r");
    std::fs::write(&path, "GT 0 0 0 0\n").unwrap();
    assert_error(read_rb2d(&path), "early.rb2d:1:", "GT needs PARAM dt");
    // Not there at all.
    assert!(read_rb2d(&dir.path().join("absent.rb2d")).is_err());
}

#[test]
fn carmen_malformed_lines() {
    let dir = temp_dir("carmen-bad");
    let cases = [
        (
            "ODOM 0 0 0 0 0 0 0 h 0\nODOM 1 0 0 0 0 h 0\n",
            2,
            "ODOM: expected 10 fields, got 8",
        ),
        (
            "# c\nFLASER 2 1 2 0 0 0 0 0 0 0 h\n",
            2,
            "FLASER: expected 13 fields, got 12",
        ),
        (
            "FLASER 2 1 2 0 0 0 0 0 0 0 h 0\nRLASER 2 1 x 0 0 0 0 0 0 0 h 0\n",
            2,
            "expected a number, got `x`",
        ),
        (
            "FLASER two 1 2\n",
            1,
            "expected a non-negative integer, got `two`",
        ),
    ];
    for (k, (text, line, reason)) in cases.iter().enumerate() {
        let path = dir.path().join(format!("bad{k}.log"));
        std::fs::write(&path, text).unwrap();
        assert_error(
            read_carmen(&path, &CarmenOptions::default()),
            &format!("bad{k}.log:{line}:"),
            reason,
        );
    }
}

/// A minimal Victoria Park `converted/` folder with `file` replaced by `text`.
fn victoria_dir(name: &str, file: &str, text: &str) -> tempfile::TempDir {
    let dir = temp_dir(name);
    let files = [
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
    ];
    for (f, t) in files {
        std::fs::write(dir.path().join(f), if f == file { text } else { t }).unwrap();
    }
    dir
}

#[test]
fn victoria_park_malformed_lines() {
    let ok = victoria_dir("vp-ok", "", "");
    assert_eq!(
        read_victoria_park(ok.path(), &VictoriaParkOptions::default())
            .unwrap()
            .counts()
            .observations,
        1
    );
    let cases = [
        (
            "odometry.csv",
            "time_ms,speed_mps,steering_rad\n1000,1.0,0.0\n2000,one,0.0\n",
            3,
            "expected a number, got `one`",
        ),
        (
            "gps.csv",
            "time,Lo_m,La_m\n",
            1,
            "expected the header `time_ms,Lo_m,La_m`",
        ),
        (
            "tree_detections.csv",
            "frame,time_s,range_m,bearing_rad,diameter_m\n0,1.5,5.0,1.0\n",
            2,
            "expected 5 fields, got 4",
        ),
        (
            "tree_detections.csv",
            "frame,time_s,range_m,bearing_rad,diameter_m\n0,1.7,5.0,1.0,0.3\n",
            2,
            "frame 0 is at 1.5 s",
        ),
        (
            "laser_frame_times.csv",
            "frame,time_s\n0,1.5\n0,1.6\n",
            3,
            "expected frame 1, got 0",
        ),
    ];
    for (k, (file, text, line, reason)) in cases.iter().enumerate() {
        let dir = victoria_dir(&format!("vp-bad{k}"), file, text);
        assert_error(
            read_victoria_park(dir.path(), &VictoriaParkOptions::default()),
            &format!("{file}:{line}:"),
            reason,
        );
    }
    assert!(
        read_victoria_park(temp_dir("vp-empty").path(), &VictoriaParkOptions::default()).is_err()
    );
}

#[test]
fn mrclam_malformed_lines() {
    let dir = temp_dir("mrclam-bad");
    let header = "# h\n# h\n# h\n# h\n";
    let write = |file: &str, body: &str| {
        std::fs::write(dir.path().join(file), format!("{header}{body}")).unwrap()
    };
    write("Barcodes.dat", "1 5\n6 72\n");
    write("Landmark_Groundtruth.dat", "6 1.0 2.0 0.001 0.001\n");
    write("Robot1_Odometry.dat", "10.0 0.1 0.0\n10.5 0.1 0.0\n");
    write("Robot1_Measurement.dat", "10.2 72 2.0 0.1\n");
    assert_eq!(
        read_mrclam(dir.path(), 1, &MrclamOptions::default())
            .unwrap()
            .counts()
            .observations,
        1
    );
    assert!(matches!(
        read_mrclam(dir.path(), 0, &MrclamOptions::default()),
        Err(slam_sensors::SensorError::InvalidArgument(_))
    ));
    assert_error(
        read_mrclam(dir.path(), 3, &MrclamOptions::default()),
        "Robot3_Odometry.dat",
        "not found",
    );

    write("Robot1_Measurement.dat", "10.2 72 2.0 0.1\n10.3 72 2.0\n");
    assert_error(
        read_mrclam(dir.path(), 1, &MrclamOptions::default()),
        "Robot1_Measurement.dat:6:",
        "expected 4 fields, got 3",
    );
    write("Robot1_Measurement.dat", "10.2 72 2.0 0.1\n");
    write("Robot1_Odometry.dat", "10.0 0.1 0.0\n10.5 fast 0.0\n");
    assert_error(
        read_mrclam(dir.path(), 1, &MrclamOptions::default()),
        "Robot1_Odometry.dat:6:",
        "expected a number, got `fast`",
    );
    write("Robot1_Odometry.dat", "10.0 0.1 0.0\n");
    write("Landmark_Groundtruth.dat", "6 1.0 2.0 0.001\n");
    assert_error(
        read_mrclam(dir.path(), 1, &MrclamOptions::default()),
        "Landmark_Groundtruth.dat:5:",
        "expected 5 fields, got 4",
    );
}

#[test]
fn impossible_readings_are_skipped_and_counted_not_errors() {
    let dir = victoria_dir(
        "vp-glitch",
        "tree_detections.csv",
        "frame,time_s,range_m,bearing_rad,diameter_m\n0,1.5,5.0,1.0,-0.3\n0,1.5,-5.0,1.0,0.3\n",
    );
    let data = read_victoria_park(dir.path(), &VictoriaParkOptions::default()).unwrap();
    assert_eq!(
        data.skipped_readings["Victoria Park detection: diameter not positive"],
        1
    );
    assert_eq!(
        data.skipped_readings["Victoria Park detection: range not positive"],
        1
    );
    assert_eq!(data.counts().observations, 0);
    let dir = temp_dir("carmen-inf");
    let path = dir.path().join("inf.log");
    std::fs::write(&path, "FLASER 2 1 inf 0 0 0 0 0 0 0 h 0\n").unwrap();
    let data = read_carmen(&path, &CarmenOptions::default()).unwrap();
    assert_eq!(
        data.skipped_readings["CARMEN laser: reading not finite (no return)"],
        1
    );
}
