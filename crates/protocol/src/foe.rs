//! File access over EtherCAT (FoE, ETG.1000.6 §5.7 / IEC 61158-6-12): the FoE header, its
//! opcodes and the error codes with their texts, and the encoding and parsing of each message.
//!
//! Layout (little endian), after the 6-byte mailbox header (type 0x04, `mailbox::TYPE_FOE`):
//! - byte 0: OpCode (1 read request, 2 write request, 3 data, 4 acknowledge, 5 error, 6 busy);
//! - byte 1: reserved (0);
//! - bytes 2..=5: by opcode the password (read and write request; 0 when none is known), the
//!   packet number (data and acknowledge; the acknowledge of a write request is packet 0, data
//!   runs from 1), the error code (error), or Done and Entire (busy, u16 each: how far the
//!   slave has got);
//! - then by opcode the file name (requests), the data (data), the error text (error,
//!   optional) or a busy text (busy, optional).
//!
//! A file is sent in data packets as long as the mailbox takes (the mailbox size less the
//! mailbox header and the FoE header); a packet shorter than that ends the file, so a file
//! whose length is a multiple of it ends with an empty packet. Every data packet is
//! acknowledged with its number; a slave may answer a data packet with busy instead, and the
//! master then sends the same packet again.
//!
//! The error codes are ETG.1000.6's table of FoE errors; 0x800C..0x800F are the later ones
//! the ETG's slave stack code (SSC 5.10 on) and vendors' firmware use.

crate::named_constants! {
    /// Header length and opcodes, by name.
    pub const TABLE;
    /// FoE header length (after the mailbox header): opcode, reserved, 32-bit field.
    pub const HEADER_LEN: usize = 6;
    /// Mailbox header and FoE header together: what a data packet takes of a mailbox beside
    /// its data.
    pub const OVERHEAD: usize = 12;
    /// OpCode: read request (RRQ), master to slave: password, file name.
    pub const OPCODE_READ: u8 = 1;
    /// OpCode: write request (WRQ), master to slave: password, file name.
    pub const OPCODE_WRITE: u8 = 2;
    /// OpCode: data, either way: packet number (from 1), data.
    pub const OPCODE_DATA: u8 = 3;
    /// OpCode: acknowledge (ACK) of a data packet or (packet 0) of a write request.
    pub const OPCODE_ACK: u8 = 4;
    /// OpCode: error (ERR), either way: error code, optional text; ends the transfer.
    pub const OPCODE_ERROR: u8 = 5;
    /// OpCode: busy, slave to master, instead of an acknowledge: Done and Entire (u16 each),
    /// optional text. The master sends the last data packet again.
    pub const OPCODE_BUSY: u8 = 6;
}

crate::coded_texts! {
    /// FoE error codes by name.
    pub const ERRORS: u32;
    /// FoE error codes (ETG.1000.6, the FoE error table; 0x800C..0x800F as the ETG's slave
    /// stack code defines them) with their texts.
    pub const ERROR_TEXTS;
    /// Not defined (see the error text).
    ERR_NOT_DEFINED = 0x8000, "not defined";
    /// The file does not exist.
    ERR_NOT_FOUND = 0x8001, "not found";
    /// The file may not be accessed.
    ERR_ACCESS_DENIED = 0x8002, "access denied";
    /// No room for the file.
    ERR_DISK_FULL = 0x8003, "disk full";
    /// An illegal FoE operation (an opcode out of turn).
    ERR_ILLEGAL = 0x8004, "illegal";
    /// The packet number is not the one expected.
    ERR_PACKET_NUMBER = 0x8005, "packet number wrong";
    /// The file already exists.
    ERR_ALREADY_EXISTS = 0x8006, "already exists";
    /// No user.
    ERR_NO_USER = 0x8007, "no user";
    /// The file can only be written in the BOOT state.
    ERR_BOOTSTRAP_ONLY = 0x8008, "bootstrap only";
    /// The file may not be accessed in the BOOT state.
    ERR_NOT_BOOTSTRAP = 0x8009, "not bootstrap";
    /// No access rights (the ETG's slave stack answers a wrong password with this code).
    ERR_NO_RIGHTS = 0x800A, "no rights";
    /// Program error.
    ERR_PROGRAM = 0x800B, "program error";
    /// The checksum in the file is wrong.
    ERR_CHECKSUM = 0x800C, "wrong checksum";
    /// The firmware does not fit the hardware.
    ERR_INVALID_FIRMWARE = 0x800D, "firmware does not fit the hardware";
    /// No file to read.
    ERR_NO_FILE = 0x800F, "no file to read";
}

/// Text of an FoE error code.
pub fn error_text(code: u32) -> &'static str {
    crate::lookup(ERROR_TEXTS, code).unwrap_or("unknown FoE error")
}

/// The name of an opcode (`"DATA"`), `None` when it is not one.
pub fn opcode_name(opcode: u8) -> Option<&'static str> {
    Some(match opcode {
        OPCODE_READ => "RRQ",
        OPCODE_WRITE => "WRQ",
        OPCODE_DATA => "DATA",
        OPCODE_ACK => "ACK",
        OPCODE_ERROR => "ERR",
        OPCODE_BUSY => "BUSY",
        _ => return None,
    })
}

/// One FoE message (the bytes after the mailbox header), borrowing its variable part.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Message<'a> {
    /// Read request: the password (0: none) and the file name.
    Read {
        /// Password.
        password: u32,
        /// File name (bytes; ETG.1000.6 gives no encoding, masters send ASCII).
        name: &'a [u8],
    },
    /// Write request: the password (0: none) and the file name.
    Write {
        /// Password.
        password: u32,
        /// File name.
        name: &'a [u8],
    },
    /// A data packet.
    Data {
        /// Packet number, from 1.
        packet: u32,
        /// The packet's data.
        data: &'a [u8],
    },
    /// Acknowledge of packet `packet` (0: of a write request).
    Ack {
        /// Packet number acknowledged.
        packet: u32,
    },
    /// Error: code and text (the text may be empty).
    Error {
        /// Error code (`ERR_*`).
        code: u32,
        /// Error text.
        text: &'a [u8],
    },
    /// Busy: `done` of `entire` (units the slave chooses), and a text (may be empty).
    Busy {
        /// Progress so far.
        done: u16,
        /// Progress at completion.
        entire: u16,
        /// Busy text.
        text: &'a [u8],
    },
}

/// Why bytes are not an FoE message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ParseError {
    /// Shorter than the 6-byte FoE header (the length is given).
    TooShort(usize),
    /// Byte 0 is not an FoE opcode (the byte is given).
    UnknownOpcode(u8),
}

impl std::fmt::Display for ParseError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ParseError::TooShort(n) => write!(
                f,
                "FoE message of {n} bytes is shorter than the {HEADER_LEN}-byte FoE header"
            ),
            ParseError::UnknownOpcode(op) => write!(f, "FoE opcode {op} is not one of 1..=6"),
        }
    }
}

impl std::error::Error for ParseError {}

impl<'a> Message<'a> {
    /// Parse the bytes after the mailbox header (trimmed to the mailbox header's length).
    pub fn parse(data: &'a [u8]) -> Result<Message<'a>, ParseError> {
        let Some(head) = data.get(..HEADER_LEN) else {
            return Err(ParseError::TooShort(data.len()));
        };
        let field = u32::from_le_bytes([head[2], head[3], head[4], head[5]]);
        let rest = &data[HEADER_LEN..];
        Ok(match head[0] {
            OPCODE_READ => Message::Read {
                password: field,
                name: rest,
            },
            OPCODE_WRITE => Message::Write {
                password: field,
                name: rest,
            },
            OPCODE_DATA => Message::Data {
                packet: field,
                data: rest,
            },
            OPCODE_ACK => Message::Ack { packet: field },
            OPCODE_ERROR => Message::Error {
                code: field,
                text: rest,
            },
            OPCODE_BUSY => Message::Busy {
                done: u16::from_le_bytes([head[2], head[3]]),
                entire: u16::from_le_bytes([head[4], head[5]]),
                text: rest,
            },
            op => return Err(ParseError::UnknownOpcode(op)),
        })
    }

    /// The message's opcode.
    pub fn opcode(&self) -> u8 {
        match self {
            Message::Read { .. } => OPCODE_READ,
            Message::Write { .. } => OPCODE_WRITE,
            Message::Data { .. } => OPCODE_DATA,
            Message::Ack { .. } => OPCODE_ACK,
            Message::Error { .. } => OPCODE_ERROR,
            Message::Busy { .. } => OPCODE_BUSY,
        }
    }

    /// The 32-bit field of bytes 2..=5 and the variable part.
    fn parts(&self) -> ([u8; 4], &'a [u8]) {
        match *self {
            Message::Read { password, name } | Message::Write { password, name } => {
                (password.to_le_bytes(), name)
            }
            Message::Data { packet, data } => (packet.to_le_bytes(), data),
            Message::Ack { packet } => (packet.to_le_bytes(), &[]),
            Message::Error { code, text } => (code.to_le_bytes(), text),
            Message::Busy { done, entire, text } => {
                let [d0, d1] = done.to_le_bytes();
                let [e0, e1] = entire.to_le_bytes();
                ([d0, d1, e0, e1], text)
            }
        }
    }

    /// Length of the encoded message (header and variable part).
    pub fn len(&self) -> usize {
        HEADER_LEN + self.parts().1.len()
    }

    /// Always false: a message has at least its header (for clippy's `len` rule).
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Append the encoded message to `out`.
    pub fn encode_into(&self, out: &mut Vec<u8>) {
        let (field, rest) = self.parts();
        out.push(self.opcode());
        out.push(0);
        out.extend_from_slice(&field);
        out.extend_from_slice(rest);
    }

    /// The encoded message.
    pub fn encode(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(self.len());
        self.encode_into(&mut out);
        out
    }
}

/// Data bytes one packet carries through a mailbox of `mailbox_size` bytes (0 when the
/// mailbox cannot carry the headers).
pub const fn max_data(mailbox_size: usize) -> usize {
    mailbox_size.saturating_sub(OVERHEAD)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_round_trip() {
        let cases = [
            Message::Read {
                password: 0x1234_5678,
                name: b"fw.efw",
            },
            Message::Write {
                password: 0,
                name: b"a",
            },
            Message::Data {
                packet: 3,
                data: &[1, 2, 3],
            },
            Message::Ack { packet: 0 },
            Message::Error {
                code: ERR_NOT_FOUND,
                text: b"not found",
            },
            Message::Busy {
                done: 5,
                entire: 100,
                text: b"",
            },
        ];
        for m in cases {
            let bytes = m.encode();
            assert_eq!(bytes.len(), m.len());
            assert_eq!(bytes[0], m.opcode());
            assert_eq!(bytes[1], 0);
            assert_eq!(Message::parse(&bytes), Ok(m));
        }
        assert_eq!(
            Message::Read {
                password: 0x1234_5678,
                name: b"x"
            }
            .encode(),
            [1, 0, 0x78, 0x56, 0x34, 0x12, b'x']
        );
        assert_eq!(
            Message::Busy {
                done: 1,
                entire: 2,
                text: b""
            }
            .encode(),
            [6, 0, 1, 0, 2, 0]
        );
    }

    #[test]
    fn bad_bytes_are_typed_errors() {
        assert_eq!(Message::parse(&[3, 0, 1]), Err(ParseError::TooShort(3)));
        assert_eq!(
            Message::parse(&[9, 0, 0, 0, 0, 0]),
            Err(ParseError::UnknownOpcode(9))
        );
        assert_eq!(
            ParseError::UnknownOpcode(9).to_string(),
            "FoE opcode 9 is not one of 1..=6"
        );
    }

    #[test]
    fn texts_and_sizes() {
        assert_eq!(error_text(0x8002), "access denied");
        assert_eq!(error_text(0x800A), "no rights");
        assert_eq!(error_text(0x1234), "unknown FoE error");
        assert_eq!(opcode_name(OPCODE_BUSY), Some("BUSY"));
        assert_eq!(opcode_name(0), None);
        assert_eq!(max_data(128), 116);
        assert_eq!(max_data(8), 0);
    }
}
