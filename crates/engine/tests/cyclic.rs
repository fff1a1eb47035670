//! The engine against a tiny ESC-like responder behind a test link: acyclic transactions,
//! the cyclic exchange, panic, watchdog, lost and foreign frames, DC follow mode.

use std::collections::VecDeque;
use std::io;
use std::sync::{Arc, Mutex};

use ether_ros_engine::plan::{DcMode, DcPlan, Order};
use ether_ros_engine::{
    flags, now_ns, Engine, Error, Link, OutputField, Plan, Received, Request, SampleRecord,
    RECORD_LEN,
};
use ether_ros_protocol::{self as wire, reg, Command};

mod common;
use common::{counter, wait_for};

/// What the fake bus does and saw.
#[derive(Default)]
struct Bus {
    /// Outputs (image bytes 0..4 and 6..10) of every LRW frame seen, in order.
    outputs_seen: Vec<[u8; 8]>,
    /// Drop every frame while set.
    drop_all: bool,
    /// Add a foreign frame and a malformed one after every n-th reply (0 = never).
    junk_every: usize,
    frames: usize,
    /// Reference clock = monotonic + this offset (ns).
    ref_offset: i64,
    /// The last time written with FPWR 0x0910.
    written_time: Option<u64>,
}

struct FakeLink {
    bus: Arc<Mutex<Bus>>,
    queue: VecDeque<Vec<u8>>,
}

const INPUTS: [u8; 4] = [0x11, 0x22, 0x33, 0x44];

fn answer(bus: &mut Bus, frame: &mut [u8]) {
    let dgs: Vec<_> = wire::datagrams(frame)
        .unwrap()
        .map(|d| d.unwrap())
        .collect();
    for d in dgs {
        let s = d.slot;
        match d.command().unwrap() {
            Command::Lrw => {
                let data = &mut frame[s.data..s.data + s.len];
                let mut out = [0u8; 8];
                out[..4].copy_from_slice(&data[0..4]);
                out[4..].copy_from_slice(&data[6..10]);
                bus.outputs_seen.push(out);
                data[4..6].copy_from_slice(&INPUTS[..2]);
                data[10..12].copy_from_slice(&INPUTS[2..]);
                wire::write_wkc(frame, &s, 6);
            }
            Command::Frmw => {
                let t = (now_ns() + bus.ref_offset) as u64;
                frame[s.data..s.data + 8].copy_from_slice(&t.to_le_bytes());
                wire::write_wkc(frame, &s, 2);
            }
            Command::Fpwr => {
                if wire::split_address(d.address).1 == reg::DC_SYSTEM_TIME {
                    let t = u64::from_le_bytes(frame[s.data..s.data + 8].try_into().unwrap());
                    bus.written_time = Some(t);
                }
                wire::write_wkc(frame, &s, 1);
            }
            _ => {
                frame[s.data..s.data + s.len].fill(0xAB);
                wire::write_wkc(frame, &s, 1);
            }
        }
    }
}

impl Link for FakeLink {
    fn send(&mut self, frame: &[u8]) -> io::Result<()> {
        let mut bus = self.bus.lock().unwrap();
        bus.frames += 1;
        if bus.drop_all {
            return Ok(());
        }
        let mut reply = frame.to_vec();
        answer(&mut bus, &mut reply);
        self.queue.push_back(reply);
        if bus.junk_every > 0 && bus.frames.is_multiple_of(bus.junk_every) {
            // A frame of another EtherType, one with a lying length, one with a foreign index.
            let mut foreign = frame.to_vec();
            foreign[12] = 0x08;
            self.queue.push_back(foreign);
            let mut bad = frame.to_vec();
            bad[14] = 0xff;
            bad[15] = 0x17;
            self.queue.push_back(bad);
            let mut other = frame.to_vec();
            other[17] = 0x7e;
            self.queue.push_back(other);
            self.queue.push_back(vec![1, 2, 3]);
        }
        Ok(())
    }

    fn recv(&mut self, buf: &mut [u8], _deadline_ns: i64) -> io::Result<Option<Received>> {
        Ok(common::pop_reply(&mut self.queue, buf))
    }

    fn describe(&self) -> String {
        "fake bus".into()
    }
}

fn engine() -> (Engine, Arc<Mutex<Bus>>) {
    let bus = Arc::new(Mutex::new(Bus::default()));
    let link = FakeLink {
        bus: bus.clone(),
        queue: VecDeque::new(),
    };
    (Engine::with_link(Box::new(link)), bus)
}

fn plan(order: Order, mode: DcMode) -> Plan {
    Plan {
        cycle_ns: 1_000_000,
        order,
        frames: common::cyclic_frame(mode, 12, 6),
        image_len: 12,
        output_ranges: vec![(0, 4), (6, 4)],
        initial_image: vec![1; 12],
        safe_image: vec![0xEE; 12],
        dc: DcPlan {
            mode,
            time_offset_ns: 0,
            sync0_shift_ns: 0,
        },
        rt: common::non_rt(),
        watchdog_ns: 0,
        ring_capacity: 100_000,
        axes: Vec::new(),
        trajectory_capacity: 16,
    }
}

fn records(e: &Engine) -> Vec<SampleRecord> {
    let (r, _, _) = e.drain_samples(usize::MAX);
    r.chunks(RECORD_LEN).map(SampleRecord::decode).collect()
}

#[test]
fn transact_returns_data_and_wkc_per_datagram() {
    let (e, _bus) = engine();
    let got = e
        .transact(
            &[
                Request {
                    cmd: Command::Brd,
                    address: 0,
                    data: None,
                    len: 2,
                },
                Request {
                    cmd: Command::Fpwr,
                    address: wire::fixed_address(0x1001, 0x120),
                    data: Some(vec![2, 0]),
                    len: 0,
                },
            ],
            1_000_000,
            0,
        )
        .unwrap();
    assert_eq!(got, vec![(vec![0xAB, 0xAB], 1), (vec![2, 0], 1)]);
}

#[test]
fn transact_retries_then_reports_timeout() {
    let (e, bus) = engine();
    bus.lock().unwrap().drop_all = true;
    let err = e
        .transact(
            &[Request {
                cmd: Command::Brd,
                address: 0,
                data: None,
                len: 2,
            }],
            1000,
            2,
        )
        .unwrap_err();
    assert!(
        matches!(err, Error::Timeout { attempts: 3, timeout_us: 1, ref commands, .. } if commands == &["BRD"]),
        "{err:?}"
    );
    assert_eq!(bus.lock().unwrap().frames, 3);
}

#[test]
fn cyclic_exchanges_outputs_inputs_and_samples() {
    for order in [Order::SendAtWake, Order::SendThenWait] {
        let (e, bus) = engine();
        e.start_cyclic(plan(order, DcMode::RefFollowsMaster))
            .unwrap();
        assert!(e.is_running());
        e.write_outputs(0, &[9, 8, 7, 6]).unwrap();
        e.write_outputs(6, &[5, 4, 3, 2]).unwrap();
        wait_for(
            || bus.lock().unwrap().outputs_seen.last() == Some(&[9, 8, 7, 6, 5, 4, 3, 2]),
            "outputs on the wire",
        );
        wait_for(
            || e.read_inputs().unwrap() == vec![9, 8, 7, 6, 0x11, 0x22, 5, 4, 3, 2, 0x33, 0x44],
            "inputs",
        );
        // Writes outside the output ranges are refused, naming the ranges.
        let err = e.write_outputs(3, &[0, 0]).unwrap_err();
        assert!(
            matches!(err, Error::Invalid(ref m) if m.contains("[(0, 4), (6, 4)]")),
            "{err:?}"
        );
        // Acyclic traffic goes through the mailbox while cyclic.
        let got = e
            .transact(
                &[Request {
                    cmd: Command::Fprd,
                    address: 0,
                    data: None,
                    len: 3,
                }],
                50_000_000,
                3,
            )
            .unwrap();
        assert_eq!(got, vec![(vec![0xAB; 3], 1)]);
        assert!(counter(&e, "acyclic_frames") >= 1);
        wait_for(
            || bus.lock().unwrap().written_time.is_some(),
            "DC time written",
        );
        e.stop_cyclic();
        assert!(!e.is_running());
        let recs = records(&e);
        assert!(recs.len() >= 3);
        for w in recs.windows(2) {
            assert_eq!(w[1].cycle, w[0].cycle + 1);
            assert!(w[1].t_wake_ns > w[0].t_wake_ns);
        }
        assert!(recs.iter().any(|r| r.flags & flags::ACYCLIC != 0));
        let answered: Vec<_> = recs
            .iter()
            .filter(|r| r.flags & flags::LOST == 0 && r.rtt_ns > 0)
            .collect();
        assert!(!answered.is_empty());
        assert!(answered
            .iter()
            .all(|r| r.wkc == 6 && r.flags & flags::WKC_ERROR == 0));
        assert_eq!(counter(&e, "cycles"), recs.len() as u64);
        // After stopping, the link is back: direct transactions work again.
        assert!(e
            .transact(
                &[Request {
                    cmd: Command::Brd,
                    address: 0,
                    data: None,
                    len: 1
                }],
                1_000_000,
                0
            )
            .is_ok());
    }
}

fn field(bit_offset: usize, bit_length: u32, raw: u64) -> OutputField {
    OutputField {
        bit_offset,
        bit_length,
        raw,
    }
}

#[test]
fn output_fields_change_only_their_bits() {
    let (e, bus) = engine();
    // No process image before the first start.
    assert!(matches!(
        e.write_output_fields(&[field(0, 1, 1)]),
        Err(Error::State(_))
    ));
    e.start_cyclic(plan(Order::SendAtWake, DcMode::Off))
        .unwrap();
    e.write_outputs(0, &[0xFF, 0x00, 0xFF, 0x00]).unwrap();
    e.write_outputs(6, &[0x00; 4]).unwrap();
    // Two fields in one call: 3 bits at bit 1 of byte 0 (clears 0b1110 of 0xFF) and a 12-bit
    // value straddling bytes 1 and 2 from bit 4 of byte 1.
    e.write_output_fields(&[field(1, 3, 0b010), field(12, 12, 0xABC)])
        .unwrap();
    assert_eq!(&e.outputs().unwrap()[..4], &[0xF5, 0xC0, 0xAB, 0x00]);
    // 1 bit, 16 and 32 bits at odd offsets in the second range; the rest stays.
    e.write_output_fields(&[field(48 + 7, 1, 1)]).unwrap();
    e.write_output_fields(&[field(48 + 9, 16, 0xFFFF)]).unwrap();
    assert_eq!(&e.outputs().unwrap()[6..10], &[0x80, 0xFE, 0xFF, 0x01]);
    e.write_output_fields(&[field(48, 32, 0x0403_0201)])
        .unwrap();
    assert_eq!(&e.outputs().unwrap()[6..10], &[1, 2, 3, 4]);
    // An empty list writes nothing and is fine.
    e.write_output_fields(&[]).unwrap();
    wait_for(
        || bus.lock().unwrap().outputs_seen.last() == Some(&[0xF5, 0xC0, 0xAB, 0x00, 1, 2, 3, 4]),
        "fields on the wire",
    );
    e.stop_cyclic();
}

#[test]
fn a_bad_output_field_writes_nothing() {
    let (e, _bus) = engine();
    let mut p = plan(Order::SendAtWake, DcMode::Off);
    p.image_len = 16;
    p.initial_image = vec![1; 16];
    p.safe_image = vec![0xEE; 16];
    p.output_ranges = vec![(0, 4), (6, 4), (12, 4)];
    p.frames = common::cyclic_frame(DcMode::Off, 16, 6);
    e.start_cyclic(p).unwrap();
    let before = e.outputs().unwrap();
    let cases = [
        // Reaches from output byte 3 into input byte 4.
        (field(30, 4, 0), "image bytes 3..5"),
        // Wholly inside the inputs.
        (field(33, 1, 1), "image bytes 4..5"),
        // Past the end of the image.
        (field(120, 16, 1), "image bytes 15..17"),
        // Malformed.
        (field(0, 0, 0), "1..=64"),
        (field(0, 65, 0), "1..=64"),
        (field(0, 3, 8), "does not fit in 3 bit(s)"),
        (field(usize::MAX - 3, 8, 0), "overflows"),
    ];
    for (bad, why) in cases {
        // The good field before the bad one must not be written either.
        let err = e
            .write_output_fields(&[field(0, 8, 0x55), field(96, 32, 0xFFFF_FFFF), bad])
            .unwrap_err();
        assert!(
            matches!(err, Error::Invalid(ref m) if m.contains("output field #2") && m.contains(why)),
            "{bad:?}: {err:?}"
        );
        assert_eq!(e.outputs().unwrap(), before, "{bad:?} wrote something");
    }
    let err = e.write_output_fields(&[field(30, 4, 0)]).unwrap_err();
    assert!(
        matches!(err, Error::Invalid(ref m) if m.contains("[(0, 4), (6, 4), (12, 4)]")),
        "{err:?}"
    );
    // A field of a whole range, and one bridging two ranges through the gap, are refused
    // only in the second case.
    e.write_output_fields(&[field(96, 32, 7)]).unwrap();
    assert!(e.write_output_fields(&[field(72, 32, 0)]).is_err());
    e.stop_cyclic();
}

#[test]
fn concurrent_field_writers_keep_each_others_bits() {
    let (e, bus) = engine();
    e.start_cyclic(plan(Order::SendAtWake, DcMode::Off))
        .unwrap();
    e.write_outputs(0, &[0; 4]).unwrap();
    e.write_outputs(6, &[0; 4]).unwrap();
    let e = Arc::new(e);
    const ROUNDS: u64 = 20_000;
    // Writer A owns bits 0..12 and the pair (bytes 6..8, bytes 8..10), which it always
    // writes equal in one call; writer B owns bits 12..32. Without the masked write under the
    // lock, one writer's stale copy of the other's bits would come back.
    let a = {
        let e = e.clone();
        std::thread::spawn(move || {
            for k in 1..=ROUNDS {
                let v = k & 0xFFF;
                let pair = k & 0xFFFF;
                e.write_output_fields(&[field(0, 12, v), field(48, 16, pair), field(64, 16, pair)])
                    .unwrap();
            }
        })
    };
    let b = {
        let e = e.clone();
        std::thread::spawn(move || {
            for k in 1..=ROUNDS {
                e.write_output_fields(&[field(12, 20, k)]).unwrap();
            }
        })
    };
    while !(a.is_finished() && b.is_finished()) {
        let out = e.outputs().unwrap();
        assert_eq!(out[6..8], out[8..10], "a torn write was read");
    }
    a.join().unwrap();
    b.join().unwrap();
    let out = e.outputs().unwrap();
    let low = u32::from_le_bytes(out[0..4].try_into().unwrap()) as u64;
    assert_eq!(low & 0xFFF, ROUNDS & 0xFFF, "writer A's bits");
    assert_eq!(low >> 12, ROUNDS, "writer B's bits");
    assert_eq!(out[6..8], (ROUNDS as u16).to_le_bytes());
    let want = out[..4].to_vec();
    wait_for(
        || {
            bus.lock()
                .unwrap()
                .outputs_seen
                .last()
                .map(|o| o[..4].to_vec())
                == Some(want.clone())
        },
        "the final fields on the wire",
    );
    // Every frame carried writer A's pair from one call (the same cycle).
    assert!(bus
        .lock()
        .unwrap()
        .outputs_seen
        .iter()
        .all(|o| o[4..6] == o[6..8]));
    e.stop_cyclic();
}

#[test]
fn panic_puts_the_safe_image_on_the_wire_within_two_frames() {
    let (e, bus) = engine();
    e.start_cyclic(plan(Order::SendAtWake, DcMode::Off))
        .unwrap();
    e.write_outputs(0, &[1, 2, 3, 4]).unwrap();
    wait_for(
        || bus.lock().unwrap().outputs_seen.last().map(|o| o[0]) == Some(1),
        "live outputs",
    );
    let before = bus.lock().unwrap().outputs_seen.len();
    e.panic();
    wait_for(
        || bus.lock().unwrap().outputs_seen.len() >= before + 3,
        "three more frames",
    );
    let seen = bus.lock().unwrap().outputs_seen.clone();
    let first_safe = seen[before..]
        .iter()
        .position(|o| *o == [0xEE; 8])
        .expect("safe image sent");
    assert!(
        first_safe <= 1,
        "safe outputs only {} frames after panic()",
        first_safe + 1
    );
    assert!(seen[before + first_safe..].iter().all(|o| *o == [0xEE; 8]));
    assert_eq!(counter(&e, "panics"), 1);
    // Clearing does not restart: a new command brings live outputs back.
    e.clear_panic();
    e.write_outputs(0, &[5, 5, 5, 5]).unwrap();
    wait_for(
        || bus.lock().unwrap().outputs_seen.last().map(|o| o[0]) == Some(5),
        "live outputs again",
    );
    e.stop_cyclic();
    assert!(records(&e).iter().any(|r| r.flags & flags::PANIC != 0));
}

#[test]
fn watchdog_switches_to_safe_outputs_when_commands_stop() {
    let (e, bus) = engine();
    let mut p = plan(Order::SendThenWait, DcMode::Off);
    p.watchdog_ns = 20_000_000;
    e.start_cyclic(p).unwrap();
    e.write_outputs(0, &[1, 2, 3, 4]).unwrap();
    wait_for(
        || bus.lock().unwrap().outputs_seen.last() == Some(&[0xEE; 8]),
        "watchdog safe image",
    );
    assert!(counter(&e, "watchdog_trips") >= 1);
    // A new command brings live outputs back. With a 20 ms watchdog a test thread held off
    // by a loaded host may find them already replaced by the safe image again, so any frame
    // since the write counts, not only the latest.
    let fed_at = bus.lock().unwrap().outputs_seen.len();
    e.write_outputs(0, &[7, 7, 7, 7]).unwrap();
    wait_for(
        || {
            bus.lock().unwrap().outputs_seen[fed_at..]
                .iter()
                .any(|o| o[0] == 7)
        },
        "outputs after feeding",
    );
    e.stop_cyclic();
    assert!(records(&e).iter().any(|r| r.flags & flags::WATCHDOG != 0));
}

/// Frames seen on the bus from `from` on.
fn seen_since(bus: &Arc<Mutex<Bus>>, from: usize) -> Vec<[u8; 8]> {
    bus.lock().unwrap().outputs_seen[from..].to_vec()
}

const A: [u8; 4] = [1, 2, 3, 4];
const B: [u8; 4] = [9, 9, 9, 9];
const SAFE: [u8; 4] = [0xEE; 4];

/// Output ranges A (image 0..4) and B (6..10) live on the wire.
fn live_a_and_b(e: &Engine, bus: &Arc<Mutex<Bus>>) {
    e.write_outputs(0, &A).unwrap();
    e.write_outputs(6, &B).unwrap();
    wait_for(
        || bus.lock().unwrap().outputs_seen.last() == Some(&[1, 2, 3, 4, 9, 9, 9, 9]),
        "live outputs A and B",
    );
}

#[test]
fn clearing_a_panic_keeps_the_safe_image_until_a_new_command() {
    // ISO 13850: resetting the stop does not restart. The outputs commanded before the panic
    // never come back; a later partial write changes only what it writes.
    let (e, bus) = engine();
    e.start_cyclic(plan(Order::SendAtWake, DcMode::Off))
        .unwrap();
    live_a_and_b(&e, &bus);
    e.panic();
    wait_for(
        || bus.lock().unwrap().outputs_seen.last() == Some(&[0xEE; 8]),
        "safe image",
    );
    e.clear_panic();
    let cleared = bus.lock().unwrap().outputs_seen.len();
    assert!(!e.is_panicked());
    let mut expected = vec![1u8; 12];
    expected[..4].copy_from_slice(&SAFE);
    expected[6..10].copy_from_slice(&SAFE);
    assert_eq!(
        e.outputs().unwrap(),
        expected,
        "the buffer is back at the safe image"
    );
    wait_for(
        || bus.lock().unwrap().outputs_seen.len() >= cleared + 20,
        "twenty frames after the clear",
    );
    // The frame being built when the clear came may still be the panic's: safe either way.
    assert!(seen_since(&bus, cleared.saturating_sub(1))
        .iter()
        .all(|o| *o == [0xEE; 8]));
    // A command for A: A live, B stays safe (its old value never returns).
    let written = bus.lock().unwrap().outputs_seen.len();
    e.write_outputs(0, &[5, 5, 5, 5]).unwrap();
    wait_for(
        || bus.lock().unwrap().outputs_seen.last() == Some(&[5, 5, 5, 5, 0xEE, 0xEE, 0xEE, 0xEE]),
        "A live, B safe",
    );
    for o in seen_since(&bus, written) {
        assert_eq!(o[4..], SAFE, "B re-activated by a write to A: {o:?}");
        assert!(o[..4] == SAFE || o[..4] == [5; 4], "{o:?}");
    }
    e.stop_cyclic();
}

#[test]
fn a_watchdog_trip_voids_the_commands_before_it() {
    let (e, bus) = engine();
    let mut p = plan(Order::SendAtWake, DcMode::Off);
    p.watchdog_ns = 50_000_000;
    e.start_cyclic(p).unwrap();
    live_a_and_b(&e, &bus);
    wait_for(
        || bus.lock().unwrap().outputs_seen.last() == Some(&[0xEE; 8]),
        "watchdog safe image",
    );
    let tripped = bus.lock().unwrap().outputs_seen.len();
    assert!(counter(&e, "watchdog_trips") >= 1);
    // A feed is no command for any output: the buffer shows the safe values, and they stay.
    e.feed_watchdog();
    let mut expected = vec![1u8; 12];
    expected[..4].copy_from_slice(&SAFE);
    expected[6..10].copy_from_slice(&SAFE);
    assert_eq!(e.outputs().unwrap(), expected);
    // A command for A only: A live, B stays safe.
    e.write_outputs(0, &[7, 7, 7, 7]).unwrap();
    wait_for(
        || seen_since(&bus, tripped).iter().any(|o| o[..4] == [7; 4]),
        "A live after the trip",
    );
    for o in seen_since(&bus, tripped) {
        assert_eq!(
            o[4..],
            SAFE,
            "B's command from before the trip came back: {o:?}"
        );
        assert!(o[..4] == SAFE || o[..4] == [7; 4], "{o:?}");
    }
    // A field write after the next trip merges into the safe bytes, not the old command.
    wait_for(
        || bus.lock().unwrap().outputs_seen.last() == Some(&[0xEE; 8]),
        "tripped again",
    );
    let tripped = bus.lock().unwrap().outputs_seen.len();
    e.write_output_fields(&[field(6 * 8, 8, 0x42)]).unwrap();
    wait_for(
        || seen_since(&bus, tripped).iter().any(|o| o[4] == 0x42),
        "the field live",
    );
    for o in seen_since(&bus, tripped) {
        assert_eq!(
            o[..4],
            SAFE,
            "A's command from before the trip came back: {o:?}"
        );
        assert!(
            o[4..] == SAFE || o[4..] == [0x42, 0xEE, 0xEE, 0xEE],
            "{o:?}"
        );
    }
    e.stop_cyclic();
}

#[test]
fn no_cycle_sends_a_voided_command_while_another_writer_races_the_stops() {
    // B is commanded once; a writer thread keeps commanding A while the main thread panics
    // and clears, again and again, and starves nothing. After the first clear, B's old value
    // must never reach the wire again, whatever the interleaving.
    let (e, bus) = engine();
    let e = Arc::new(e);
    let mut p = plan(Order::SendAtWake, DcMode::Off);
    p.cycle_ns = 100_000;
    e.start_cyclic(p).unwrap();
    live_a_and_b(&e, &bus);
    let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let writer = {
        let (e, stop) = (e.clone(), stop.clone());
        std::thread::spawn(move || {
            let mut k = 0u8;
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                k = k.wrapping_add(1) % 100;
                e.write_output_fields(&[field(0, 8, k as u64)]).unwrap();
            }
        })
    };
    e.panic();
    wait_for(
        || bus.lock().unwrap().outputs_seen.last().map(|o| o[4]) == Some(0xEE),
        "safe image",
    );
    e.clear_panic();
    let cleared = bus.lock().unwrap().outputs_seen.len();
    for _ in 0..200 {
        e.panic();
        std::thread::sleep(std::time::Duration::from_micros(150));
        e.clear_panic();
        std::thread::sleep(std::time::Duration::from_micros(150));
    }
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    writer.join().unwrap();
    let seen = seen_since(&bus, cleared.saturating_sub(1));
    assert!(seen.len() > 100, "only {} frames", seen.len());
    for o in &seen {
        assert_eq!(o[4..], SAFE, "B's voided command on the wire: {o:?}");
        assert!(o[1..4] == SAFE[1..], "A's voided bytes on the wire: {o:?}");
    }
    e.stop_cyclic();
}

#[test]
fn lost_and_foreign_frames_are_counted_and_do_not_disturb_the_loop() {
    let (e, bus) = engine();
    bus.lock().unwrap().junk_every = 2;
    e.start_cyclic(plan(Order::SendAtWake, DcMode::Off))
        .unwrap();
    wait_for(|| counter(&e, "unmatched_frames") >= 20, "junk counted");
    bus.lock().unwrap().drop_all = true;
    wait_for(|| counter(&e, "lost_frames") >= 3, "lost frames counted");
    {
        let mut b = bus.lock().unwrap();
        b.drop_all = false;
        b.junk_every = 0;
    }
    e.write_outputs(0, &[3, 3, 3, 3]).unwrap();
    wait_for(|| e.read_inputs().unwrap()[4] == 0x11, "exchange continues");
    e.stop_cyclic();
    let recs = records(&e);
    assert!(recs.iter().any(|r| r.flags & flags::LOST != 0));
    assert!(recs.iter().any(|r| r.flags & flags::UNMATCHED != 0));
}

#[test]
fn master_follows_the_reference_clock_phase() {
    let (e, bus) = engine();
    // The reference clock sits at an odd phase against CLOCK_MONOTONIC.
    bus.lock().unwrap().ref_offset = 123_456_789_000 + 370_000;
    e.start_cyclic(plan(Order::SendThenWait, DcMode::MasterFollowsRef))
        .unwrap();
    wait_for(|| counter(&e, "cycles") >= 60, "cycles");
    e.stop_cyclic();
    let recs = records(&e);
    let mut tail: Vec<i64> = recs[recs.len() - 30..]
        .iter()
        .map(|r| (r.dc_diff_ns as i64).abs())
        .collect();
    tail.sort();
    // Without following, the phase error would stay at 370 µs of the 1 ms cycle.
    assert!(
        tail[tail.len() / 2] < 100_000,
        "median phase error {} ns",
        tail[tail.len() / 2]
    );
    assert!(recs.iter().any(|r| r.flags & flags::DC_ADJUSTED != 0));
}

#[test]
fn lifecycle_errors_are_clear() {
    let (e, _bus) = engine();
    assert!(matches!(e.write_outputs(0, &[1]), Err(Error::State(_))));
    e.start_cyclic(plan(Order::SendAtWake, DcMode::Off))
        .unwrap();
    assert!(matches!(
        e.start_cyclic(plan(Order::SendAtWake, DcMode::Off)),
        Err(Error::State(_))
    ));
    for _ in 0..5 {
        e.stop_cyclic();
        e.start_cyclic(plan(Order::SendAtWake, DcMode::Off))
            .unwrap();
    }
    e.reset_stats();
    e.close();
    assert!(!e.is_running());
    assert!(matches!(
        e.transact(
            &[Request {
                cmd: Command::Brd,
                address: 0,
                data: None,
                len: 1
            }],
            1000,
            0
        ),
        Err(Error::State(_))
    ));
    let mut bad = plan(Order::SendAtWake, DcMode::Off);
    bad.image_len = 3;
    assert!(
        matches!(e.start_cyclic(bad), Err(Error::Invalid(ref m)) if m.contains("initial_image"))
    );
    let _ = now_ns();
}
