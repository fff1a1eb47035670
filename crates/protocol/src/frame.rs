//! EtherCAT on the wire: frame and datagram layout and the datagram commands.
//!
//! The master's engine and the simulator encode and decode frames with this code, so the layout
//! is written down exactly once. Everything here works on caller-provided byte slices and never
//! allocates, because the engine uses it from its real-time thread.
//!
//! Layout facts (IEC 61158-4-12 / ETG.1000.4):
//! - Ethernet II header: destination (6), source (6), EtherType 0x88A4.
//! - EtherCAT header, 16 bit little endian: bits 0..=10 length of the datagrams that follow,
//!   bit 11 reserved, bits 12..=15 type (1 = EtherCAT DLPDU).
//! - Each datagram: command (1), index (1), address (4: ADP+ADO or a 32-bit logical address),
//!   length word (2: bits 0..=10 data length, bit 14 circulating, bit 15 more datagrams follow),
//!   IRQ (2), data (length), working counter (2).
//! - An Ethernet frame is at least 60 bytes without FCS: short frames are padded with zeros.

crate::named_constants! {
    /// Every layout constant, by name.
    pub const TABLE;
    /// EtherType of EtherCAT frames.
    pub const ETHERTYPE: u16 = 0x88A4;
    /// Ethernet II header length.
    pub const ETH_HEADER_LEN: usize = 14;
    /// EtherCAT frame header length (the 16-bit length/type word).
    pub const ECAT_HEADER_LEN: usize = 2;
    /// Datagram header: command, index, address, length word, IRQ.
    pub const DATAGRAM_HEADER_LEN: usize = 10;
    /// Working counter after each datagram's data.
    pub const WKC_LEN: usize = 2;
    /// Minimum Ethernet frame length without FCS.
    pub const MIN_FRAME_LEN: usize = 60;
    /// Largest Ethernet payload (standard MTU).
    pub const MAX_PAYLOAD: usize = 1500;
    /// Largest frame we build or accept (header + MTU payload).
    pub const MAX_FRAME_LEN: usize = ETH_HEADER_LEN + MAX_PAYLOAD;
    /// Largest data length one datagram can carry in a standard frame.
    pub const MAX_DATAGRAM_DATA: usize = MAX_PAYLOAD - ECAT_HEADER_LEN - DATAGRAM_HEADER_LEN - WKC_LEN;
    /// EtherCAT header type value for DLPDUs.
    pub const ECAT_TYPE_DLPDU: u8 = 1;
}

/// Masters conventionally send from a locally administered address; slaves flip bit 1 of the
/// first source byte on the way back, which is how a master tells its own echo from the answer.
pub const MASTER_MAC: [u8; 6] = [0x02, 0x00, 0x00, 0x00, 0x00, 0x01];
/// Broadcast destination used by masters.
pub const BROADCAST_MAC: [u8; 6] = [0xff; 6];

/// Datagram command codes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum Command {
    /// No operation.
    Nop = 0,
    /// Auto-increment physical read.
    Aprd = 1,
    /// Auto-increment physical write.
    Apwr = 2,
    /// Auto-increment physical read-write.
    Aprw = 3,
    /// Configured address physical read.
    Fprd = 4,
    /// Configured address physical write.
    Fpwr = 5,
    /// Configured address physical read-write.
    Fprw = 6,
    /// Broadcast read.
    Brd = 7,
    /// Broadcast write.
    Bwr = 8,
    /// Broadcast read-write.
    Brw = 9,
    /// Logical memory read.
    Lrd = 10,
    /// Logical memory write.
    Lwr = 11,
    /// Logical memory read-write.
    Lrw = 12,
    /// Auto-increment physical read, multiple write.
    Armw = 13,
    /// Configured address physical read, multiple write.
    Frmw = 14,
}

/// How a command selects slaves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Addressing {
    /// No slave (NOP).
    None,
    /// Auto-increment: ADP holds minus the position; each slave increments it on the way.
    AutoIncrement,
    /// Configured station address (register 0x0010) or alias.
    Fixed,
    /// Every slave.
    Broadcast,
    /// The logical address space, through the slaves' FMMUs.
    Logical,
}

impl Command {
    /// Every command, by code.
    pub const ALL: [Command; 15] = [
        Command::Nop,
        Command::Aprd,
        Command::Apwr,
        Command::Aprw,
        Command::Fprd,
        Command::Fpwr,
        Command::Fprw,
        Command::Brd,
        Command::Bwr,
        Command::Brw,
        Command::Lrd,
        Command::Lwr,
        Command::Lrw,
        Command::Armw,
        Command::Frmw,
    ];

    /// The command with code `v`.
    pub fn from_u8(v: u8) -> Option<Command> {
        use Command::*;
        Some(match v {
            0 => Nop,
            1 => Aprd,
            2 => Apwr,
            3 => Aprw,
            4 => Fprd,
            5 => Fpwr,
            6 => Fprw,
            7 => Brd,
            8 => Bwr,
            9 => Brw,
            10 => Lrd,
            11 => Lwr,
            12 => Lrw,
            13 => Armw,
            14 => Frmw,
            _ => return None,
        })
    }

    /// How the command selects slaves.
    pub fn addressing(self) -> Addressing {
        use Command::*;
        match self {
            Nop => Addressing::None,
            Aprd | Apwr | Aprw | Armw => Addressing::AutoIncrement,
            Fprd | Fpwr | Fprw | Frmw => Addressing::Fixed,
            Brd | Bwr | Brw => Addressing::Broadcast,
            Lrd | Lwr | Lrw => Addressing::Logical,
        }
    }

    /// The command reads slave memory into the frame (ARMW/FRMW read at the addressed slave).
    pub fn reads(self) -> bool {
        use Command::*;
        matches!(
            self,
            Aprd | Aprw | Fprd | Fprw | Brd | Brw | Lrd | Lrw | Armw | Frmw
        )
    }

    /// The command writes frame data into slave memory (ARMW/FRMW write at all other slaves).
    pub fn writes(self) -> bool {
        use Command::*;
        matches!(
            self,
            Apwr | Aprw | Fpwr | Fprw | Bwr | Brw | Lwr | Lrw | Armw | Frmw
        )
    }

    /// The command's name as ETG.1000.4 writes it (`"LRW"`).
    pub fn name(self) -> &'static str {
        use Command::*;
        match self {
            Nop => "NOP",
            Aprd => "APRD",
            Apwr => "APWR",
            Aprw => "APRW",
            Fprd => "FPRD",
            Fpwr => "FPWR",
            Fprw => "FPRW",
            Brd => "BRD",
            Bwr => "BWR",
            Brw => "BRW",
            Lrd => "LRD",
            Lwr => "LWR",
            Lrw => "LRW",
            Armw => "ARMW",
            Frmw => "FRMW",
        }
    }
}

/// Address of a position-addressed datagram: ADP is the two's complement of the position.
pub fn auto_increment_address(position: u16, offset: u16) -> u32 {
    (0u16.wrapping_sub(position) as u32) | ((offset as u32) << 16)
}

/// Address of a station-addressed (configured address or alias) datagram.
pub fn fixed_address(station: u16, offset: u16) -> u32 {
    (station as u32) | ((offset as u32) << 16)
}

/// Split a physical address into (ADP, ADO).
pub fn split_address(address: u32) -> (u16, u16) {
    (address as u16, (address >> 16) as u16)
}

/// Why a frame could not be built or parsed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WireError {
    /// Not enough room in the buffer for the datagram.
    NoRoom,
    /// Datagram data longer than 11 bits / the frame.
    TooLong,
    /// Not an EtherCAT frame (EtherType or header type).
    NotEthercat,
    /// Header length disagrees with the frame, or a datagram runs past the end.
    Truncated,
}

impl core::fmt::Display for WireError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let s = match self {
            WireError::NoRoom => "no room for the datagram in the frame",
            WireError::TooLong => "datagram data longer than a frame can carry",
            WireError::NotEthercat => "not an EtherCAT frame",
            WireError::Truncated => "frame truncated: a datagram runs past the end",
        };
        f.write_str(s)
    }
}

impl std::error::Error for WireError {}

/// Builds an EtherCAT frame in a caller-owned buffer without allocating.
pub struct FrameBuilder<'a> {
    buf: &'a mut [u8],
    len: usize,
    last_header: Option<usize>,
}

/// Where a pushed datagram lives inside the frame, so the caller can fill or read it later.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DatagramSlot {
    /// Offset of the datagram header in the frame.
    pub header: usize,
    /// Offset of the data.
    pub data: usize,
    /// Data length.
    pub len: usize,
    /// Offset of the working counter.
    pub wkc: usize,
}

impl<'a> FrameBuilder<'a> {
    /// Start a frame from `src` to broadcast. `buf` must hold at least `MIN_FRAME_LEN` bytes.
    pub fn new(buf: &'a mut [u8], src: [u8; 6]) -> Result<Self, WireError> {
        if buf.len() < MIN_FRAME_LEN {
            return Err(WireError::NoRoom);
        }
        buf[0..6].copy_from_slice(&BROADCAST_MAC);
        buf[6..12].copy_from_slice(&src);
        buf[12..14].copy_from_slice(&ETHERTYPE.to_be_bytes());
        buf[14..16].fill(0);
        Ok(FrameBuilder {
            buf,
            len: ETH_HEADER_LEN + ECAT_HEADER_LEN,
            last_header: None,
        })
    }

    /// Room left for data in one more datagram.
    pub fn room(&self) -> usize {
        let limit = self.buf.len().min(MAX_FRAME_LEN);
        limit.saturating_sub(self.len + DATAGRAM_HEADER_LEN + WKC_LEN)
    }

    /// Number of datagrams pushed so far.
    pub fn is_empty(&self) -> bool {
        self.last_header.is_none()
    }

    /// Append a datagram. `data` is copied when given; otherwise `len` zero bytes are reserved
    /// (reads). The working counter starts at zero.
    pub fn push(
        &mut self,
        cmd: Command,
        index: u8,
        address: u32,
        data: Option<&[u8]>,
        len: usize,
    ) -> Result<DatagramSlot, WireError> {
        let len = data.map_or(len, |d| d.len());
        if len > MAX_DATAGRAM_DATA {
            return Err(WireError::TooLong);
        }
        if len > self.room() {
            return Err(WireError::NoRoom);
        }
        if let Some(prev) = self.last_header {
            // Set "more datagrams follow" on the previous one.
            self.buf[prev + 7] |= 0x80;
        }
        let h = self.len;
        self.buf[h] = cmd as u8;
        self.buf[h + 1] = index;
        self.buf[h + 2..h + 6].copy_from_slice(&address.to_le_bytes());
        self.buf[h + 6..h + 8].copy_from_slice(&(len as u16 & 0x07ff).to_le_bytes());
        self.buf[h + 8..h + 10].fill(0);
        let d = h + DATAGRAM_HEADER_LEN;
        match data {
            Some(src) => self.buf[d..d + len].copy_from_slice(src),
            None => self.buf[d..d + len].fill(0),
        }
        let w = d + len;
        self.buf[w..w + 2].fill(0);
        self.len = w + WKC_LEN;
        self.last_header = Some(h);
        Ok(DatagramSlot {
            header: h,
            data: d,
            len,
            wkc: w,
        })
    }

    /// Finish the frame: write the EtherCAT header, pad to the Ethernet minimum, return the
    /// frame length to send.
    pub fn finish(self) -> usize {
        let payload = (self.len - ETH_HEADER_LEN - ECAT_HEADER_LEN) as u16;
        let header = (payload & 0x07ff) | ((ECAT_TYPE_DLPDU as u16) << 12);
        self.buf[14..16].copy_from_slice(&header.to_le_bytes());
        let total = self.len.max(MIN_FRAME_LEN);
        self.buf[self.len..total].fill(0);
        total
    }
}

/// One datagram located inside a frame buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Datagram {
    /// Raw command byte (may be unknown: see `command()`).
    pub cmd: u8,
    /// Index (the master's tag to match the reply).
    pub index: u8,
    /// Address: ADP in the low 16 bits and ADO in the high ones, or a logical address.
    pub address: u32,
    /// Circulating bit: the frame passed a closed port once.
    pub circulating: bool,
    /// More datagrams follow in the frame.
    pub more: bool,
    /// IRQ field (the slaves' event requests ORed together).
    pub irq: u16,
    /// Where the data and the working counter sit in the frame buffer.
    pub slot: DatagramSlot,
}

impl Datagram {
    /// The command, `None` when the code is unknown.
    pub fn command(&self) -> Option<Command> {
        Command::from_u8(self.cmd)
    }
}

/// Check the Ethernet and EtherCAT headers; return the offset just past the datagrams.
pub fn check_frame(frame: &[u8]) -> Result<usize, WireError> {
    if frame.len() < ETH_HEADER_LEN + ECAT_HEADER_LEN {
        return Err(WireError::Truncated);
    }
    if u16::from_be_bytes([frame[12], frame[13]]) != ETHERTYPE {
        return Err(WireError::NotEthercat);
    }
    let header = u16::from_le_bytes([frame[14], frame[15]]);
    if (header >> 12) as u8 != ECAT_TYPE_DLPDU {
        return Err(WireError::NotEthercat);
    }
    let end = ETH_HEADER_LEN + ECAT_HEADER_LEN + (header & 0x07ff) as usize;
    if end > frame.len() {
        return Err(WireError::Truncated);
    }
    Ok(end)
}

/// Iterates over the datagrams of a frame. Stops (returning an error once) on a datagram that
/// runs past the frame, so a corrupted frame can never make a reader index out of bounds.
pub struct Datagrams<'a> {
    frame: &'a [u8],
    pos: usize,
    end: usize,
    done: bool,
}

/// Parse a frame's datagrams. The frame's headers are checked first.
pub fn datagrams(frame: &[u8]) -> Result<Datagrams<'_>, WireError> {
    let end = check_frame(frame)?;
    Ok(Datagrams {
        frame,
        pos: ETH_HEADER_LEN + ECAT_HEADER_LEN,
        end,
        done: false,
    })
}

impl Iterator for Datagrams<'_> {
    type Item = Result<Datagram, WireError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.done || self.pos >= self.end {
            return None;
        }
        let h = self.pos;
        if h + DATAGRAM_HEADER_LEN > self.end {
            self.done = true;
            return Some(Err(WireError::Truncated));
        }
        let f = self.frame;
        let lenword = u16::from_le_bytes([f[h + 6], f[h + 7]]);
        let len = (lenword & 0x07ff) as usize;
        let d = h + DATAGRAM_HEADER_LEN;
        let w = d + len;
        if w + WKC_LEN > self.end {
            self.done = true;
            return Some(Err(WireError::Truncated));
        }
        let more = lenword & 0x8000 != 0;
        self.pos = w + WKC_LEN;
        if !more {
            self.done = true;
        }
        Some(Ok(Datagram {
            cmd: f[h],
            index: f[h + 1],
            address: u32::from_le_bytes([f[h + 2], f[h + 3], f[h + 4], f[h + 5]]),
            circulating: lenword & 0x4000 != 0,
            more,
            irq: u16::from_le_bytes([f[h + 8], f[h + 9]]),
            slot: DatagramSlot {
                header: h,
                data: d,
                len,
                wkc: w,
            },
        }))
    }
}

/// Read a datagram's working counter from a frame.
pub fn read_wkc(frame: &[u8], slot: &DatagramSlot) -> u16 {
    u16::from_le_bytes([frame[slot.wkc], frame[slot.wkc + 1]])
}

/// Write a datagram's working counter into a frame.
pub fn write_wkc(frame: &mut [u8], slot: &DatagramSlot, wkc: u16) {
    frame[slot.wkc..slot.wkc + 2].copy_from_slice(&wkc.to_le_bytes());
}

/// Write a datagram's address field (slaves increment ADP of auto-increment datagrams).
pub fn write_address(frame: &mut [u8], slot: &DatagramSlot, address: u32) {
    frame[slot.header + 2..slot.header + 6].copy_from_slice(&address.to_le_bytes());
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn build_then_parse_round_trips() {
        let mut buf = [0u8; MAX_FRAME_LEN];
        let mut b = FrameBuilder::new(&mut buf, MASTER_MAC).unwrap();
        let s1 = b.push(Command::Brd, 7, 0, None, 2).unwrap();
        let s2 = b
            .push(
                Command::Fpwr,
                8,
                fixed_address(0x1001, 0x0120),
                Some(&[2, 0]),
                0,
            )
            .unwrap();
        let n = b.finish();
        assert_eq!(n, MIN_FRAME_LEN);
        let dgs: Vec<_> = datagrams(&buf[..n]).unwrap().map(|d| d.unwrap()).collect();
        assert_eq!(dgs.len(), 2);
        assert_eq!(dgs[0].command(), Some(Command::Brd));
        assert!(dgs[0].more);
        assert!(!dgs[1].more);
        assert_eq!(dgs[0].slot, s1);
        assert_eq!(dgs[1].slot, s2);
        assert_eq!(split_address(dgs[1].address), (0x1001, 0x0120));
        assert_eq!(&buf[s2.data..s2.data + 2], &[2, 0]);
    }

    #[test]
    fn auto_increment_address_is_negative_position() {
        assert_eq!(split_address(auto_increment_address(0, 0x10)), (0, 0x10));
        assert_eq!(
            split_address(auto_increment_address(3, 0x10)),
            (0xfffd, 0x10)
        );
    }

    #[test]
    fn truncated_frames_are_rejected_not_indexed() {
        let mut buf = [0u8; MAX_FRAME_LEN];
        let mut b = FrameBuilder::new(&mut buf, MASTER_MAC).unwrap();
        b.push(Command::Lrw, 0, 0, None, 100).unwrap();
        let n = b.finish();
        // Claim a longer datagram than the frame holds.
        buf[ETH_HEADER_LEN + ECAT_HEADER_LEN + 6] = 0xff;
        buf[ETH_HEADER_LEN + ECAT_HEADER_LEN + 7] = 0x07;
        let r: Vec<_> = datagrams(&buf[..n]).unwrap().collect();
        assert_eq!(r, vec![Err(WireError::Truncated)]);
        // Wrong EtherType.
        buf[12] = 0x08;
        assert_eq!(datagrams(&buf[..n]).err(), Some(WireError::NotEthercat));
        // Too short to hold headers.
        assert_eq!(check_frame(&buf[..10]).err(), Some(WireError::Truncated));
    }

    #[test]
    fn no_room_is_an_error() {
        let mut buf = [0u8; 80];
        let mut b = FrameBuilder::new(&mut buf, MASTER_MAC).unwrap();
        assert_eq!(
            b.push(Command::Lrd, 0, 0, None, 100).err(),
            Some(WireError::NoRoom)
        );
        assert_eq!(
            b.push(Command::Lrd, 0, 0, None, 4000).err(),
            Some(WireError::TooLong)
        );
    }
}
