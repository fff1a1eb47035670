//! EtherCAT, written down once: the one crate of the project that knows the protocol.
//!
//! Everything a master, a slave or a tool must agree on lives here and nowhere else: the frame
//! and datagram layout (`frame`, re-exported at the root), the ESC register map with its bit
//! fields (`reg`, `al`, `sii`, `sm`, `fmmu`, `dl`, `dc`, `esc`), the SII EEPROM layout and its
//! CRC-8 (`sii`), mailbox, CoE, FoE and SoE facts with the SDO abort, FoE and SoE error and
//! emergency code texts (`mailbox`, `coe`, `foe`, `soe`, `emergency`), the AL status codes with their texts (`al`),
//! the CoE data types and the value checks of process variables and SDO values (`dtype`,
//! `value`), the object address grammar (`address`), the CiA 402 words, states and modes
//! (`cia402`) and the port order (`topology`).
//!
//! The engine, the simulator and the native command path use it directly; Python reaches it as
//! `ether_ros._native.protocol` (crates/py/src/protocol_bindings.rs exports every table below
//! by name, so a Python module never keeps a copy). The simulator shares these *definitions*
//! with the master; pysoem and ethercrab stay the independent check that both behave like
//! hardware.
//!
//! Nothing here allocates on the paths the engine uses from its real-time thread (frame
//! building and parsing, working counters, value encoding).

#![forbid(unsafe_code)]
#![warn(missing_docs)]

/// Defines constants together with a table of them by name, so the Python binding can export
/// every constant without a second list of names. Each table is `&[(name, value)]`.
///
/// ```
/// ether_ros_protocol::named_constants! {
///     /// Every constant below, by name.
///     pub const TABLE;
///     /// The answer.
///     pub const ANSWER: u16 = 42;
/// }
/// assert_eq!(TABLE, &[("ANSWER", 42)]);
/// ```
#[macro_export]
macro_rules! named_constants {
    (
        $(#[$tmeta:meta])* pub const $table:ident;
        $( $(#[$meta:meta])* pub const $name:ident : $ty:ty = $value:expr; )*
    ) => {
        $( $(#[$meta])* pub const $name: $ty = $value; )*
        $(#[$tmeta])*
        pub const $table: &[(&str, u64)] = &[ $( (stringify!($name), $name as u64), )* ];
    };
}

/// Defines coded conditions (AL status codes, SDO abort codes, mailbox errors): a constant per
/// code, the table of names for the Python binding and the table of texts.
#[macro_export]
macro_rules! coded_texts {
    (
        $(#[$tmeta:meta])* pub const $table:ident: $ty:ty;
        $(#[$xmeta:meta])* pub const $texts:ident;
        $( $(#[$meta:meta])* $name:ident = $value:expr, $text:expr; )*
    ) => {
        $( $(#[$meta])* pub const $name: $ty = $value; )*
        $(#[$tmeta])*
        pub const $table: &[(&str, u64)] = &[ $( (stringify!($name), $name as u64), )* ];
        $(#[$xmeta])*
        pub const $texts: &[($ty, &str)] = &[ $( ($name, $text), )* ];
    };
}

/// Little-endian field readers of the record codecs (SyncManager and FMMU registers, the SII
/// categories' records): the one place that says how a multi-byte field sits in a record.
/// Callers have checked the record's length, so an index out of range is a bug.
pub(crate) mod le {
    /// The u16 at byte `at` of `b`.
    pub(crate) const fn u16_at(b: &[u8], at: usize) -> u16 {
        u16::from_le_bytes([b[at], b[at + 1]])
    }

    /// The u32 at byte `at` of `b`.
    pub(crate) const fn u32_at(b: &[u8], at: usize) -> u32 {
        u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
    }

    /// The 8-byte window record a SyncManager register set and an SII SyncM entry share:
    /// start (u16), length (u16), then four single bytes.
    pub(crate) const fn window(start: u16, length: u16, tail: [u8; 4]) -> [u8; 8] {
        let s = start.to_le_bytes();
        let l = length.to_le_bytes();
        [s[0], s[1], l[0], l[1], tail[0], tail[1], tail[2], tail[3]]
    }
}

pub mod address;
pub mod al;
pub mod cia402;
pub mod coe;
pub mod dtype;
pub mod emergency;
pub mod foe;
pub mod frame;
pub mod mailbox;
pub mod reg;
pub mod sii;
pub mod soe;
pub mod topology;
pub mod value;

pub use frame::*;

/// The text of `code` in a table of coded texts (tables are short; a linear search is fine).
pub fn lookup<T: Copy + PartialEq>(table: &[(T, &'static str)], code: T) -> Option<&'static str> {
    table.iter().find(|(c, _)| *c == code).map(|(_, t)| *t)
}
