//! FoE (File access over EtherCAT, ETG.1000.6) server of a virtual slave whose SII announces
//! FoE (word 0x1C bit 3): a small file store the master reads and writes by name, and the
//! firmware update of the BOOT state.
//!
//! - **Store**: files by name, their total size bounded (`FoeSpec::capacity`); files can be
//!   given in the spec (the simulator's config). A file written replaces one of the same name.
//! - **Read** (RRQ): the file in data packets of the read mailbox's size less the mailbox and
//!   FoE headers, each sent when the previous one is acknowledged with its number; a packet
//!   shorter than that ends the file (a file whose length is a multiple of it ends with an
//!   empty packet).
//! - **Write** (WRQ): acknowledged with packet 0; each data packet must carry the next number
//!   and is acknowledged with it; a packet shorter than the write mailbox allows ends the file,
//!   which is then stored. A device busy with its flash answers data packets with BUSY
//!   (`FoeSpec::busy` of them per write, the first ones); the master sends the same packet
//!   again.
//! - **Errors** (an FoE error message, which ends the transfer): a password other than the
//!   configured one 0x800A "no rights" (as the ETG's slave stack code answers a wrong
//!   password), a file that is not there 0x8001, a file that does not fit 0x8003 "disk full",
//!   a packet number out of turn 0x8005, an acknowledge or data packet outside a transfer
//!   0x8004 "illegal". An error message from the master ends the transfer silently.
//! - **BOOT**: only the firmware file (`FoeSpec::firmware`) may be read or written there
//!   (0x8009 "not bootstrap" for any other name), and it may be written only there (0x8008
//!   "bootstrap only"). A firmware image written in BOOT takes effect when the device leaves
//!   BOOT for INIT (it restarts): its software version, object 0x100A, becomes the image's
//!   (`firmware_version`).
//!
//! Nothing a master sends can make this code panic; a message too short for the FoE header is
//! the caller's mailbox error.

use std::collections::BTreeMap;

use ether_ros_protocol::foe::{self as facts, Message};
use ether_ros_protocol::{al, coe, dtype};

use crate::od::{Access, Entry, Object, ObjectDictionary};

/// What a slave's FoE server starts with (the simulator's config, `sim: {foe: ...}`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FoeSpec {
    /// Most bytes all files together may take.
    pub capacity: usize,
    /// The password every request must carry; `None`: any password is taken.
    pub password: Option<u32>,
    /// Files present at power-on: (name, contents).
    pub files: Vec<(String, Vec<u8>)>,
    /// The name of the firmware image (written in BOOT only).
    pub firmware: String,
    /// Data packets of each write answered with BUSY before the first is acknowledged.
    pub busy: u32,
}

/// `FoeSpec::capacity` when the config gives none.
pub const DEFAULT_CAPACITY: usize = 64 * 1024;
/// `FoeSpec::firmware` when the config gives none (Beckhoff's firmware files end in .efw).
pub const DEFAULT_FIRMWARE: &str = "firmware.efw";
/// A firmware image names its version after this marker (up to the first byte that is not
/// printable ASCII, at most `MAX_VERSION_LEN` bytes).
pub const VERSION_MARKER: &[u8] = b"version=";
/// Longest software version taken from an image.
pub const MAX_VERSION_LEN: usize = 64;

impl Default for FoeSpec {
    fn default() -> Self {
        FoeSpec {
            capacity: DEFAULT_CAPACITY,
            password: None,
            files: Vec::new(),
            firmware: DEFAULT_FIRMWARE.into(),
            busy: 0,
        }
    }
}

impl FoeSpec {
    /// Whether the files given fit the capacity; the error names the total and the capacity.
    pub fn check(&self) -> Result<(), String> {
        let total: usize = self.files.iter().map(|(_, data)| data.len()).sum();
        if total > self.capacity {
            return Err(format!(
                "the FoE files given take {total} bytes, more than the store's capacity of {} \
                 bytes",
                self.capacity
            ));
        }
        Ok(())
    }
}

/// The transfer in progress.
#[derive(Clone, Debug, PartialEq, Eq)]
enum Transfer {
    Idle,
    /// Sending `data`: `sent` bytes are out, the last packet was `packet` of `last_len` bytes,
    /// of at most `chunk`.
    Reading {
        data: Vec<u8>,
        sent: usize,
        packet: u32,
        last_len: usize,
        chunk: usize,
    },
    /// Receiving `name`: `buffer` so far, `next` the packet number expected.
    Writing {
        name: Vec<u8>,
        buffer: Vec<u8>,
        next: u32,
        busy_left: u32,
    },
}

/// A slave's FoE server (see the module documentation).
#[derive(Clone, Debug)]
pub struct FoeServer {
    capacity: usize,
    password: Option<u32>,
    firmware: Vec<u8>,
    busy: u32,
    files: BTreeMap<Vec<u8>, Vec<u8>>,
    transfer: Transfer,
    /// A firmware image written in BOOT, applied when the device restarts into INIT.
    pending_firmware: Option<Vec<u8>>,
}

impl FoeServer {
    /// A server with the spec's store.
    pub fn new(spec: &FoeSpec) -> FoeServer {
        FoeServer {
            capacity: spec.capacity,
            password: spec.password,
            firmware: spec.firmware.as_bytes().to_vec(),
            busy: spec.busy,
            files: spec
                .files
                .iter()
                .map(|(name, data)| (name.as_bytes().to_vec(), data.clone()))
                .collect(),
            transfer: Transfer::Idle,
            pending_firmware: None,
        }
    }

    /// The contents of file `name`.
    pub fn file(&self, name: &str) -> Option<&[u8]> {
        self.files.get(name.as_bytes()).map(Vec::as_slice)
    }

    /// Bytes all files take.
    pub fn used(&self) -> usize {
        self.files.values().map(Vec::len).sum()
    }

    /// Whether a transfer is in progress.
    pub fn busy_with_transfer(&self) -> bool {
        self.transfer != Transfer::Idle
    }

    /// The device restarts into INIT (the mailbox is reset): a transfer in progress is
    /// dropped, and coming from BOOT a firmware image written there takes effect — the
    /// software version 0x100A becomes the image's. Returns the new version when it changed.
    pub fn restart(&mut self, od: &mut ObjectDictionary, from_boot: bool) -> Option<String> {
        self.transfer = Transfer::Idle;
        let image = self.pending_firmware.take().filter(|_| from_boot)?;
        let version = firmware_version(&image);
        set_software_version(od, &version);
        Some(version)
    }

    /// Handle one FoE message (mailbox header stripped, trimmed to its length) in AL state
    /// `al_state`. `rx_size` and `tx_size` are the write and read mailbox sizes (SM0 and SM1
    /// lengths). Responses go to `out`. `Err` is the mailbox error code the caller answers
    /// with instead (a message shorter than the FoE header).
    pub fn handle(
        &mut self,
        request: &[u8],
        al_state: u8,
        rx_size: usize,
        tx_size: usize,
        out: &mut Vec<Vec<u8>>,
    ) -> Result<(), u16> {
        let msg = match Message::parse(request) {
            Ok(m) => m,
            Err(facts::ParseError::TooShort(_)) => {
                return Err(ether_ros_protocol::mailbox::ERR_SIZE_TOO_SHORT)
            }
            Err(facts::ParseError::UnknownOpcode(_)) => {
                self.fail(facts::ERR_ILLEGAL, out);
                return Ok(());
            }
        };
        let boot = al_state == al::BOOT;
        match msg {
            Message::Read { password, name } => {
                if let Err(code) = self.check_request(password, name, boot, false) {
                    self.fail(code, out);
                    return Ok(());
                }
                let Some(data) = self.files.get(name).cloned() else {
                    self.fail(facts::ERR_NOT_FOUND, out);
                    return Ok(());
                };
                let chunk = facts::max_data(tx_size);
                if chunk == 0 {
                    self.fail(facts::ERR_PROGRAM, out);
                    return Ok(());
                }
                self.transfer = Transfer::Reading {
                    data,
                    sent: 0,
                    packet: 0,
                    last_len: 0,
                    chunk,
                };
                self.send_next(out);
            }
            Message::Write { password, name } => {
                if let Err(code) = self.check_request(password, name, boot, true) {
                    self.fail(code, out);
                    return Ok(());
                }
                self.transfer = Transfer::Writing {
                    name: name.to_vec(),
                    buffer: Vec::new(),
                    next: 1,
                    busy_left: self.busy,
                };
                out.push(Message::Ack { packet: 0 }.encode());
            }
            Message::Ack { packet } => match &self.transfer {
                Transfer::Reading {
                    packet: expected,
                    last_len,
                    chunk,
                    ..
                } => {
                    if packet != *expected {
                        self.fail(facts::ERR_PACKET_NUMBER, out);
                        return Ok(());
                    }
                    if last_len < chunk {
                        // The short packet was the last: the file is read.
                        self.transfer = Transfer::Idle;
                    } else {
                        self.send_next(out);
                    }
                }
                _ => self.fail(facts::ERR_ILLEGAL, out),
            },
            Message::Data { packet, data } => {
                self.receive(packet, data, boot, facts::max_data(rx_size), out)
            }
            Message::Error { .. } => self.transfer = Transfer::Idle,
            Message::Busy { .. } => self.fail(facts::ERR_ILLEGAL, out),
        }
        Ok(())
    }

    /// The checks of a read or write request: password, and which names BOOT allows.
    fn check_request(
        &self,
        password: u32,
        name: &[u8],
        boot: bool,
        write: bool,
    ) -> Result<(), u32> {
        if self.password.is_some_and(|p| p != password) {
            return Err(facts::ERR_NO_RIGHTS);
        }
        let firmware = name == self.firmware.as_slice();
        if boot && !firmware {
            return Err(facts::ERR_NOT_BOOTSTRAP);
        }
        if write && firmware && !boot {
            return Err(facts::ERR_BOOTSTRAP_ONLY);
        }
        Ok(())
    }

    /// The next data packet of the file being read.
    fn send_next(&mut self, out: &mut Vec<Vec<u8>>) {
        if let Transfer::Reading {
            data,
            sent,
            packet,
            last_len,
            chunk,
        } = &mut self.transfer
        {
            let n = (*chunk).min(data.len() - *sent);
            *packet += 1;
            *last_len = n;
            let msg = Message::Data {
                packet: *packet,
                data: &data[*sent..*sent + n],
            };
            *sent += n;
            out.push(msg.encode());
        }
    }

    /// A data packet of a write.
    fn receive(
        &mut self,
        packet: u32,
        data: &[u8],
        boot: bool,
        chunk: usize,
        out: &mut Vec<Vec<u8>>,
    ) {
        let others = |name: &[u8], files: &BTreeMap<Vec<u8>, Vec<u8>>| -> usize {
            files
                .iter()
                .filter(|(n, _)| n.as_slice() != name)
                .map(|(_, d)| d.len())
                .sum()
        };
        let Transfer::Writing {
            name,
            buffer,
            next,
            busy_left,
        } = &mut self.transfer
        else {
            return self.fail(facts::ERR_ILLEGAL, out);
        };
        if packet != *next {
            return self.fail(facts::ERR_PACKET_NUMBER, out);
        }
        if *busy_left > 0 {
            // Dropped: the master sends this packet again after a busy.
            *busy_left -= 1;
            let busy = Message::Busy {
                done: (self.busy - *busy_left) as u16,
                entire: self.busy as u16,
                text: b"",
            };
            out.push(busy.encode());
            return;
        }
        if others(name, &self.files) + buffer.len() + data.len() > self.capacity {
            return self.fail(facts::ERR_DISK_FULL, out);
        }
        buffer.extend_from_slice(data);
        out.push(Message::Ack { packet }.encode());
        *next += 1;
        if data.len() < chunk {
            let name = std::mem::take(name);
            let contents = std::mem::take(buffer);
            if boot && name == self.firmware {
                self.pending_firmware = Some(contents.clone());
            }
            self.files.insert(name, contents);
            self.transfer = Transfer::Idle;
        }
    }

    /// Answer with an FoE error (its text as the message text) and end the transfer.
    fn fail(&mut self, code: u32, out: &mut Vec<Vec<u8>>) {
        self.transfer = Transfer::Idle;
        let text = facts::error_text(code).as_bytes();
        out.push(Message::Error { code, text }.encode());
    }
}

/// The software version a firmware image carries: the printable ASCII after
/// `VERSION_MARKER` (at most `MAX_VERSION_LEN` bytes); an image without it gets
/// "image of N bytes".
pub fn firmware_version(image: &[u8]) -> String {
    let found = image
        .windows(VERSION_MARKER.len())
        .position(|w| w == VERSION_MARKER);
    if let Some(at) = found {
        let text: String = image[at + VERSION_MARKER.len()..]
            .iter()
            .take_while(|b| (0x20..0x7F).contains(*b))
            .take(MAX_VERSION_LEN)
            .map(|&b| char::from(b))
            .collect();
        if !text.is_empty() {
            return text;
        }
    }
    format!("image of {} bytes", image.len())
}

/// Set 0x100A:0 (manufacturer software version, VISIBLE_STRING) to `version`, its length the
/// string's; the object is added when the dictionary lacks it.
pub fn set_software_version(od: &mut ObjectDictionary, version: &str) {
    if od.object(coe::SOFTWARE_VERSION).is_none() {
        od.add_object(Object {
            index: coe::SOFTWARE_VERSION,
            name: "Manufacturer software version".into(),
            object_code: coe::OBJECT_VAR,
        });
    }
    let (name, access) = od.entry(coe::SOFTWARE_VERSION, 0).map_or(
        ("Manufacturer software version".into(), Access::ReadOnly),
        |e| (e.name.clone(), e.access),
    );
    od.add_entry(Entry {
        index: coe::SOFTWARE_VERSION,
        subindex: 0,
        name,
        data_type: dtype::VISIBLE_STRING,
        bit_length: (version.len() * 8) as u16,
        access,
        pdo_mappable: false,
        value: version.as_bytes().to_vec(),
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use ether_ros_protocol::foe::{ERR_ILLEGAL, OVERHEAD};

    /// A mailbox of 32 bytes: 20 data bytes per packet.
    const MBX: usize = 32;
    const CHUNK: usize = MBX - OVERHEAD;

    fn server(spec: FoeSpec) -> FoeServer {
        FoeServer::new(&spec)
    }

    /// Send `msg` in `state`, return the one reply (or None) parsed into owned parts.
    fn ask(s: &mut FoeServer, msg: Message<'_>, state: u8) -> Option<(u8, u32, Vec<u8>)> {
        let mut out = Vec::new();
        s.handle(&msg.encode(), state, MBX, MBX, &mut out).unwrap();
        assert!(out.len() <= 1, "one reply at most, got {out:?}");
        out.pop().map(|r| {
            assert!(r.len() <= MBX - 6, "reply longer than the mailbox");
            let field = u32::from_le_bytes([r[2], r[3], r[4], r[5]]);
            (r[0], field, r[6..].to_vec())
        })
    }

    fn write_file(s: &mut FoeServer, name: &str, data: &[u8], state: u8) {
        let reply = ask(
            s,
            Message::Write {
                password: 0,
                name: name.as_bytes(),
            },
            state,
        );
        assert_eq!(reply, Some((facts::OPCODE_ACK, 0, vec![])));
        let mut chunks: Vec<&[u8]> = data.chunks(CHUNK).collect();
        if data.len().is_multiple_of(CHUNK) {
            chunks.push(&[]);
        }
        for (packet, chunk) in (1..).zip(chunks) {
            let reply = ask(
                s,
                Message::Data {
                    packet,
                    data: chunk,
                },
                state,
            );
            assert_eq!(reply, Some((facts::OPCODE_ACK, packet, vec![])));
        }
        assert!(!s.busy_with_transfer());
    }

    fn read_file(s: &mut FoeServer, name: &str, state: u8) -> Result<Vec<u8>, u32> {
        let mut reply = ask(
            s,
            Message::Read {
                password: 0,
                name: name.as_bytes(),
            },
            state,
        );
        let mut data = Vec::new();
        let mut expected = 1;
        loop {
            let (op, field, body) = reply.expect("a reply");
            if op == facts::OPCODE_ERROR {
                return Err(field);
            }
            assert_eq!((op, field), (facts::OPCODE_DATA, expected));
            data.extend_from_slice(&body);
            reply = ask(s, Message::Ack { packet: field }, state);
            if body.len() < CHUNK {
                assert_eq!(reply, None, "no packet after the short one");
                return Ok(data);
            }
            expected += 1;
        }
    }

    #[test]
    fn files_are_segmented_to_the_mailbox_and_read_back() {
        let mut s = server(FoeSpec::default());
        for len in [0, 1, CHUNK - 1, CHUNK, CHUNK + 1, 3 * CHUNK, 1000] {
            let data: Vec<u8> = (0..len).map(|i| (i * 7) as u8).collect();
            write_file(&mut s, "f.bin", &data, al::PREOP);
            assert_eq!(s.file("f.bin"), Some(data.as_slice()));
            assert_eq!(read_file(&mut s, "f.bin", al::OP), Ok(data));
        }
    }

    #[test]
    fn configured_files_and_missing_ones() {
        let mut s = server(FoeSpec {
            files: vec![("cfg.txt".into(), b"gain=3".to_vec())],
            ..FoeSpec::default()
        });
        assert_eq!(
            read_file(&mut s, "cfg.txt", al::PREOP),
            Ok(b"gain=3".to_vec())
        );
        assert_eq!(
            read_file(&mut s, "nope", al::PREOP),
            Err(facts::ERR_NOT_FOUND)
        );
    }

    #[test]
    fn a_wrong_password_is_refused_with_its_text() {
        let mut s = server(FoeSpec {
            password: Some(0x1234),
            ..FoeSpec::default()
        });
        let reply = ask(
            &mut s,
            Message::Write {
                password: 1,
                name: b"x",
            },
            al::PREOP,
        );
        assert_eq!(
            reply,
            Some((
                facts::OPCODE_ERROR,
                facts::ERR_NO_RIGHTS,
                b"no rights".to_vec()
            ))
        );
        let reply = ask(
            &mut s,
            Message::Write {
                password: 0x1234,
                name: b"x",
            },
            al::PREOP,
        );
        assert_eq!(reply, Some((facts::OPCODE_ACK, 0, vec![])));
    }

    #[test]
    fn packet_numbers_are_checked_both_ways() {
        let mut s = server(FoeSpec::default());
        ask(
            &mut s,
            Message::Write {
                password: 0,
                name: b"x",
            },
            al::PREOP,
        );
        let reply = ask(
            &mut s,
            Message::Data {
                packet: 2,
                data: b"ab",
            },
            al::PREOP,
        );
        assert_eq!(reply.map(|r| r.1), Some(facts::ERR_PACKET_NUMBER));
        assert!(!s.busy_with_transfer());
        assert_eq!(s.file("x"), None, "an aborted write stores nothing");
        // Read: the acknowledge must name the packet just sent.
        write_file(&mut s, "y", &[5; 50], al::PREOP);
        let first = ask(
            &mut s,
            Message::Read {
                password: 0,
                name: b"y",
            },
            al::PREOP,
        );
        assert_eq!(first.map(|r| (r.0, r.1)), Some((facts::OPCODE_DATA, 1)));
        let reply = ask(&mut s, Message::Ack { packet: 7 }, al::PREOP);
        assert_eq!(reply.map(|r| r.1), Some(facts::ERR_PACKET_NUMBER));
        // Out of turn.
        let reply = ask(&mut s, Message::Ack { packet: 1 }, al::PREOP);
        assert_eq!(reply.map(|r| r.1), Some(ERR_ILLEGAL));
        let reply = ask(
            &mut s,
            Message::Data {
                packet: 1,
                data: b"",
            },
            al::PREOP,
        );
        assert_eq!(reply.map(|r| r.1), Some(ERR_ILLEGAL));
        // An unknown opcode is an FoE error too; a message shorter than the header the
        // caller's mailbox error.
        let mut out = Vec::new();
        s.handle(&[9, 0, 0, 0, 0, 0], al::PREOP, MBX, MBX, &mut out)
            .unwrap();
        assert_eq!(out[0][..6], [5, 0, 0x04, 0x80, 0, 0]);
        assert_eq!(
            s.handle(&[3, 0], al::PREOP, MBX, MBX, &mut out),
            Err(ether_ros_protocol::mailbox::ERR_SIZE_TOO_SHORT)
        );
    }

    #[test]
    fn the_master_aborts_with_an_error() {
        let mut s = server(FoeSpec::default());
        ask(
            &mut s,
            Message::Write {
                password: 0,
                name: b"x",
            },
            al::PREOP,
        );
        let reply = ask(
            &mut s,
            Message::Error {
                code: facts::ERR_NOT_DEFINED,
                text: b"",
            },
            al::PREOP,
        );
        assert_eq!(reply, None);
        assert!(!s.busy_with_transfer());
    }

    #[test]
    fn the_store_is_bounded() {
        let mut s = server(FoeSpec {
            capacity: 49,
            files: vec![("a".into(), vec![0; 30])],
            ..FoeSpec::default()
        });
        assert!(FoeSpec {
            capacity: 10,
            files: vec![("a".into(), vec![0; 30])],
            ..FoeSpec::default()
        }
        .check()
        .unwrap_err()
        .contains("30 bytes, more than the store's capacity of 10"));
        ask(
            &mut s,
            Message::Write {
                password: 0,
                name: b"b",
            },
            al::PREOP,
        );
        let reply = ask(
            &mut s,
            Message::Data {
                packet: 1,
                data: &[1; CHUNK],
            },
            al::PREOP,
        );
        assert_eq!(
            reply,
            Some((
                facts::OPCODE_ERROR,
                facts::ERR_DISK_FULL,
                b"disk full".to_vec()
            ))
        );
        assert_eq!(s.used(), 30);
        // Replacing a file counts only the new contents.
        write_file(&mut s, "a", &[2; 45], al::PREOP);
        assert_eq!(s.used(), 45);
    }

    #[test]
    fn busy_packets_are_sent_again() {
        let mut s = server(FoeSpec {
            busy: 2,
            ..FoeSpec::default()
        });
        ask(
            &mut s,
            Message::Write {
                password: 0,
                name: b"x",
            },
            al::PREOP,
        );
        let data = Message::Data {
            packet: 1,
            data: b"abc",
        };
        assert_eq!(
            ask(&mut s, data, al::PREOP),
            Some((facts::OPCODE_BUSY, 1 | 2 << 16, vec![]))
        );
        assert_eq!(
            ask(&mut s, data, al::PREOP),
            Some((facts::OPCODE_BUSY, 2 | 2 << 16, vec![]))
        );
        assert_eq!(
            ask(&mut s, data, al::PREOP),
            Some((facts::OPCODE_ACK, 1, vec![]))
        );
        assert_eq!(s.file("x"), Some(&b"abc"[..]));
    }

    #[test]
    fn firmware_goes_in_boot_and_takes_effect_at_restart() {
        let mut s = server(FoeSpec::default());
        let mut od = ObjectDictionary::new();
        let write = |name: &'static [u8]| Message::Write { password: 0, name };
        assert_eq!(
            ask(&mut s, write(b"firmware.efw"), al::PREOP).map(|r| r.1),
            Some(facts::ERR_BOOTSTRAP_ONLY)
        );
        assert_eq!(
            ask(&mut s, write(b"other"), al::BOOT).map(|r| r.1),
            Some(facts::ERR_NOT_BOOTSTRAP)
        );
        write_file(
            &mut s,
            "firmware.efw",
            b"\x7fELF..version=2.1.0\0rest",
            al::BOOT,
        );
        // Nothing changes before the restart, and only a restart out of BOOT applies it.
        assert_eq!(od.get_bytes(coe::SOFTWARE_VERSION, 0), None);
        assert_eq!(s.restart(&mut od, true), Some("2.1.0".into()));
        assert_eq!(od.get_bytes(coe::SOFTWARE_VERSION, 0), Some(&b"2.1.0"[..]));
        assert_eq!(s.restart(&mut od, true), None, "applied once");
        assert_eq!(firmware_version(b"no marker"), "image of 9 bytes");
    }

    #[test]
    fn random_messages_never_panic_and_get_at_most_one_answer() {
        let mut s = server(FoeSpec {
            capacity: 300,
            password: Some(7),
            busy: 1,
            files: vec![("firmware.efw".into(), vec![1; 40])],
            ..FoeSpec::default()
        });
        let mut od = ObjectDictionary::new();
        let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut next = move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        for _ in 0..20_000 {
            let r = next();
            let len = (r % 40) as usize;
            let mut msg: Vec<u8> = (0..len).map(|_| next() as u8).collect();
            if len > 0 {
                msg[0] = (r >> 8) as u8 % 8; // mostly valid opcodes
            }
            if len > 5 && r & 0x1_0000 != 0 {
                msg[2..6].copy_from_slice(&((r >> 20) as u32 % 4).to_le_bytes());
            }
            let state = [al::PREOP, al::BOOT, al::OP][(r >> 24) as usize % 3];
            let mut out = Vec::new();
            let mbx = 12 + (r >> 32) as usize % 64;
            let _ = s.handle(&msg, state, mbx, mbx, &mut out);
            assert!(out.len() <= 1);
            if r % 97 == 0 {
                s.restart(&mut od, r % 2 == 0);
            }
        }
        assert!(s.used() <= 300);
    }
}
