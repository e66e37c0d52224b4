//! The TUM trajectory format (TUM RGB-D benchmark): one pose per line,
//! `timestamp tx ty tz qx qy qz qw`, `#` comment lines, fields separated by spaces.
//!
//! The quaternion is the rotation `world_from_body` (Hamilton convention, `qw` last), as the
//! TUM tools and `evo` read it.

use std::io::Write;
use std::path::Path;

use slam_core::Pose3;
use slam_core::nalgebra::{Quaternion, Rotation3, UnitQuaternion, Vector3};

use super::{Fields, numbered_lines, read_text};
use crate::error::{Result, SensorError};

/// One stamped pose of a trajectory.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StampedPose {
    /// Time, s (or a sequence number for data without a clock).
    pub time: f64,
    /// `world_from_body`.
    pub pose: Pose3,
}

/// Reads a TUM trajectory. Comment and blank lines are skipped; a line without exactly 8
/// finite numbers, or with a quaternion far from unit length (|q| outside 0.9..1.1), is an
/// error naming `file:line`. Quaternions are normalized.
///
/// ```
/// use slam_sensors::data::tum::{read_tum, write_tum, StampedPose};
/// use slam_core::{Pose2, Pose3};
/// let dir = tempfile::tempdir().unwrap();
/// let path = dir.path().join("tum-doc.txt");
/// let poses = vec![StampedPose { time: 0.5, pose: Pose2::new(1.0, 2.0, 0.3).to_pose3(0.0) }];
/// write_tum(&path, &poses).unwrap();
/// let back = read_tum(&path).unwrap();
/// assert!((back[0].pose.yaw - 0.3).abs() < 1e-8 && back[0].time == 0.5);
/// ```
pub fn read_tum(path: &Path) -> Result<Vec<StampedPose>> {
    let text = read_text(path)?;
    let mut poses = Vec::new();
    for (line, content) in numbered_lines(&text) {
        let trimmed = content.trim();
        if trimmed.is_empty() || trimmed.starts_with('#') {
            continue;
        }
        let fields = Fields::whitespace(path, line, trimmed);
        fields.expect_len(8, "TUM pose (timestamp tx ty tz qx qy qz qw)")?;
        let [time, tx, ty, tz, qx, qy, qz, qw] = fields.f64s(0, "TUM pose")?;
        let q = Quaternion::new(qw, qx, qy, qz);
        let norm = q.norm();
        if !(0.9..=1.1).contains(&norm) {
            return Err(fields.error(format!(
                "quaternion ({qx}, {qy}, {qz}, {qw}) has norm {norm}, not 1"
            )));
        }
        let rotation = UnitQuaternion::from_quaternion(q).to_rotation_matrix();
        poses.push(StampedPose {
            time,
            pose: Pose3::from_rotation(Vector3::new(tx, ty, tz), rotation.matrix()),
        });
    }
    Ok(poses)
}

/// The TUM text of a trajectory, with a header comment.
pub fn tum_text(poses: &[StampedPose]) -> String {
    let mut bytes = Vec::new();
    // Writing to memory cannot fail.
    let _ = write_tum_lines(&mut bytes, poses);
    String::from_utf8(bytes).unwrap_or_default()
}

/// Writes the TUM text of a trajectory (with its header comment) to `out`, line by line.
fn write_tum_lines(out: &mut dyn Write, poses: &[StampedPose]) -> std::io::Result<()> {
    writeln!(out, "# timestamp tx ty tz qx qy qz qw")?;
    for p in poses {
        // The rotation is orthonormal by construction: no iterative re-orthonormalization.
        let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(
            p.pose.rotation(),
        ));
        let t = p.pose.translation;
        writeln!(
            out,
            "{:.6} {:.6} {:.6} {:.6} {:.9} {:.9} {:.9} {:.9}",
            p.time, t.x, t.y, t.z, q.i, q.j, q.k, q.w
        )?;
    }
    Ok(())
}

/// Writes a TUM trajectory completely or not at all ([`write_atomically_with`]), streamed:
/// no copy of the text in memory.
pub fn write_tum(path: &Path, poses: &[StampedPose]) -> Result<()> {
    write_atomically_with(path, |out| write_tum_lines(out, poses))
}

/// Writes `bytes` to `path` completely or not at all: to a temporary file beside it, then
/// renamed into place. On error the temporary file is removed and `path` is untouched.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomically_with(path, |out| out.write_all(bytes))
}

/// Writes to `path` completely or not at all, with `fill` writing the contents to a buffered
/// temporary file beside it, which is then renamed into place (a long output is streamed, not
/// built in memory first). On error the temporary file is removed and `path` is untouched.
pub fn write_atomically_with(
    path: &Path,
    fill: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
) -> Result<()> {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let temporary = path.with_file_name(format!(".{name}.partial"));
    let written = std::fs::File::create(&temporary)
        .and_then(|file| {
            let mut out = std::io::BufWriter::new(file);
            fill(&mut out)?;
            out.flush()
        })
        .and_then(|()| std::fs::rename(&temporary, path));
    written.map_err(|e| {
        let _ = std::fs::remove_file(&temporary);
        SensorError::io(path, e)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::test_dir;
    use slam_core::Pose2;

    #[test]
    fn round_trip_keeps_poses() {
        let dir = test_dir("tum-round-trip");
        let path = dir.path().join("t.tum");
        let poses: Vec<_> = (0..20)
            .map(|k| StampedPose {
                time: k as f64 * 0.1,
                pose: Pose2::new(k as f64, -0.5 * k as f64, 0.4 * k as f64 - 3.0).to_pose3(0.0),
            })
            .collect();
        write_tum(&path, &poses).unwrap();
        let back = read_tum(&path).unwrap();
        assert_eq!(back.len(), poses.len());
        for (a, b) in poses.iter().zip(&back) {
            assert!((a.time - b.time).abs() < 1e-9);
            assert!((a.pose.translation - b.pose.translation).norm() < 1e-6);
            assert!((a.pose.rotation() - b.pose.rotation()).amax() < 1e-8);
        }
    }

    #[test]
    fn malformed_lines_name_file_and_line() {
        let dir = test_dir("tum-malformed");
        let cases = [
            ("0 1 2 3 0 0 0\n", "expected 8 fields"),
            ("# c\n0 1 2 3 0 0 0 x\n", "expected a number"),
            ("0 1 2 3 0 0 0 nan\n", "not finite"),
            ("0 1 2 3 0 0 0 2\n", "norm"),
        ];
        for (k, (text, reason)) in cases.iter().enumerate() {
            let path = dir.path().join(format!("bad{k}.tum"));
            std::fs::write(&path, text).unwrap();
            let error = read_tum(&path).unwrap_err().to_string();
            let line = text.lines().count();
            assert!(
                error.contains(&format!("bad{k}.tum:{line}:")) && error.contains(reason),
                "{error}"
            );
        }
    }

    #[test]
    fn atomic_write_leaves_no_partial_file() {
        let dir = test_dir("tum-atomic");
        let missing_folder = dir.path().join("no-such-folder").join("t.tum");
        assert!(write_tum(&missing_folder, &[]).is_err());
        assert!(!missing_folder.exists());
        let path = dir.path().join("ok.tum");
        write_tum(&path, &[]).unwrap();
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, vec![std::ffi::OsString::from("ok.tum")]);
    }
}
