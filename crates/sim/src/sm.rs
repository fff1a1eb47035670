//! SyncManager state of a virtual ESC (registers 0x0800 + 8·n: start, length, control, status,
//! activate, PDI control).
//!
//! Mailbox mode (control bits 0..=1 = 2) keeps one buffer in ESC memory: a write mailbox becomes
//! full when the master writes its last byte and refuses further writes until the slave has
//! read it; a read mailbox refuses reads until the slave has filled it, and becomes empty when
//! the master reads its last byte. Refused accesses do not count in the working counter.
//!
//! Buffered mode (control bits 0..=1 = 0) is the 3-buffer scheme: the producer fills one buffer
//! while the consumer holds another, and a completed buffer (last byte written after the first
//! one) replaces the third, so the consumer always gets a consistent, most recent buffer. The
//! three buffers live outside the 64 KiB memory; the master sees them at the configured
//! address as on a real ESC.

/// Control, status and activate bits: the protocol crate's (`ether_ros_protocol::reg::sm`).
pub use ether_ros_protocol::reg::sm::{
    ACTIVATE_ENABLE as ACT_ENABLE, DIR_MASK, DIR_WRITE as DIR_ECAT_WRITES, MODE_MAILBOX, MODE_MASK,
    REPEAT as ACT_REPEAT, WATCHDOG as WATCHDOG_TRIGGER,
};

/// Where a SyncManager may lie: the process RAM (0x1000 on) or the digital output registers
/// 0x0F00..0x0F03 (ET1100/ET1200 digital I/O: an SM there makes the outputs count for the
/// process-data watchdog). An SM over the rest of the register space guards nothing: the
/// registers stay registers, so no SM write can make a slave unaddressable.
pub fn window_allowed(start: u16, len: u16) -> bool {
    let (start, end) = (start as usize, start as usize + len as usize);
    start >= 0x1000 || (start >= 0x0F00 && end <= 0x0F04)
}

#[derive(Clone, Debug, Default)]
pub struct SyncManager {
    pub start: u16,
    pub len: u16,
    pub control: u8,
    pub activate: u8,
    /// The slave application keeps this SyncManager disabled (PDI control bit 0).
    pub pdi_disabled: bool,
    /// Repeat acknowledge (PDI control bit 1).
    pub repeat_ack: bool,
    /// Mailbox: buffer full.
    pub full: bool,
    bufs: [Vec<u8>; 3],
    producer: usize,
    middle: usize,
    consumer: usize,
    middle_new: bool,
    opened: bool,
    /// Last completed buffer (status bits 4..=5), 3 when none yet.
    last_buffer: u8,
}

impl SyncManager {
    pub fn is_mailbox(&self) -> bool {
        self.control & MODE_MASK == MODE_MAILBOX
    }

    pub fn ecat_writes(&self) -> bool {
        self.control & DIR_MASK == DIR_ECAT_WRITES
    }

    /// Enabled by the master with a non-zero length over memory an SM may guard: the area is
    /// guarded by this SM.
    pub fn configured(&self) -> bool {
        self.activate & ACT_ENABLE != 0 && self.len > 0 && window_allowed(self.start, self.len)
    }

    /// Guarding the area and accepting accesses.
    pub fn enabled(&self) -> bool {
        self.configured() && !self.pdi_disabled
    }

    pub fn contains(&self, addr: usize) -> bool {
        let s = self.start as usize;
        addr >= s && addr < s + self.len as usize
    }

    /// Reset the buffer state after the master changed the configuration.
    pub fn reset_buffers(&mut self) {
        self.full = false;
        self.middle_new = false;
        self.opened = false;
        self.last_buffer = 3;
        self.producer = 0;
        self.middle = 1;
        self.consumer = 2;
        let n = if self.is_mailbox() {
            0
        } else {
            self.len as usize
        };
        for b in self.bufs.iter_mut() {
            b.clear();
            b.resize(n, 0);
        }
    }

    /// Status register (offset 5).
    pub fn status(&self) -> u8 {
        let mut s = 0u8;
        if self.is_mailbox() {
            if self.full {
                s |= 0x08;
                s |= if self.ecat_writes() { 0x01 } else { 0x02 };
            }
        } else {
            s |= (self.last_buffer & 3) << 4;
            if self.middle_new {
                s |= if self.ecat_writes() { 0x01 } else { 0x02 };
            }
            if self.opened {
                s |= if self.ecat_writes() { 0x80 } else { 0x40 };
            }
        }
        s
    }

    /// PDI control register (offset 7).
    pub fn pdi_control(&self) -> u8 {
        (self.pdi_disabled as u8) | ((self.repeat_ack as u8) << 1)
    }

    fn complete(&mut self) {
        std::mem::swap(&mut self.producer, &mut self.middle);
        self.middle_new = true;
        self.last_buffer = (self.last_buffer + 1) % 3;
    }

    fn take(&mut self) -> bool {
        if self.middle_new {
            std::mem::swap(&mut self.consumer, &mut self.middle);
            self.middle_new = false;
            true
        } else {
            false
        }
    }

    /// Buffered mode: the master writes `data` at offset `off`. Returns true when this access
    /// completed a buffer.
    pub fn buffered_write(&mut self, off: usize, data: &[u8]) -> bool {
        let b = &mut self.bufs[self.producer];
        let end = (off + data.len()).min(b.len());
        if off < end {
            b[off..end].copy_from_slice(&data[..end - off]);
        }
        if off == 0 {
            self.opened = true;
        }
        if off + data.len() >= self.len as usize && self.opened {
            self.opened = false;
            self.complete();
            return true;
        }
        false
    }

    /// Buffered mode: the master reads at offset `off` (OR-ing when `or`).
    pub fn buffered_read(&mut self, off: usize, out: &mut [u8], or: bool) {
        if !self.ecat_writes() && off == 0 {
            self.take();
            self.opened = true;
        }
        let idx = if self.ecat_writes() {
            self.producer
        } else {
            self.consumer
        };
        let b = &self.bufs[idx];
        for (i, o) in out.iter_mut().enumerate() {
            let v = b.get(off + i).copied().unwrap_or(0);
            *o = if or { *o | v } else { v };
        }
        if off + out.len() >= self.len as usize {
            self.opened = false;
        }
    }

    /// Buffered mode, value of one byte as the master would see it (no side effects).
    pub fn buffered_peek(&self, off: usize) -> u8 {
        let idx = if self.ecat_writes() {
            self.producer
        } else {
            self.consumer
        };
        self.bufs[idx].get(off).copied().unwrap_or(0)
    }

    /// Slave side of a write SM: the newest complete buffer, if one arrived since last time.
    pub fn pdi_take(&mut self) -> Option<&[u8]> {
        if self.take() {
            Some(&self.bufs[self.consumer])
        } else {
            None
        }
    }

    /// Slave side of a read SM: fill the producer buffer and publish it.
    pub fn pdi_publish(&mut self, fill: impl FnOnce(&mut [u8])) {
        fill(&mut self.bufs[self.producer]);
        self.complete();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn buffered(len: u16, ecat_writes: bool) -> SyncManager {
        let mut s = SyncManager {
            start: 0x1000,
            len,
            control: if ecat_writes { 0x64 } else { 0x20 },
            activate: 1,
            ..Default::default()
        };
        s.reset_buffers();
        s
    }

    #[test]
    fn an_sm_guards_process_ram_and_digital_outputs_only() {
        assert!(window_allowed(0x1000, 8));
        assert!(window_allowed(0x0F00, 4) && window_allowed(0x0F03, 1));
        assert!(!window_allowed(0x0F02, 4));
        assert!(!window_allowed(0x0000, 0x1000));
        assert!(!window_allowed(0x0981, 1));
        let mut s = buffered(4, true);
        s.start = 0x0000;
        assert!(!s.configured());
    }

    #[test]
    fn write_buffer_switches_only_after_first_and_last_byte() {
        let mut s = buffered(4, true);
        assert!(!s.buffered_write(2, &[3, 4]));
        assert!(s.pdi_take().is_none());
        assert!(!s.buffered_write(0, &[1, 2]));
        assert!(s.buffered_write(2, &[3, 4]));
        assert_eq!(s.pdi_take(), Some(&[1u8, 2, 3, 4][..]));
        assert!(s.pdi_take().is_none());
    }

    #[test]
    fn read_buffer_stays_consistent_while_the_master_reads() {
        let mut s = buffered(2, false);
        s.pdi_publish(|b| b.copy_from_slice(&[1, 2]));
        let mut o = [0u8; 1];
        s.buffered_read(0, &mut o, false);
        assert_eq!(o, [1]);
        // The slave publishes a newer buffer in between: the master still reads the old one.
        s.pdi_publish(|b| b.copy_from_slice(&[7, 8]));
        s.buffered_read(1, &mut o, false);
        assert_eq!(o, [2]);
        let mut o2 = [0u8; 2];
        s.buffered_read(0, &mut o2, false);
        assert_eq!(o2, [7, 8]);
    }
}
