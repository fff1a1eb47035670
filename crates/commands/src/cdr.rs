//! CDR (XCDR version 1, little or big endian) for the messages of the command path: decoding
//! `ether_ros_msgs/WriteVariable` and `sensor_msgs/JointState` (`joint_commands`), encoding
//! `ether_ros_msgs/WriteResult`.
//!
//! Layout rules (OMG DDS-XTypes, encapsulation CDR_LE/CDR_BE as ROS 2's rmw implementations
//! use it): a 4-byte encapsulation header, then the fields in order, each primitive aligned to
//! its size (8-byte types to 8) relative to the end of the header; a string is a u32 length that
//! counts the terminating NUL, then the bytes and the NUL; a sequence is a u32 count, then its
//! elements (an empty sequence adds no alignment padding). Padding bytes carry no meaning (Fast
//! DDS leaves them uninitialised), so they are skipped, never checked.

use std::fmt;

/// A decoded `WriteVariable` (see interfaces/ether_ros_msgs/msg/WriteVariable.msg). The strings
/// borrow from the serialized buffer.
#[derive(Debug, Clone, PartialEq)]
pub struct WriteRequest<'a> {
    /// Target slave by name (empty: by `position`, or all slaves).
    pub slave: &'a str,
    /// Target slave by bus position, used when `slave` is empty (-1: none given).
    pub position: i32,
    /// Write the variable on every slave that has it, not one.
    pub all_slaves: bool,
    /// The variable by name (`a_ellipse100`) or by object (`0x7000:0d`, hexadecimal).
    pub variable: &'a str,
    /// The numeric value to write (ignored when `text` is set).
    pub value: f64,
    /// The value as text (`true`, `0x1F`, `-12`), which wins over `value` when not empty.
    pub text: &'a str,
    /// Echoed in the `write_results` answer so the caller can match it to this request.
    pub request_id: u32,
}

/// Why a buffer is not a `WriteVariable` this decoder understands.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CdrError {
    /// Fewer bytes than the field at `offset` needs.
    Truncated {
        /// Which field was cut short.
        field: &'static str,
        /// Byte offset at which the field starts.
        offset: usize,
    },
    /// The encapsulation header names a representation other than plain CDR.
    Encapsulation(u16),
    /// A string that is not NUL-terminated or not UTF-8.
    BadString {
        /// Which string field is malformed.
        field: &'static str,
    },
    /// A string with a NUL before its end: C code (rclpy's conversion to Python, any
    /// `strlen`) would see only the part before it, so `Kp100_knee\0junk` would act on
    /// `Kp100_knee`. Refused, never truncated.
    EmbeddedNul {
        /// Which string field holds the NUL.
        field: &'static str,
        /// Byte index of the NUL within the string.
        at: usize,
    },
}

impl fmt::Display for CdrError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CdrError::Truncated { field, offset } => {
                write!(f, "message ends inside field '{field}' (at byte {offset})")
            }
            CdrError::Encapsulation(id) => write!(f, "unsupported CDR encapsulation 0x{id:04x}"),
            CdrError::BadString { field } => {
                write!(f, "field '{field}' is not a NUL-terminated UTF-8 string")
            }
            CdrError::EmbeddedNul { field, at } => {
                write!(f, "field '{field}' holds a NUL at byte {at}")
            }
        }
    }
}

impl std::error::Error for CdrError {}

const HEADER: usize = 4;
const CDR_BE: u16 = 0x0000;
const CDR_LE: u16 = 0x0001;

struct Reader<'a> {
    body: &'a [u8],
    pos: usize,
    little: bool,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize, align: usize, field: &'static str) -> Result<&'a [u8], CdrError> {
        let start = self.pos.next_multiple_of(align);
        let end = start.checked_add(n).filter(|&e| e <= self.body.len());
        let Some(end) = end else {
            return Err(CdrError::Truncated {
                field,
                offset: HEADER + start,
            });
        };
        self.pos = end;
        Ok(&self.body[start..end])
    }

    fn array<const N: usize>(&mut self, field: &'static str) -> Result<[u8; N], CdrError> {
        let mut b: [u8; N] = self.take(N, N, field)?.try_into().expect("length checked");
        if !self.little {
            b.reverse();
        }
        Ok(b)
    }

    fn u32(&mut self, field: &'static str) -> Result<u32, CdrError> {
        Ok(u32::from_le_bytes(self.array(field)?))
    }

    fn i32(&mut self, field: &'static str) -> Result<i32, CdrError> {
        Ok(i32::from_le_bytes(self.array(field)?))
    }

    fn f64(&mut self, field: &'static str) -> Result<f64, CdrError> {
        Ok(f64::from_le_bytes(self.array(field)?))
    }

    fn bool(&mut self, field: &'static str) -> Result<bool, CdrError> {
        Ok(self.take(1, 1, field)?[0] != 0)
    }

    /// Step over a string by its length alone (its bytes unchecked).
    fn skip_string(&mut self, field: &'static str) -> Result<(), CdrError> {
        let len = self.u32(field)? as usize;
        self.take(len, 1, field).map(|_| ())
    }

    fn string(&mut self, field: &'static str) -> Result<&'a str, CdrError> {
        let len = self.u32(field)? as usize;
        if len == 0 {
            return Ok(""); // some writers encode the empty string without its NUL
        }
        let bytes = self.take(len, 1, field)?;
        let (nul, text) = bytes.split_last().expect("len > 0");
        if *nul != 0 {
            return Err(CdrError::BadString { field });
        }
        if let Some(at) = text.iter().position(|&b| b == 0) {
            return Err(CdrError::EmbeddedNul { field, at });
        }
        std::str::from_utf8(text).map_err(|_| CdrError::BadString { field })
    }
}

/// A reader over the body of `data`, after checking its encapsulation header.
fn reader(data: &[u8]) -> Result<Reader<'_>, CdrError> {
    if data.len() < HEADER {
        return Err(CdrError::Truncated {
            field: "encapsulation header",
            offset: 0,
        });
    }
    let id = u16::from_be_bytes([data[0], data[1]]);
    let little = match id {
        CDR_LE => true,
        CDR_BE => false,
        other => return Err(CdrError::Encapsulation(other)),
    };
    Ok(Reader {
        body: &data[HEADER..],
        pos: 0,
        little,
    })
}

/// Decode a serialized `WriteVariable` (with its encapsulation header).
pub fn decode_write_variable(data: &[u8]) -> Result<WriteRequest<'_>, CdrError> {
    let mut r = reader(data)?;
    Ok(WriteRequest {
        slave: r.string("slave")?,
        position: r.i32("position")?,
        all_slaves: r.bool("all_slaves")?,
        variable: r.string("variable")?,
        value: r.f64("value")?,
        text: r.string("text")?,
        request_id: r.u32("request_id")?,
    })
}

/// The `request_id` of a serialized `WriteVariable` whose strings may be bad (a NUL inside, not
/// UTF-8): the fields are stepped over by their lengths, so that a refusal can still be answered
/// to its request, as rclpy reads it. None when even the lengths do not fit.
pub fn write_variable_request_id(data: &[u8]) -> Option<u32> {
    let mut r = reader(data).ok()?;
    r.skip_string("slave").ok()?;
    r.i32("position").ok()?;
    r.bool("all_slaves").ok()?;
    r.skip_string("variable").ok()?;
    r.f64("value").ok()?;
    r.skip_string("text").ok()?;
    r.u32("request_id").ok()
}

/// A `sequence<float64>` of a serialized message, read in place (no copy, no allocation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct F64Seq<'a> {
    bytes: &'a [u8],
    little: bool,
}

impl F64Seq<'_> {
    /// Number of `f64` elements (the byte length over 8).
    pub fn len(&self) -> usize {
        self.bytes.len() / 8
    }

    /// True when the sequence has no element (an unset `position`/`velocity`/`effort`).
    pub fn is_empty(&self) -> bool {
        self.bytes.is_empty()
    }

    /// Element `i` (< len).
    pub fn get(&self, i: usize) -> f64 {
        let mut b: [u8; 8] = self.bytes[i * 8..i * 8 + 8].try_into().expect("8 bytes");
        if !self.little {
            b.reverse();
        }
        f64::from_le_bytes(b)
    }
}

/// A decoded `sensor_msgs/JointState` as `joint_commands` carries it; the names are in the
/// vector given to [`decode_joint_state`].
#[derive(Debug, Clone, PartialEq)]
pub struct JointCommand<'a> {
    /// Header stamp, seconds: with `stamp_nanosec`, when the publisher sent it.
    pub stamp_sec: i32,
    /// Header stamp, nanoseconds within `stamp_sec`.
    pub stamp_nanosec: u32,
    /// Header frame id; not used for control, kept so a log can show it.
    pub frame_id: &'a str,
    /// Target positions per joint (rad or m), empty when not commanded.
    pub position: F64Seq<'a>,
    /// Target velocities per joint, empty when not commanded.
    pub velocity: F64Seq<'a>,
    /// Target efforts (torques) per joint, empty when not commanded.
    pub effort: F64Seq<'a>,
}

impl<'a> Reader<'a> {
    fn count(&mut self, field: &'static str) -> Result<usize, CdrError> {
        Ok(self.u32(field)? as usize)
    }

    fn f64_seq(&mut self, field: &'static str) -> Result<F64Seq<'a>, CdrError> {
        let n = self.count(field)?;
        let little = self.little;
        if n == 0 {
            return Ok(F64Seq { bytes: &[], little });
        }
        let len = n.checked_mul(8).ok_or(CdrError::Truncated {
            field,
            offset: HEADER + self.pos,
        })?;
        Ok(F64Seq {
            bytes: self.take(len, 8, field)?,
            little,
        })
    }
}

/// Decode a serialized `sensor_msgs/JointState` (header, name[], position[], velocity[],
/// effort[]); the joint names go into `names` (cleared first, reused between messages).
pub fn decode_joint_state<'a>(
    data: &'a [u8],
    names: &mut Vec<&'a str>,
) -> Result<JointCommand<'a>, CdrError> {
    names.clear();
    let mut r = reader(data)?;
    let stamp_sec = r.i32("header.stamp.sec")?;
    let stamp_nanosec = r.u32("header.stamp.nanosec")?;
    let frame_id = r.string("header.frame_id")?;
    let n = r.count("name")?;
    for _ in 0..n {
        // Each string takes at least its 4-byte length, so a bogus count ends in Truncated
        // after at most len/4 names, never in a huge allocation.
        names.push(r.string("name")?);
    }
    Ok(JointCommand {
        stamp_sec,
        stamp_nanosec,
        frame_id,
        position: r.f64_seq("position")?,
        velocity: r.f64_seq("velocity")?,
        effort: r.f64_seq("effort")?,
    })
}

/// Check a serialized `trajectory_msgs/JointTrajectory` (header, joint_names[], points[] of
/// positions[], velocities[], accelerations[], effort[], time_from_start) without keeping it:
/// every string whole (no NUL inside, UTF-8) and every sequence inside the buffer. Python
/// handles the trajectory itself; this only tells it whether rclpy's copy can be trusted.
pub fn check_joint_trajectory(data: &[u8]) -> Result<(), CdrError> {
    let mut r = reader(data)?;
    r.i32("header.stamp.sec")?;
    r.u32("header.stamp.nanosec")?;
    r.string("header.frame_id")?;
    for _ in 0..r.count("joint_names")? {
        r.string("joint_names")?;
    }
    for _ in 0..r.count("points")? {
        // Each point takes at least 24 bytes, so a bogus count ends in Truncated.
        r.f64_seq("points.positions")?;
        r.f64_seq("points.velocities")?;
        r.f64_seq("points.accelerations")?;
        r.f64_seq("points.effort")?;
        r.i32("points.time_from_start.sec")?;
        r.u32("points.time_from_start.nanosec")?;
    }
    Ok(())
}

/// Encode a `WriteResult` (request_id, success, message) into `out` (cleared first), little
/// endian, with its encapsulation header.
pub fn encode_write_result(out: &mut Vec<u8>, request_id: u32, success: bool, message: &str) {
    out.clear();
    out.extend_from_slice(&[0x00, 0x01, 0x00, 0x00]);
    out.extend_from_slice(&request_id.to_le_bytes());
    out.push(u8::from(success));
    // The string length is a u32 aligned to 4 within the body (body offset 5 -> 8).
    while !(out.len() - HEADER).is_multiple_of(4) {
        out.push(0);
    }
    out.extend_from_slice(&(message.len() as u32 + 1).to_le_bytes());
    out.extend_from_slice(message.as_bytes());
    out.push(0);
}

#[cfg(test)]
mod tests {
    use super::*;

    // Serialized by rclpy (Fast DDS) for WriteVariable(slave='ab', position=3, all_slaves=True,
    // variable='xyz', value=1.5, text='', request_id=7); its padding bytes are garbage.
    const FROM_RCLPY: &str =
        "00 01 00 00 03 00 00 00 61 62 00 00 03 00 00 00 01 73 67 3a 04 00 00 \
        00 78 79 7a 00 00 00 00 00 00 00 f8 3f 01 00 00 00 00 00 72 74 07 00 00 00";

    fn hex(s: &str) -> Vec<u8> {
        s.split_whitespace()
            .map(|b| u8::from_str_radix(b, 16).unwrap())
            .collect()
    }

    #[test]
    fn decodes_what_rclpy_serializes() {
        let data = hex(FROM_RCLPY);
        let r = decode_write_variable(&data).unwrap();
        assert_eq!(
            r,
            WriteRequest {
                slave: "ab",
                position: 3,
                all_slaves: true,
                variable: "xyz",
                value: 1.5,
                text: "",
                request_id: 7
            }
        );
    }

    #[test]
    fn the_request_id_of_a_message_with_a_bad_string_is_still_read() {
        let mut data = hex(FROM_RCLPY);
        // variable 'xyz' → 'x\0z': refused, but its request is known.
        let at = data.windows(3).position(|w| w == b"xyz").unwrap();
        data[at + 1] = 0;
        assert!(matches!(
            decode_write_variable(&data),
            Err(CdrError::EmbeddedNul {
                field: "variable",
                at: 1
            })
        ));
        assert_eq!(write_variable_request_id(&data), Some(7));
        assert_eq!(write_variable_request_id(&data[..data.len() - 1]), None);
    }

    #[test]
    fn every_truncation_is_an_error_naming_the_field() {
        let data = hex(FROM_RCLPY);
        for n in 0..data.len() {
            let e = decode_write_variable(&data[..n]).unwrap_err();
            assert!(matches!(e, CdrError::Truncated { .. }), "{n}: {e}");
        }
        let e = decode_write_variable(&data[..30]).unwrap_err();
        assert_eq!(
            e.to_string(),
            "message ends inside field 'value' (at byte 28)"
        );
    }

    #[test]
    fn rejects_strings_without_nul_and_other_encapsulations() {
        let mut data = hex(FROM_RCLPY);
        data[10] = b'c'; // the NUL of "ab"
        assert_eq!(
            decode_write_variable(&data),
            Err(CdrError::BadString { field: "slave" })
        );
        let mut data = hex(FROM_RCLPY);
        data[1] = 0x03; // PL_CDR_LE
        assert_eq!(
            decode_write_variable(&data),
            Err(CdrError::Encapsulation(3))
        );
    }

    /// A WriteVariable as rclpy serializes it, with `slave` and `variable` given as raw bytes
    /// (so they may hold a NUL), little endian.
    fn write_variable(slave: &[u8], variable: &[u8]) -> Vec<u8> {
        fn string(b: &mut Vec<u8>, s: &[u8]) {
            while !(b.len() - HEADER).is_multiple_of(4) {
                b.push(0);
            }
            b.extend_from_slice(&(s.len() as u32 + 1).to_le_bytes());
            b.extend_from_slice(s);
            b.push(0);
        }
        let mut b = vec![0x00, 0x01, 0x00, 0x00];
        string(&mut b, slave);
        while !(b.len() - HEADER).is_multiple_of(4) {
            b.push(0);
        }
        b.extend_from_slice(&(-1i32).to_le_bytes());
        b.push(0); // all_slaves
        string(&mut b, variable);
        while !(b.len() - HEADER).is_multiple_of(8) {
            b.push(0);
        }
        b.extend_from_slice(&1.0f64.to_le_bytes());
        string(&mut b, b"");
        while !(b.len() - HEADER).is_multiple_of(4) {
            b.push(0);
        }
        b.extend_from_slice(&5u32.to_le_bytes());
        b
    }

    #[test]
    fn an_embedded_nul_is_refused_not_truncated() {
        let ok = write_variable(b"leg", b"Kp100_knee");
        let r = decode_write_variable(&ok).unwrap();
        assert_eq!(
            (r.slave, r.variable, r.request_id),
            ("leg", "Kp100_knee", 5)
        );
        let e = decode_write_variable(&write_variable(b"leg", b"Kp100_knee\0junk")).unwrap_err();
        assert_eq!(
            e,
            CdrError::EmbeddedNul {
                field: "variable",
                at: 10
            }
        );
        assert_eq!(e.to_string(), "field 'variable' holds a NUL at byte 10");
        let e = decode_write_variable(&write_variable(b"\0leg", b"x")).unwrap_err();
        assert_eq!(
            e,
            CdrError::EmbeddedNul {
                field: "slave",
                at: 0
            }
        );
    }

    #[test]
    fn a_joint_name_with_a_nul_is_refused() {
        // JOINTS_FROM_RCLPY with the name "a" made "a\0b" (length 4, then padding).
        let mut data = hex(JOINTS_FROM_RCLPY)[..24].to_vec();
        data.extend_from_slice(&4u32.to_le_bytes());
        data.extend_from_slice(b"a\0b\0");
        let mut names = Vec::new();
        assert_eq!(
            decode_joint_state(&data, &mut names),
            Err(CdrError::EmbeddedNul {
                field: "name",
                at: 1
            })
        );
    }

    #[test]
    fn decodes_big_endian() {
        let mut b = vec![0x00, 0x00, 0x00, 0x00];
        b.extend_from_slice(&2u32.to_be_bytes());
        b.extend_from_slice(b"a\0\0\0");
        b.extend_from_slice(&(-1i32).to_be_bytes());
        b.extend_from_slice(&[0, 0, 0, 0]); // bool + pad to 4
        b.extend_from_slice(&2u32.to_be_bytes());
        b.extend_from_slice(b"v\0");
        b.extend_from_slice(&[0; 2]); // pad to 8 (body offset 22 -> 24)
        b.extend_from_slice(&(-2.25f64).to_be_bytes());
        b.extend_from_slice(&1u32.to_be_bytes());
        b.extend_from_slice(b"\0\0\0\0");
        b.extend_from_slice(&9u32.to_be_bytes());
        let r = decode_write_variable(&b).unwrap();
        assert_eq!((r.slave, r.position, r.all_slaves), ("a", -1, false));
        assert_eq!(
            (r.variable, r.value, r.text, r.request_id),
            ("v", -2.25, "", 9)
        );
    }

    // Serialized by rclpy: JointState(header.frame_id='f', name=['a'], position=[],
    // velocity=[1.0], effort=[]); padding bytes are garbage, 4 trailing bytes of padding.
    const JOINTS_FROM_RCLPY: &str =
        "00 01 00 00 00 00 00 00 00 00 00 00 02 00 00 00 66 00 f4 00 01 00 00 00 02 00 00 00 \
        61 00 f0 00 00 00 00 00 01 00 00 00 01 24 73 12 00 00 00 00 00 00 f0 3f 00 00 00 00 \
        42 11 03 c2";

    #[test]
    fn decodes_a_joint_state_as_rclpy_serializes_it() {
        let data = hex(JOINTS_FROM_RCLPY);
        let mut names = Vec::new();
        let j = decode_joint_state(&data, &mut names).unwrap();
        assert_eq!(names, ["a"]);
        assert_eq!((j.stamp_sec, j.stamp_nanosec, j.frame_id), (0, 0, "f"));
        assert!(j.position.is_empty() && j.effort.is_empty());
        assert_eq!((j.velocity.len(), j.velocity.get(0)), (1, 1.0));
        for n in 0..52 {
            let e = decode_joint_state(&data[..n], &mut names).unwrap_err();
            assert!(matches!(e, CdrError::Truncated { .. }), "{n}: {e}");
        }
    }

    #[test]
    fn a_huge_name_count_is_truncated_not_allocated() {
        let mut data = hex(JOINTS_FROM_RCLPY);
        data[20..24].copy_from_slice(&u32::MAX.to_le_bytes());
        let mut names = Vec::new();
        assert!(matches!(
            decode_joint_state(&data, &mut names),
            Err(CdrError::Truncated { field: "name", .. } | CdrError::BadString { field: "name" })
        ));
        assert!(names.len() < 16);
    }

    #[test]
    fn encodes_write_result_as_rclpy_does() {
        // rclpy: WriteResult(request_id=7, success=True, message='ok')
        let mut out = Vec::new();
        encode_write_result(&mut out, 7, true, "ok");
        assert_eq!(
            out,
            hex("00 01 00 00 07 00 00 00 01 00 00 00 03 00 00 00 6f 6b 00")
        );
    }
}
