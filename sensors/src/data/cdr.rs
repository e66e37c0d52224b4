//! A small decoder of the ROS 2 messages the MCAP reader needs, in CDR (XCDR1, the encoding of
//! ROS 2 bags): `sensor_msgs/msg/LaserScan`, `nav_msgs/msg/Odometry`,
//! `geometry_msgs/msg/PoseStamped` and `tf2_msgs/msg/TFMessage`.
//!
//! A message is a 4-byte encapsulation header (`00 01`: little endian, `00 00`: big endian; two
//! option bytes) followed by the payload. Primitives are aligned to their size (4 or 8 bytes)
//! relative to the start of the payload; a string is a `uint32` length that counts its
//! terminating NUL, then its bytes; a sequence is a `uint32` count, then its elements.
//!
//! Every error says what was being read and at which payload offset; nothing panics on
//! malformed bytes and no sequence is allocated before its bytes are known to be there.

/// A decoding error: what was wrong, at which payload offset.
pub(crate) type CdrResult<T> = std::result::Result<T, String>;

/// Bytes after a message's last field that are taken as padding.
const MAX_PADDING: usize = 3;

/// A cursor over one CDR payload.
pub(crate) struct Cdr<'a> {
    payload: &'a [u8],
    pos: usize,
    little: bool,
}

impl<'a> Cdr<'a> {
    /// The payload of `bytes` after its encapsulation header.
    pub(crate) fn new(bytes: &'a [u8]) -> CdrResult<Self> {
        let Some((header, payload)) = bytes.split_first_chunk::<4>() else {
            return Err(format!(
                "truncated: {} bytes, shorter than the 4-byte CDR encapsulation header",
                bytes.len()
            ));
        };
        let little = match [header[0], header[1]] {
            [0, 1] => true,
            [0, 0] => false,
            [0, 2] | [0, 3] => {
                return Err(
                    "parameter-list CDR (PL_CDR) is not supported: ROS 2 messages are plain CDR"
                        .into(),
                );
            }
            [a, b] => {
                return Err(format!(
                    "unknown CDR encapsulation {a:02x} {b:02x} (expected 00 01 or 00 00)"
                ));
            }
        };
        Ok(Cdr {
            payload,
            pos: 0,
            little,
        })
    }

    /// The next `n` bytes, aligned to `align` first.
    fn take(&mut self, n: usize, align: usize, what: &str) -> CdrResult<&'a [u8]> {
        let start = self.pos.next_multiple_of(align);
        match start.checked_add(n) {
            Some(end) if end <= self.payload.len() => {
                self.pos = end;
                Ok(&self.payload[start..end])
            }
            _ => Err(format!(
                "truncated: {what} needs {n} bytes at payload offset {start}, the payload has {}",
                self.payload.len()
            )),
        }
    }

    fn array<const N: usize>(&mut self, what: &str) -> CdrResult<[u8; N]> {
        let bytes = self.take(N, N, what)?;
        let mut out = [0u8; N];
        out.copy_from_slice(bytes);
        if !self.little {
            out.reverse();
        }
        Ok(out)
    }

    /// A `uint32`.
    pub(crate) fn u32(&mut self, what: &str) -> CdrResult<u32> {
        self.array::<4>(what).map(u32::from_le_bytes)
    }

    /// An `int32`.
    pub(crate) fn i32(&mut self, what: &str) -> CdrResult<i32> {
        self.array::<4>(what).map(i32::from_le_bytes)
    }

    /// A `float32`.
    pub(crate) fn f32(&mut self, what: &str) -> CdrResult<f32> {
        self.array::<4>(what).map(f32::from_le_bytes)
    }

    /// A `float64`.
    pub(crate) fn f64(&mut self, what: &str) -> CdrResult<f64> {
        self.array::<8>(what).map(f64::from_le_bytes)
    }

    /// `N` `float64`s (a fixed-size array: no count).
    pub(crate) fn f64s<const N: usize>(&mut self, what: &str) -> CdrResult<[f64; N]> {
        let mut out = [0.0; N];
        for value in &mut out {
            *value = self.f64(what)?;
        }
        Ok(out)
    }

    /// A sequence count, checked against the bytes left for `element_size`-byte elements.
    fn count(&mut self, element_size: usize, what: &str) -> CdrResult<usize> {
        let at = self.pos.next_multiple_of(4);
        let n = self.u32(what)? as usize;
        let left = self.payload.len().saturating_sub(self.pos);
        if n.checked_mul(element_size).is_none_or(|bytes| bytes > left) {
            return Err(format!(
                "truncated: {what} announces {n} elements at payload offset {at}, only {left} \
                 bytes follow"
            ));
        }
        Ok(n)
    }

    /// A `string` (length with its NUL, then the bytes).
    pub(crate) fn string(&mut self, what: &str) -> CdrResult<String> {
        let n = self.count(1, what)?;
        if n == 0 {
            // Some writers encode the empty string without its NUL.
            return Ok(String::new());
        }
        let at = self.pos;
        let bytes = self.take(n, 1, what)?;
        let (last, text) = bytes.split_last().unwrap_or((&0, &[]));
        if *last != 0 {
            return Err(format!(
                "{what} at payload offset {at} does not end with NUL: is the schema right?"
            ));
        }
        String::from_utf8(text.to_vec())
            .map_err(|_| format!("{what} at payload offset {at} is not UTF-8"))
    }

    /// A `float32[]` sequence.
    pub(crate) fn f32_sequence(&mut self, what: &str) -> CdrResult<Vec<f32>> {
        let n = self.count(4, what)?;
        (0..n).map(|_| self.f32(what)).collect()
    }

    /// Fails when more than a few padding bytes follow the last field (another message type
    /// than the schema says).
    pub(crate) fn finish(&self, message: &str) -> CdrResult<()> {
        let left = self.payload.len() - self.pos;
        if left > MAX_PADDING {
            return Err(format!(
                "{left} bytes left after the last field of a {message}: is the schema right?"
            ));
        }
        Ok(())
    }
}

/// `std_msgs/msg/Header`.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Header {
    /// The stamp, seconds.
    pub stamp: f64,
    /// The frame the data are in.
    pub frame_id: String,
}

fn header(c: &mut Cdr) -> CdrResult<Header> {
    let sec = c.i32("header.stamp.sec")?;
    let nanosec = c.u32("header.stamp.nanosec")?;
    let frame_id = c.string("header.frame_id")?;
    Ok(Header {
        // Divided (correctly rounded), so that 0.204947 s comes back as 0.204947.
        stamp: f64::from(sec) + f64::from(nanosec) / 1e9,
        frame_id,
    })
}

/// `geometry_msgs/msg/Pose` (or a `Transform`): position and orientation `(x, y, z, w)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct PoseMsg {
    /// Position, m.
    pub position: [f64; 3],
    /// Unit quaternion `(x, y, z, w)`.
    pub orientation: [f64; 4],
}

impl PoseMsg {
    /// The rotation about z of the orientation (the heading of a planar robot), radians.
    pub(crate) fn yaw(&self) -> f64 {
        let [x, y, z, w] = self.orientation;
        f64::atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    }
}

fn pose(c: &mut Cdr, what: &str) -> CdrResult<PoseMsg> {
    Ok(PoseMsg {
        position: c.f64s(what)?,
        orientation: c.f64s(what)?,
    })
}

/// `sensor_msgs/msg/LaserScan`.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct LaserScanMsg {
    pub header: Header,
    pub angle_min: f32,
    pub angle_max: f32,
    pub angle_increment: f32,
    pub range_min: f32,
    pub range_max: f32,
    pub ranges: Vec<f32>,
}

/// Decodes a `sensor_msgs/msg/LaserScan`.
pub(crate) fn laser_scan(bytes: &[u8]) -> CdrResult<LaserScanMsg> {
    let mut c = Cdr::new(bytes)?;
    let header = header(&mut c)?;
    let angle_min = c.f32("angle_min")?;
    let angle_max = c.f32("angle_max")?;
    let angle_increment = c.f32("angle_increment")?;
    c.f32("time_increment")?;
    c.f32("scan_time")?;
    let range_min = c.f32("range_min")?;
    let range_max = c.f32("range_max")?;
    let ranges = c.f32_sequence("ranges")?;
    c.f32_sequence("intensities")?;
    c.finish("LaserScan")?;
    Ok(LaserScanMsg {
        header,
        angle_min,
        angle_max,
        angle_increment,
        range_min,
        range_max,
        ranges,
    })
}

/// A stamped pose: `nav_msgs/msg/Odometry` (its pose) or `geometry_msgs/msg/PoseStamped`.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct StampedPoseMsg {
    pub header: Header,
    pub pose: PoseMsg,
}

/// Decodes a `nav_msgs/msg/Odometry` (header, child frame, pose with covariance, twist with
/// covariance); the twist and the covariances are read and dropped.
pub(crate) fn odometry(bytes: &[u8]) -> CdrResult<StampedPoseMsg> {
    let mut c = Cdr::new(bytes)?;
    let header = header(&mut c)?;
    c.string("child_frame_id")?;
    let pose = pose(&mut c, "pose.pose")?;
    c.f64s::<36>("pose.covariance")?;
    c.f64s::<6>("twist.twist")?;
    c.f64s::<36>("twist.covariance")?;
    c.finish("Odometry")?;
    Ok(StampedPoseMsg { header, pose })
}

/// Decodes a `geometry_msgs/msg/PoseStamped`.
pub(crate) fn pose_stamped(bytes: &[u8]) -> CdrResult<StampedPoseMsg> {
    let mut c = Cdr::new(bytes)?;
    let header = header(&mut c)?;
    let pose = pose(&mut c, "pose")?;
    c.finish("PoseStamped")?;
    Ok(StampedPoseMsg { header, pose })
}

/// One `geometry_msgs/msg/TransformStamped`: `parent_from_child`.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct TransformMsg {
    /// The parent frame (`header.frame_id`).
    pub parent: String,
    /// The child frame.
    pub child: String,
    /// The child frame's pose in the parent frame.
    pub parent_from_child: PoseMsg,
}

/// Decodes a `tf2_msgs/msg/TFMessage`.
pub(crate) fn tf_message(bytes: &[u8]) -> CdrResult<Vec<TransformMsg>> {
    let mut c = Cdr::new(bytes)?;
    // A TransformStamped takes at least 4 + 4 + 4 + 4 + 56 bytes.
    let n = c.count(72, "transforms")?;
    let mut transforms = Vec::with_capacity(n);
    for _ in 0..n {
        let header = header(&mut c)?;
        let child = c.string("child_frame_id")?;
        let parent_from_child = pose(&mut c, "transform")?;
        transforms.push(TransformMsg {
            parent: header.frame_id,
            child,
            parent_from_child,
        });
    }
    c.finish("TFMessage")?;
    Ok(transforms)
}

/// Hand-made CDR payloads, for the tests of this module and of the MCAP reader.
#[cfg(test)]
pub(crate) mod build {
    /// A CDR writer with the alignment rules of [`super::Cdr`].
    pub(crate) struct Builder {
        pub bytes: Vec<u8>,
        little: bool,
    }

    impl Builder {
        pub(crate) fn new(little: bool) -> Self {
            Builder {
                bytes: vec![0, u8::from(little), 0, 0],
                little,
            }
        }
        fn align(&mut self, n: usize) {
            while !(self.bytes.len() - 4).is_multiple_of(n) {
                self.bytes.push(0);
            }
        }
        fn put<const N: usize>(&mut self, mut le: [u8; N]) -> &mut Self {
            self.align(N);
            if !self.little {
                le.reverse();
            }
            self.bytes.extend_from_slice(&le);
            self
        }
        pub(crate) fn u32(&mut self, v: u32) -> &mut Self {
            self.put(v.to_le_bytes())
        }
        pub(crate) fn i32(&mut self, v: i32) -> &mut Self {
            self.put(v.to_le_bytes())
        }
        pub(crate) fn f32(&mut self, v: f32) -> &mut Self {
            self.put(v.to_le_bytes())
        }
        pub(crate) fn f64(&mut self, v: f64) -> &mut Self {
            self.put(v.to_le_bytes())
        }
        pub(crate) fn string(&mut self, s: &str) -> &mut Self {
            self.u32(s.len() as u32 + 1);
            self.bytes.extend_from_slice(s.as_bytes());
            self.bytes.push(0);
            self
        }
        pub(crate) fn header(&mut self, sec: i32, nanosec: u32, frame: &str) -> &mut Self {
            self.i32(sec).u32(nanosec).string(frame)
        }
        pub(crate) fn pose(&mut self, xyz: [f64; 3], yaw: f64) -> &mut Self {
            for v in xyz {
                self.f64(v);
            }
            let (s, c) = (0.5 * yaw).sin_cos();
            self.f64(0.0).f64(0.0).f64(s).f64(c)
        }
    }

    /// A LaserScan message.
    pub(crate) fn laser_scan(
        little: bool,
        stamp: (i32, u32),
        frame: &str,
        angles: [f32; 3],
        limits: [f32; 2],
        ranges: &[f32],
    ) -> Vec<u8> {
        let mut b = Builder::new(little);
        b.header(stamp.0, stamp.1, frame);
        for v in angles {
            b.f32(v);
        }
        b.f32(0.0).f32(0.0).f32(limits[0]).f32(limits[1]);
        b.u32(ranges.len() as u32);
        for &r in ranges {
            b.f32(r);
        }
        b.u32(0);
        b.bytes
    }

    /// An Odometry message at `(x, y, yaw)`.
    pub(crate) fn odometry(little: bool, stamp: (i32, u32), pose: [f64; 3]) -> Vec<u8> {
        let mut b = Builder::new(little);
        b.header(stamp.0, stamp.1, "odom").string("base_link");
        b.pose([pose[0], pose[1], 0.0], pose[2]);
        for _ in 0..(36 + 6 + 36) {
            b.f64(0.0);
        }
        b.bytes
    }

    /// A PoseStamped message at `(x, y, yaw)`.
    pub(crate) fn pose_stamped(little: bool, stamp: (i32, u32), pose: [f64; 3]) -> Vec<u8> {
        let mut b = Builder::new(little);
        b.header(stamp.0, stamp.1, "map");
        b.pose([pose[0], pose[1], 0.0], pose[2]);
        b.bytes
    }

    /// A TFMessage of `(parent, child, xyz, yaw)` transforms.
    pub(crate) fn tf_message(transforms: &[(&str, &str, [f64; 3], f64)]) -> Vec<u8> {
        let mut b = Builder::new(true);
        b.u32(transforms.len() as u32);
        for (parent, child, xyz, yaw) in transforms {
            b.header(0, 0, parent).string(child).pose(*xyz, *yaw);
        }
        b.bytes
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn laser_scans_decode_in_both_byte_orders() {
        for little in [true, false] {
            let bytes = build::laser_scan(
                little,
                (12, 500_000_000),
                "laser",
                [-1.5, 1.5, 0.75],
                [0.1, 30.0],
                &[1.0, 2.5, f32::INFINITY, 4.0, 0.05],
            );
            let scan = laser_scan(&bytes).unwrap();
            assert_eq!(scan.header.stamp, 12.5);
            assert_eq!(scan.header.frame_id, "laser");
            assert_eq!(
                (scan.angle_min, scan.angle_max, scan.angle_increment),
                (-1.5, 1.5, 0.75)
            );
            assert_eq!((scan.range_min, scan.range_max), (0.1, 30.0));
            assert_eq!(scan.ranges, [1.0, 2.5, f32::INFINITY, 4.0, 0.05]);
        }
    }

    #[test]
    fn doubles_are_aligned_to_eight_bytes_of_the_payload() {
        // Header "odom" ends at payload offset 4 + 4 + 4 + 5 = 17; child "b" at 17 -> 20 + 4 + 2
        // = 26: the first double starts at 32, after 6 padding bytes.
        let mut b = build::Builder::new(true);
        b.header(1, 0, "odom").string("b");
        assert_eq!(b.bytes.len() - 4, 26);
        b.pose([1.0, 2.0, 0.0], 0.5);
        assert_eq!(&b.bytes[4 + 26..4 + 32], &[0; 6]);
        for _ in 0..78 {
            b.f64(0.0);
        }
        let odom = odometry(&b.bytes).unwrap();
        assert_eq!(odom.pose.position, [1.0, 2.0, 0.0]);
        assert!((odom.pose.yaw() - 0.5).abs() < 1e-15);
        assert_eq!(odom.header.frame_id, "odom");
        // The same bytes without the padding are misread: the doubles are off.
        let mut unpadded = b.bytes.clone();
        unpadded.drain(4 + 26..4 + 32);
        let misread = odometry(&unpadded);
        assert!(misread.is_err() || misread.unwrap().pose.position != [1.0, 2.0, 0.0]);
    }

    #[test]
    fn poses_and_transforms_decode() {
        let p = pose_stamped(&build::pose_stamped(false, (3, 0), [1.0, -2.0, 3.0])).unwrap();
        assert_eq!(p.header.stamp, 3.0);
        assert_eq!(&p.pose.position[..2], &[1.0, -2.0]);
        assert!((p.pose.yaw() - 3.0).abs() < 1e-12);
        let tf = tf_message(&build::tf_message(&[
            ("base_link", "mount", [0.5, 0.0, 0.2], 0.0),
            ("mount", "laser", [0.0, 0.1, 0.0], 1.0),
        ]))
        .unwrap();
        assert_eq!(tf.len(), 2);
        assert_eq!(
            (tf[1].parent.as_str(), tf[1].child.as_str()),
            ("mount", "laser")
        );
        assert!((tf[1].parent_from_child.yaw() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn truncated_input_is_an_error_at_every_length() {
        type Decodes = fn(&[u8]) -> bool;
        let messages: [(&str, Vec<u8>, Decodes); 4] = [
            (
                "scan",
                build::laser_scan(true, (1, 0), "l", [0.0, 1.0, 0.5], [0.0, 5.0], &[1.0; 3]),
                |b| laser_scan(b).is_ok(),
            ),
            (
                "odom",
                build::odometry(true, (1, 0), [1.0, 2.0, 3.0]),
                |b| odometry(b).is_ok(),
            ),
            (
                "pose",
                build::pose_stamped(true, (1, 0), [1.0, 2.0, 3.0]),
                |b| pose_stamped(b).is_ok(),
            ),
            ("tf", build::tf_message(&[("a", "b", [0.0; 3], 0.0)]), |b| {
                tf_message(b).is_ok()
            }),
        ];
        for (name, bytes, decodes) in messages {
            assert!(decodes(&bytes), "{name}");
            // Cutting off the last field's bytes (beyond what passes as padding) fails.
            for len in 0..bytes.len() - MAX_PADDING {
                assert!(!decodes(&bytes[..len]), "{name} cut at {len}");
            }
        }
        let e = laser_scan(&[0, 1, 0]).unwrap_err();
        assert!(
            e.contains("shorter than the 4-byte CDR encapsulation header"),
            "{e}"
        );
        let full = build::laser_scan(true, (1, 0), "l", [0.0, 1.0, 0.5], [0.0, 5.0], &[1.0; 3]);
        let e = laser_scan(&full[..full.len() - 10]).unwrap_err();
        assert!(e.starts_with("truncated: ranges"), "{e}");
    }

    #[test]
    fn huge_counts_and_bad_strings_are_errors_not_allocations() {
        let mut b = build::Builder::new(true);
        b.header(0, 0, "l");
        for _ in 0..7 {
            b.f32(1.0);
        }
        b.u32(u32::MAX);
        let e = laser_scan(&b.bytes).unwrap_err();
        assert!(e.contains("ranges announces 4294967295 elements"), "{e}");
        // A string whose last byte is not NUL.
        let mut bytes = build::pose_stamped(true, (0, 0), [0.0; 3]);
        bytes[4 + 8 + 4 + 3] = b'x';
        let e = pose_stamped(&bytes).unwrap_err();
        assert!(e.contains("header.frame_id") && e.contains("NUL"), "{e}");
    }

    #[test]
    fn wrong_schema_and_encapsulation_are_errors() {
        // An Odometry read as a LaserScan: a field or the leftover bytes give it away.
        let odom = build::odometry(true, (1, 0), [1.0, 2.0, 3.0]);
        assert!(laser_scan(&odom).is_err());
        // A PoseStamped read as an Odometry: too short.
        let pose = build::pose_stamped(true, (1, 0), [1.0, 2.0, 3.0]);
        assert!(odometry(&pose).unwrap_err().starts_with("truncated"));
        // A LaserScan read as a PoseStamped: left-over bytes.
        let scan = build::laser_scan(true, (1, 0), "l", [0.0, 1.0, 0.5], [0.0, 5.0], &[1.0; 30]);
        let e = pose_stamped(&scan).unwrap_err();
        assert!(e.contains("is the schema right?"), "{e}");
        let mut pl = pose.clone();
        pl[1] = 3;
        assert!(pose_stamped(&pl).unwrap_err().contains("PL_CDR"));
        pl[0] = 7;
        assert!(
            pose_stamped(&pl)
                .unwrap_err()
                .contains("unknown CDR encapsulation 07 03")
        );
    }
}
