//! Lock-free hand-over between the real-time thread and the rest of the process: a seqlock
//! buffer (process image in either direction), the single-producer single-consumer ring of
//! per-cycle samples, and the one-slot acyclic request mailbox.
//!
//! None of these ever makes the real-time thread wait: a reader that meets a write in progress
//! keeps the previous complete version (RT side) or retries (Python side), the ring drops a
//! sample when full instead of overwriting unread ones, and the mailbox changes hands through
//! one atomic state word.

use std::cell::UnsafeCell;
use std::sync::atomic::{fence, AtomicI64, AtomicU32, AtomicU64, AtomicU8, AtomicUsize, Ordering};

use ether_ros_protocol::MAX_FRAME_LEN;

/// A byte buffer guarded by a sequence counter: one writer at a time (callers ensure it),
/// any number of readers that detect and reject torn copies. Bytes are atomics so that the
/// racy copy a reader may discard is still defined behaviour.
pub struct SeqBuffer {
    seq: AtomicU64,
    data: Box<[AtomicU8]>,
}

impl SeqBuffer {
    pub fn new(initial: &[u8]) -> SeqBuffer {
        SeqBuffer {
            seq: AtomicU64::new(0),
            data: initial.iter().map(|&b| AtomicU8::new(b)).collect(),
        }
    }

    pub fn len(&self) -> usize {
        self.data.len()
    }

    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    /// Version counter: even when no write is in progress; changes with every write.
    pub fn version(&self) -> u64 {
        self.seq.load(Ordering::Acquire)
    }

    /// Write `src` at `offset`. The caller guarantees a single writer and that the range fits.
    pub fn write(&self, offset: usize, src: &[u8]) {
        let s = self.seq.load(Ordering::Relaxed);
        self.seq.store(s.wrapping_add(1), Ordering::Relaxed);
        fence(Ordering::Release);
        for (cell, &b) in self.data[offset..offset + src.len()].iter().zip(src) {
            cell.store(b, Ordering::Relaxed);
        }
        self.seq.store(s.wrapping_add(2), Ordering::Release);
    }

    /// Copy the bytes at `offset` into `dst` without checking the version. Only for the single
    /// writer (while it holds whatever serialises writers): nobody else changes the bytes, so
    /// it reads them consistently, e.g. to change some bits and write the bytes back.
    pub fn read_as_writer(&self, offset: usize, dst: &mut [u8]) {
        let cells = &self.data[offset..offset + dst.len()];
        for (d, cell) in dst.iter_mut().zip(cells) {
            *d = cell.load(Ordering::Relaxed);
        }
    }

    /// Copy the whole buffer into `dst` once. Returns the version copied, or `None` when a write
    /// overlapped (then `dst` holds garbage and must not be used).
    pub fn try_read(&self, dst: &mut [u8]) -> Option<u64> {
        let s1 = self.seq.load(Ordering::Acquire);
        if s1 & 1 == 1 {
            return None;
        }
        for (d, cell) in dst.iter_mut().zip(self.data.iter()) {
            *d = cell.load(Ordering::Relaxed);
        }
        fence(Ordering::Acquire);
        let s2 = self.seq.load(Ordering::Relaxed);
        (s1 == s2).then_some(s1)
    }

    /// Copy out a consistent version, retrying while the writer is busy (never used by the
    /// real-time thread).
    pub fn read(&self) -> Vec<u8> {
        let mut out = vec![0u8; self.data.len()];
        while self.try_read(&mut out).is_none() {
            std::hint::spin_loop();
        }
        out
    }
}

/// Size of one sample record in bytes (see `SampleRecord::encode` and `samples.py`).
pub const RECORD_LEN: usize = 56;

/// Flags of a sample (bit values shared with `python/ether_ros/master/samples.py`).
pub mod flags {
    /// The reply to a cyclic frame did not arrive in time (which: the record's `lost_mask`).
    pub const LOST: u16 = 1 << 0;
    /// A reply to an older cyclic frame arrived (after it was already counted lost).
    pub const LATE: u16 = 1 << 1;
    /// A logical datagram's working counter differed from the expected one.
    pub const WKC_ERROR: u16 = 1 << 2;
    /// Panic latched: the safe image went on the wire.
    pub const PANIC: u16 = 1 << 3;
    /// Command watchdog expired: the safe image went on the wire.
    pub const WATCHDOG: u16 = 1 << 4;
    /// A frame that matched nothing we sent was received (and ignored).
    pub const UNMATCHED: u16 = 1 << 5;
    /// The DC controller moved the master's wake-up time (master_follows_ref).
    pub const DC_ADJUSTED: u16 = 1 << 6;
    /// An acyclic (mailbox) frame was sent after the cyclic frame.
    pub const ACYCLIC: u16 = 1 << 7;
    /// The thread woke a whole cycle or more too late: cycles were skipped.
    pub const OVERRUN: u16 = 1 << 8;
    /// Sending the cyclic frame failed (link down, no buffer space).
    pub const SEND_ERROR: u16 = 1 << 9;
}

/// One cycle as the real-time thread saw it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SampleRecord {
    /// The cycle number.
    pub cycle: u64,
    /// Actual wake-up, CLOCK_MONOTONIC ns.
    pub t_wake_ns: u64,
    /// Actual minus planned wake-up.
    pub wake_latency_ns: i64,
    /// Wake-up to cyclic frame sent.
    pub exec_ns: u32,
    /// Time since the previous wake-up.
    pub period_ns: u32,
    /// Round trip of the cyclic reply processed in this cycle (0 when none).
    pub rtt_ns: u32,
    /// Sum of the logical datagrams' working counters of the replies processed this cycle.
    pub wkc: u16,
    /// What happened in the cycle (`flags`).
    pub flags: u16,
    /// Distributed-clock difference (see docs/engine.md, "DC modes").
    pub dc_diff_ns: i32,
    /// Bit k: the reply to cyclic frame k was declared lost in this cycle.
    pub lost_mask: u32,
    /// Bit k: frame k's inputs in this cycle's image are stale: no reply to it came back whole
    /// (every working counter as expected) within two of its periods, or none ever did.
    pub stale_mask: u32,
}

impl SampleRecord {
    /// Little-endian layout: cycle u64, t_wake u64, latency i64, exec u32, period u32, rtt u32,
    /// wkc u16, flags u16, dc_diff i32, lost_mask u32, stale_mask u32, 4 reserved bytes (0).
    pub fn encode(&self, out: &mut [u8]) {
        out[0..8].copy_from_slice(&self.cycle.to_le_bytes());
        out[8..16].copy_from_slice(&self.t_wake_ns.to_le_bytes());
        out[16..24].copy_from_slice(&self.wake_latency_ns.to_le_bytes());
        out[24..28].copy_from_slice(&self.exec_ns.to_le_bytes());
        out[28..32].copy_from_slice(&self.period_ns.to_le_bytes());
        out[32..36].copy_from_slice(&self.rtt_ns.to_le_bytes());
        out[36..38].copy_from_slice(&self.wkc.to_le_bytes());
        out[38..40].copy_from_slice(&self.flags.to_le_bytes());
        out[40..44].copy_from_slice(&self.dc_diff_ns.to_le_bytes());
        out[44..48].copy_from_slice(&self.lost_mask.to_le_bytes());
        out[48..52].copy_from_slice(&self.stale_mask.to_le_bytes());
        out[52..56].fill(0);
    }

    /// Read a record from its `RECORD_LEN` bytes.
    pub fn decode(b: &[u8]) -> SampleRecord {
        let u64_at = |i: usize| u64::from_le_bytes(b[i..i + 8].try_into().unwrap());
        let u32_at = |i: usize| u32::from_le_bytes(b[i..i + 4].try_into().unwrap());
        let u16_at = |i: usize| u16::from_le_bytes(b[i..i + 2].try_into().unwrap());
        SampleRecord {
            cycle: u64_at(0),
            t_wake_ns: u64_at(8),
            wake_latency_ns: u64_at(16) as i64,
            exec_ns: u32_at(24),
            period_ns: u32_at(28),
            rtt_ns: u32_at(32),
            wkc: u16_at(36),
            flags: u16_at(38),
            dc_diff_ns: u32_at(40) as i32,
            lost_mask: u32_at(44),
            stale_mask: u32_at(48),
        }
    }
}

/// Single-producer (RT thread) single-consumer (Python, serialized by the caller) ring of
/// sample records, each with a copy of the process image.
pub struct SampleRing {
    capacity: usize,
    image_len: usize,
    records: Box<[UnsafeCell<[u8; RECORD_LEN]>]>,
    images: Box<[UnsafeCell<u8>]>,
    /// Next slot the producer writes (monotonic count).
    head: AtomicUsize,
    /// Next slot the consumer reads (monotonic count).
    tail: AtomicUsize,
    dropped: AtomicU64,
}

// SAFETY: slots between tail and head belong to the consumer, the others to the producer; the
// indices are exchanged with release/acquire, so no slot is ever accessed by both at once.
unsafe impl Sync for SampleRing {}
unsafe impl Send for SampleRing {}

impl SampleRing {
    pub fn new(capacity: usize, image_len: usize) -> SampleRing {
        let capacity = capacity.max(1);
        SampleRing {
            capacity,
            image_len,
            records: (0..capacity)
                .map(|_| UnsafeCell::new([0u8; RECORD_LEN]))
                .collect(),
            images: (0..capacity * image_len)
                .map(|_| UnsafeCell::new(0))
                .collect(),
            head: AtomicUsize::new(0),
            tail: AtomicUsize::new(0),
            dropped: AtomicU64::new(0),
        }
    }

    /// Samples dropped because the consumer lagged (the tests check the count).
    #[cfg(test)]
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// Producer: append a sample. Returns false (and counts it) when the ring is full.
    pub fn push(&self, record: &SampleRecord, image: &[u8]) -> bool {
        let head = self.head.load(Ordering::Relaxed);
        let tail = self.tail.load(Ordering::Acquire);
        if head.wrapping_sub(tail) >= self.capacity {
            self.dropped.fetch_add(1, Ordering::Relaxed);
            return false;
        }
        let slot = head % self.capacity;
        // SAFETY: the slot is outside [tail, head), so the consumer does not touch it.
        unsafe {
            record.encode(&mut *self.records[slot].get());
            let base = self.images[slot * self.image_len..].as_ptr() as *mut u8;
            let n = self.image_len.min(image.len());
            std::ptr::copy_nonoverlapping(image.as_ptr(), base, n);
        }
        self.head.store(head.wrapping_add(1), Ordering::Release);
        true
    }

    /// Consumer: move up to `max` samples out. Callers serialize consumers.
    pub fn drain(&self, max: usize, records: &mut Vec<u8>, images: &mut Vec<u8>) -> usize {
        let tail = self.tail.load(Ordering::Relaxed);
        let head = self.head.load(Ordering::Acquire);
        let n = head.wrapping_sub(tail).min(max);
        records.reserve(n * RECORD_LEN);
        images.reserve(n * self.image_len);
        for i in 0..n {
            let slot = tail.wrapping_add(i) % self.capacity;
            // SAFETY: the slot is inside [tail, head): the producer finished it (release on head).
            unsafe {
                records.extend_from_slice(&*self.records[slot].get());
                let base = self.images[slot * self.image_len..].as_ptr() as *const u8;
                images.extend_from_slice(std::slice::from_raw_parts(base, self.image_len));
            }
        }
        self.tail.store(tail.wrapping_add(n), Ordering::Release);
        n
    }
}

/// Mailbox states. The owner of the slot is fixed by the state: the requester in EMPTY, DONE,
/// TIMEOUT and ABORTED; the RT thread in SENDING and SENT; REQUESTED is the hand-over (the RT
/// thread takes it with a compare-and-swap, the requester may take it back the same way).
pub mod mailbox_state {
    pub const EMPTY: u32 = 0;
    pub const REQUESTED: u32 = 1;
    pub const SENDING: u32 = 2;
    pub const SENT: u32 = 3;
    pub const DONE: u32 = 4;
    pub const TIMEOUT: u32 = 5;
    pub const ABORTED: u32 = 6;
}

/// One-slot acyclic request mailbox between a `transact` caller and the RT thread.
pub struct Mailbox {
    pub state: AtomicU32,
    request: UnsafeCell<[u8; MAX_FRAME_LEN]>,
    request_len: AtomicUsize,
    reply: UnsafeCell<[u8; MAX_FRAME_LEN]>,
    reply_len: AtomicUsize,
    /// Answer wait limit relative to sending, ns (set by the requester).
    pub timeout_ns: AtomicI64,
    /// Absolute deadline, set by the RT thread when it sends.
    pub deadline_ns: AtomicI64,
}

// SAFETY: the buffers are only accessed by the owner that the state word designates (see
// `mailbox_state`), and ownership changes with release/acquire operations on the state.
unsafe impl Sync for Mailbox {}
unsafe impl Send for Mailbox {}

impl Default for Mailbox {
    fn default() -> Self {
        Mailbox {
            state: AtomicU32::new(mailbox_state::EMPTY),
            request: UnsafeCell::new([0; MAX_FRAME_LEN]),
            request_len: AtomicUsize::new(0),
            reply: UnsafeCell::new([0; MAX_FRAME_LEN]),
            reply_len: AtomicUsize::new(0),
            timeout_ns: AtomicI64::new(0),
            deadline_ns: AtomicI64::new(0),
        }
    }
}

impl Mailbox {
    /// Requester: post a frame (the slot must be EMPTY, which the requester owns).
    pub fn post(&self, frame: &[u8], timeout_ns: i64) {
        debug_assert_eq!(self.state.load(Ordering::Acquire), mailbox_state::EMPTY);
        // SAFETY: EMPTY: the requester owns the buffers.
        unsafe { (&mut (*self.request.get()))[..frame.len()].copy_from_slice(frame) };
        self.request_len.store(frame.len(), Ordering::Relaxed);
        self.timeout_ns.store(timeout_ns, Ordering::Relaxed);
        self.state
            .store(mailbox_state::REQUESTED, Ordering::Release);
    }

    /// RT thread: take a posted request. Returns the frame to send; the caller must then call
    /// `mark_sent`.
    pub fn take(&self) -> Option<&[u8]> {
        self.state
            .compare_exchange(
                mailbox_state::REQUESTED,
                mailbox_state::SENDING,
                Ordering::Acquire,
                Ordering::Relaxed,
            )
            .ok()?;
        let n = self.request_len.load(Ordering::Relaxed);
        // SAFETY: SENDING: the RT thread owns the buffers.
        Some(unsafe { &(&(*self.request.get()))[..n] })
    }

    /// The request frame, for matching replies while SENT (RT thread only).
    pub fn sent_request(&self) -> Option<&[u8]> {
        if self.state.load(Ordering::Acquire) != mailbox_state::SENT {
            return None;
        }
        let n = self.request_len.load(Ordering::Relaxed);
        // SAFETY: SENT: the RT thread owns the buffers.
        Some(unsafe { &(&(*self.request.get()))[..n] })
    }

    pub fn mark_sent(&self, now_ns: i64) {
        self.deadline_ns.store(
            now_ns + self.timeout_ns.load(Ordering::Relaxed),
            Ordering::Relaxed,
        );
        self.state.store(mailbox_state::SENT, Ordering::Release);
    }

    /// RT thread: hand a reply to the requester.
    pub fn deliver(&self, reply: &[u8]) {
        // SAFETY: called in SENT: the RT thread owns the buffers.
        unsafe { (&mut (*self.reply.get()))[..reply.len()].copy_from_slice(reply) };
        self.reply_len.store(reply.len(), Ordering::Relaxed);
        self.state.store(mailbox_state::DONE, Ordering::Release);
    }

    /// RT thread: give up on a request whose answer is overdue.
    pub fn expire(&self, now_ns: i64) -> bool {
        if self.state.load(Ordering::Acquire) == mailbox_state::SENT
            && now_ns > self.deadline_ns.load(Ordering::Relaxed)
        {
            self.state.store(mailbox_state::TIMEOUT, Ordering::Release);
            return true;
        }
        false
    }

    /// Requester: the reply frame (valid in DONE).
    pub fn reply(&self) -> Vec<u8> {
        let n = self.reply_len.load(Ordering::Relaxed);
        // SAFETY: DONE: the requester owns the buffers.
        unsafe { (&(*self.reply.get()))[..n].to_vec() }
    }

    /// Requester: withdraw a request the RT thread has not taken yet.
    pub fn cancel(&self) -> bool {
        self.state
            .compare_exchange(
                mailbox_state::REQUESTED,
                mailbox_state::EMPTY,
                Ordering::AcqRel,
                Ordering::Relaxed,
            )
            .is_ok()
    }

    /// After the RT thread stopped: whatever it held is aborted so a waiter can retry directly.
    pub fn abort_pending(&self) {
        for s in [
            mailbox_state::REQUESTED,
            mailbox_state::SENDING,
            mailbox_state::SENT,
        ] {
            let _ = self.state.compare_exchange(
                s,
                mailbox_state::ABORTED,
                Ordering::AcqRel,
                Ordering::Relaxed,
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    #[test]
    fn seqlock_readers_never_accept_a_torn_copy() {
        let buf = Arc::new(SeqBuffer::new(&[0u8; 256]));
        let writer = {
            let buf = buf.clone();
            std::thread::spawn(move || {
                for k in 0..20_000u32 {
                    buf.write(0, &[(k % 251) as u8; 256]);
                }
            })
        };
        let mut dst = [0u8; 256];
        let mut accepted = 0;
        while !writer.is_finished() || accepted == 0 {
            if buf.try_read(&mut dst).is_some() {
                accepted += 1;
                assert!(dst.iter().all(|&b| b == dst[0]), "torn copy accepted");
            }
        }
        writer.join().unwrap();
        assert_eq!(buf.read(), vec![(19_999 % 251) as u8; 256]);
    }

    #[test]
    fn full_ring_drops_the_new_sample_and_keeps_the_old() {
        let ring = SampleRing::new(2, 3);
        for c in 0..4u64 {
            let pushed = ring.push(
                &SampleRecord {
                    cycle: c,
                    ..Default::default()
                },
                &[c as u8; 3],
            );
            assert_eq!(pushed, c < 2);
        }
        assert_eq!(ring.dropped(), 2);
        let (mut recs, mut imgs) = (Vec::new(), Vec::new());
        assert_eq!(ring.drain(10, &mut recs, &mut imgs), 2);
        let cycles: Vec<u64> = recs
            .chunks(RECORD_LEN)
            .map(|r| SampleRecord::decode(r).cycle)
            .collect();
        assert_eq!(cycles, vec![0, 1]);
        assert_eq!(imgs, vec![0, 0, 0, 1, 1, 1]);
        assert!(ring.push(&SampleRecord::default(), &[9; 3]));
    }

    #[test]
    fn record_round_trips() {
        let r = SampleRecord {
            cycle: 1 << 40,
            t_wake_ns: 123,
            wake_latency_ns: -7,
            exec_ns: 4000,
            period_ns: 400_000,
            rtt_ns: 20_000,
            wkc: 12,
            flags: flags::LOST | flags::PANIC,
            dc_diff_ns: -99,
            lost_mask: 0b101,
            stale_mask: 0b110,
        };
        let mut b = [0u8; RECORD_LEN];
        r.encode(&mut b);
        assert_eq!(SampleRecord::decode(&b), r);
    }

    #[test]
    fn mailbox_hands_ownership_back_and_forth() {
        use mailbox_state::*;
        let mb = Mailbox::default();
        mb.post(&[1, 2, 3], 1_000);
        assert!(mb.cancel(), "an untaken request can be withdrawn");
        assert_eq!(mb.state.load(Ordering::Acquire), EMPTY);
        mb.post(&[1, 2, 3], 1_000);
        assert_eq!(mb.take(), Some(&[1u8, 2, 3][..]));
        assert!(!mb.cancel(), "a taken request belongs to the RT thread");
        assert!(mb.take().is_none());
        mb.mark_sent(10_000);
        assert_eq!(mb.sent_request(), Some(&[1u8, 2, 3][..]));
        assert!(!mb.expire(10_500));
        mb.deliver(&[4, 5]);
        assert_eq!(mb.state.load(Ordering::Acquire), DONE);
        assert_eq!(mb.reply(), vec![4, 5]);
        mb.state.store(EMPTY, Ordering::Release);
        mb.post(&[7], 1_000);
        mb.take();
        mb.mark_sent(0);
        assert!(mb.expire(1_001));
        assert_eq!(mb.state.load(Ordering::Acquire), TIMEOUT);
        mb.state.store(EMPTY, Ordering::Release);
        mb.post(&[7], 1_000);
        mb.abort_pending();
        assert_eq!(mb.state.load(Ordering::Acquire), ABORTED);
    }
}
