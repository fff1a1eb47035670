//! CDR (XCDR version 1, little or big endian) for the two messages of the command path:
//! decoding `ether_ros_msgs/WriteVariable` and encoding `ether_ros_msgs/WriteResult`.
//!
//! Layout rules (OMG DDS-XTypes, encapsulation CDR_LE/CDR_BE as ROS 2's rmw implementations
//! use it): a 4-byte encapsulation header, then the fields in order, each primitive aligned to
//! its size (8-byte types to 8) relative to the end of the header; a string is a u32 length that
//! counts the terminating NUL, then the bytes and the NUL. Padding bytes carry no meaning (Fast
//! DDS leaves them uninitialised), so they are skipped, never checked.

use std::fmt;

/// A decoded `WriteVariable` (see interfaces/ether_ros_msgs/msg/WriteVariable.msg). The strings
/// borrow from the serialized buffer.
#[derive(Debug, Clone, PartialEq)]
pub struct WriteRequest<'a> {
    pub slave: &'a str,
    pub position: i32,
    pub all_slaves: bool,
    pub variable: &'a str,
    pub value: f64,
    pub text: &'a str,
    pub request_id: u32,
}

/// Why a buffer is not a `WriteVariable` this decoder understands.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CdrError {
    /// Fewer bytes than the field at `offset` needs.
    Truncated { field: &'static str, offset: usize },
    /// The encapsulation header names a representation other than plain CDR.
    Encapsulation(u16),
    /// A string that is not NUL-terminated or not UTF-8.
    BadString { field: &'static str },
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
        std::str::from_utf8(text).map_err(|_| CdrError::BadString { field })
    }
}

/// Decode a serialized `WriteVariable` (with its encapsulation header).
pub fn decode_write_variable(data: &[u8]) -> Result<WriteRequest<'_>, CdrError> {
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
    let mut r = Reader {
        body: &data[HEADER..],
        pos: 0,
        little,
    };
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
