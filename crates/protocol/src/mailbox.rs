//! The mailbox (ETG.1000.4 §5.6): the 6-byte header every message starts with, the protocol
//! types, and the codes of a mailbox error reply (type 0) with their texts.
//!
//! Header: length (u16, bytes after the header), address (u16), channel (bits 0..=5) and
//! priority (bits 6..=7) in one byte, then type (bits 0..=3) and counter (bits 4..=6, 1..=7;
//! 0 is never taken for a repetition) in the last byte.

crate::named_constants! {
    /// Header length and types, by name.
    pub const TABLE;
    /// Mailbox header length.
    pub const HEADER_LEN: usize = 6;
    /// Type 0: error reply.
    pub const TYPE_ERR: u8 = 0x00;
    /// ADS over EtherCAT.
    pub const TYPE_AOE: u8 = 0x01;
    /// Ethernet over EtherCAT.
    pub const TYPE_EOE: u8 = 0x02;
    /// CANopen over EtherCAT.
    pub const TYPE_COE: u8 = 0x03;
    /// File access over EtherCAT.
    pub const TYPE_FOE: u8 = 0x04;
    /// Servo drive profile over EtherCAT.
    pub const TYPE_SOE: u8 = 0x05;
    /// Vendor specific.
    pub const TYPE_VOE: u8 = 0x0F;
    /// Largest counter value; counters run 1..=7.
    pub const MAX_COUNTER: u8 = 7;
    /// The `type` word of a mailbox error reply's body (followed by the error code).
    pub const ERROR_REPLY_TYPE: u16 = 0x0001;
    /// SII word 0x1C (mailbox protocols) bit: AoE.
    pub const PROTOCOL_AOE: u16 = 0x0001;
    /// SII word 0x1C bit: EoE.
    pub const PROTOCOL_EOE: u16 = 0x0002;
    /// SII word 0x1C bit: CoE.
    pub const PROTOCOL_COE: u16 = 0x0004;
    /// SII word 0x1C bit: FoE.
    pub const PROTOCOL_FOE: u16 = 0x0008;
    /// SII word 0x1C bit: SoE.
    pub const PROTOCOL_SOE: u16 = 0x0010;
    /// SII word 0x1C bit: VoE.
    pub const PROTOCOL_VOE: u16 = 0x0020;
}

/// The name of a mailbox type (`"CoE"`), `None` when the type is not assigned.
pub fn type_name(mbx_type: u8) -> Option<&'static str> {
    Some(match mbx_type {
        TYPE_ERR => "error",
        TYPE_AOE => "AoE",
        TYPE_EOE => "EoE",
        TYPE_COE => "CoE",
        TYPE_FOE => "FoE",
        TYPE_SOE => "SoE",
        TYPE_VOE => "VoE",
        _ => return None,
    })
}

/// A mailbox header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Header {
    /// Bytes after the header.
    pub length: u16,
    /// Station address of the source (slave to master) or destination.
    pub address: u16,
    /// Channel and priority byte.
    pub channel: u8,
    /// Protocol type (bits 0..=3 of the last byte).
    pub mbx_type: u8,
    /// Counter (bits 4..=6 of the last byte).
    pub counter: u8,
}

impl Header {
    /// Decode the first six bytes of `data` (`None` when shorter).
    pub fn decode(data: &[u8]) -> Option<Header> {
        let h = data.get(..HEADER_LEN)?;
        Some(Header {
            length: u16::from_le_bytes([h[0], h[1]]),
            address: u16::from_le_bytes([h[2], h[3]]),
            channel: h[4],
            mbx_type: h[5] & 0x0F,
            counter: (h[5] >> 4) & 0x07,
        })
    }

    /// The six header bytes.
    pub fn encode(&self) -> [u8; HEADER_LEN] {
        let l = self.length.to_le_bytes();
        let a = self.address.to_le_bytes();
        [
            l[0],
            l[1],
            a[0],
            a[1],
            self.channel,
            (self.mbx_type & 0x0F) | ((self.counter & 0x07) << 4),
        ]
    }
}

crate::coded_texts! {
    /// Mailbox error codes by name.
    pub const ERRORS: u16;
    /// Mailbox error codes (ETG.1000.4 table 30) with their texts.
    pub const ERROR_TEXTS;
    /// Syntax of the header is wrong.
    ERR_SYNTAX = 0x0001, "syntax of the 6-byte mailbox header is wrong";
    /// Protocol not supported.
    ERR_UNSUPPORTED_PROTOCOL = 0x0002, "the mailbox protocol is not supported";
    /// Channel field wrong.
    ERR_INVALID_CHANNEL = 0x0003, "channel field contains a wrong value";
    /// Service not supported.
    ERR_SERVICE_NOT_SUPPORTED = 0x0004, "the service in the mailbox protocol is not supported";
    /// Protocol header wrong.
    ERR_INVALID_HEADER = 0x0005, "mailbox protocol header is wrong";
    /// Data too short.
    ERR_SIZE_TOO_SHORT = 0x0006, "length of the received mailbox data is too short";
    /// Not enough resources.
    ERR_NO_MORE_MEMORY = 0x0007, "mailbox protocol cannot be processed: not enough resources";
    /// Inconsistent length.
    ERR_INVALID_SIZE = 0x0008, "length of the data is inconsistent";
}

/// Text of a mailbox error code.
pub fn error_text(code: u16) -> &'static str {
    crate::lookup(ERROR_TEXTS, code).unwrap_or("unknown mailbox error")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_round_trips() {
        let h = Header {
            length: 10,
            address: 0x1001,
            channel: 0,
            mbx_type: TYPE_COE,
            counter: 5,
        };
        assert_eq!(h.encode(), [10, 0, 0x01, 0x10, 0, 0x53]);
        assert_eq!(Header::decode(&h.encode()), Some(h));
        assert_eq!(Header::decode(&[0; 5]), None);
        assert_eq!(error_text(0x0002), "the mailbox protocol is not supported");
        assert_eq!(type_name(TYPE_COE), Some("CoE"));
    }
}
