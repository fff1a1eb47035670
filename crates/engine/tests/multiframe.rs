//! Cycles of several frames against a bus of fake slaves with their own logical areas: every
//! frame goes out, replies are matched by their index whatever order they come back in, each
//! logical datagram's working counter is checked, losses and late replies are counted per frame,
//! LRD + LWR serve a slave that refuses LRW, and a frame of a slower group goes out at its rate.

use std::collections::VecDeque;
use std::io;
use std::sync::{Arc, Mutex};

use ether_ros_engine::plan::{DcMode, DcPlan, FramePlan, Logical, Order};
use ether_ros_engine::{
    flags, Engine, FrameSnapshot, Link, Plan, Received, SampleRecord, RECORD_LEN,
};
use ether_ros_protocol::{self as wire, Command};

mod common;
use common::{logical, wait_for};

/// A slave's process data: `out` image bytes at `out_at` and `inp` bytes at `inp_at` (logical
/// address = 0x1_0000 + image offset, as `common::logical` lays them).
struct FakeSlave {
    out_at: usize,
    out: Vec<u8>,
    inp_at: usize,
    inp: Vec<u8>,
    /// ESC register 0x0008 bit 9 set: LRW is not processed (no data, no working counter).
    refuses_lrw: bool,
}

#[derive(Default)]
struct Bus {
    slaves: Vec<FakeSlave>,
    /// Frames whose first logical datagram starts at one of these image offsets are dropped.
    drop_at: Vec<usize>,
    /// ...or held back and delivered one send later (late replies).
    delay_at: Vec<usize>,
    /// Replies of one send burst are delivered in reverse order.
    reverse: bool,
    /// Frames seen per first-datagram image offset.
    seen: Vec<(usize, u64)>,
}

impl Bus {
    /// Process the logical datagrams of `frame` like the slaves' FMMUs would.
    fn answer(&mut self, frame: &mut [u8]) -> Option<usize> {
        let dgs: Vec<_> = wire::datagrams(frame)
            .unwrap()
            .map(|d| d.unwrap())
            .collect();
        let mut first = None;
        for d in dgs {
            let s = d.slot;
            let cmd = d.command().unwrap();
            let (reads, writes) = match cmd {
                Command::Lrw => (true, true),
                Command::Lrd => (true, false),
                Command::Lwr => (false, true),
                _ => {
                    wire::write_wkc(frame, &s, 1);
                    continue;
                }
            };
            let start = d.address as usize - 0x1_0000;
            first.get_or_insert(start);
            let mut wkc = 0u16;
            for sl in &mut self.slaves {
                if cmd == Command::Lrw && sl.refuses_lrw {
                    continue;
                }
                let overlap = |at: usize, len: usize| at < start + s.len && start < at + len;
                if writes && overlap(sl.out_at, sl.out.len()) {
                    for (i, b) in sl.out.iter_mut().enumerate() {
                        if let Some(k) = (sl.out_at + i).checked_sub(start).filter(|k| *k < s.len) {
                            *b = frame[s.data + k];
                        }
                    }
                    wkc += if cmd == Command::Lrw { 2 } else { 1 };
                }
                if reads && overlap(sl.inp_at, sl.inp.len()) {
                    for (i, b) in sl.inp.iter().enumerate() {
                        if let Some(k) = (sl.inp_at + i).checked_sub(start).filter(|k| *k < s.len) {
                            frame[s.data + k] = *b;
                        }
                    }
                    wkc += 1;
                }
            }
            wire::write_wkc(frame, &s, wkc);
        }
        first
    }
}

struct FakeLink {
    bus: Arc<Mutex<Bus>>,
    queue: VecDeque<Vec<u8>>,
    held: Vec<Vec<u8>>,
}

impl Link for FakeLink {
    fn send(&mut self, frame: &[u8]) -> io::Result<()> {
        let mut bus = self.bus.lock().unwrap();
        let mut reply = frame.to_vec();
        let Some(first) = bus.answer(&mut reply) else {
            self.queue.push_back(reply);
            return Ok(());
        };
        match bus.seen.iter_mut().find(|(at, _)| *at == first) {
            Some((_, n)) => *n += 1,
            None => bus.seen.push((first, 1)),
        }
        // Replies held back by the previous send come now: a cycle late.
        self.queue.extend(self.held.drain(..));
        if bus.drop_at.contains(&first) {
            return Ok(());
        }
        if bus.delay_at.contains(&first) {
            self.held.push(reply);
        } else if bus.reverse {
            self.queue.push_front(reply);
        } else {
            self.queue.push_back(reply);
        }
        Ok(())
    }

    fn recv(&mut self, buf: &mut [u8], _deadline_ns: i64) -> io::Result<Option<Received>> {
        Ok(common::pop_reply(&mut self.queue, buf))
    }

    fn describe(&self) -> String {
        "fake multi-frame bus".into()
    }
}

/// Bytes of outputs and of inputs per slave: two slaves fill most of a frame.
const AREA: usize = 350;

/// `n` slaves; slave `i` owns image bytes `i*2*AREA..` (outputs, then inputs). Its inputs
/// are `i + 1` repeated.
fn bus(n: usize) -> Arc<Mutex<Bus>> {
    let slaves = (0..n)
        .map(|i| FakeSlave {
            out_at: i * 2 * AREA,
            out: vec![0; AREA],
            inp_at: i * 2 * AREA + AREA,
            inp: vec![i as u8 + 1; AREA],
            refuses_lrw: false,
        })
        .collect();
    Arc::new(Mutex::new(Bus {
        slaves,
        ..Default::default()
    }))
}

fn engine(bus: &Arc<Mutex<Bus>>) -> Engine {
    Engine::with_link(Box::new(FakeLink {
        bus: bus.clone(),
        queue: VecDeque::new(),
        held: Vec::new(),
    }))
}

/// Two slaves per frame, one LRW each (wkc 3), DC datagrams in the first frame.
fn plan(n: usize, order: Order) -> Plan {
    let frames = (0..n.div_ceil(2))
        .map(|k| FramePlan {
            datagrams: (2 * k..(2 * k + 2).min(n))
                .map(|i| logical(Logical::Lrw, i * 2 * AREA, 2 * AREA, 3))
                .collect(),
            every: 1,
            watchdog_ns: 0,
        })
        .collect::<Vec<_>>();
    let mut p = Plan {
        cycle_ns: 1_000_000,
        order,
        frames,
        image_len: n * 2 * AREA,
        output_ranges: (0..n).map(|i| (i * 2 * AREA, AREA)).collect(),
        initial_image: vec![0; n * 2 * AREA],
        safe_image: vec![0xEE; n * 2 * AREA],
        dc: DcPlan {
            mode: DcMode::RefFollowsMaster,
            time_offset_ns: 0,
            sync0_shift_ns: 0,
        },
        rt: common::non_rt(),
        watchdog_ns: 0,
        ring_capacity: 4096,
        axes: Vec::new(),
        trajectory_capacity: 16,
    };
    let dc = common::cyclic_frame(DcMode::RefFollowsMaster, 1, 0);
    let dc = &dc[0].datagrams[..2];
    p.frames[0].datagrams.splice(0..0, dc.iter().copied());
    p
}

fn records(e: &Engine) -> Vec<SampleRecord> {
    let (r, _, _) = e.drain_samples(usize::MAX);
    r.chunks(RECORD_LEN).map(SampleRecord::decode).collect()
}

fn frame_counter(f: &FrameSnapshot, name: &str) -> u64 {
    f.counters.iter().find(|(n, _)| *n == name).unwrap().1
}

fn frames(e: &Engine) -> Vec<FrameSnapshot> {
    e.stats().frames
}

#[test]
fn three_frames_exchange_both_ways_matched_by_index_in_any_order() {
    for order in [Order::SendAtWake, Order::SendThenWait] {
        let b = bus(6);
        b.lock().unwrap().reverse = true;
        let e = engine(&b);
        e.start_cyclic(plan(6, order)).unwrap();
        for i in 0..6 {
            e.write_outputs(i * 2 * AREA, &vec![0x10 + i as u8; AREA])
                .unwrap();
        }
        wait_for(
            || {
                let img = e.read_inputs().unwrap();
                (0..6).all(|i| img[i * 2 * AREA + AREA..(i + 1) * 2 * AREA] == [i as u8 + 1; AREA])
            },
            "the inputs of all three frames",
        );
        wait_for(
            || {
                let bus = b.lock().unwrap();
                (0..6).all(|i| bus.slaves[i].out == [0x10 + i as u8; AREA])
            },
            "the outputs of all three frames",
        );
        wait_for(|| common::counter(&e, "cycles") > 20, "cycles");
        e.stop_cyclic();
        let stats = e.stats();
        assert_eq!(stats.frames.len(), 3);
        for f in &stats.frames {
            assert!(frame_counter(f, "sent") > 20);
            assert_eq!(frame_counter(f, "lost"), 0, "{order:?}");
            assert_eq!(frame_counter(f, "wkc_errors"), 0, "{order:?}");
            assert_eq!(frame_counter(f, "last_wkc"), 6);
            assert!(f.rtt.count > 20);
        }
        assert_eq!(common::counter(&e, "unmatched_frames"), 0, "{order:?}");
        let recs = records(&e);
        assert!(recs.iter().all(|r| r.flags & flags::LOST == 0), "{order:?}");
        assert!(recs.iter().any(|r| r.wkc == 18), "{order:?}");
    }
}

#[test]
fn working_counters_are_checked_per_datagram_and_summed_per_cycle() {
    let b = bus(6);
    let e = engine(&b);
    e.start_cyclic(plan(6, Order::SendThenWait)).unwrap();
    wait_for(
        || records(&e).iter().any(|r| r.wkc == 18),
        "wkc 6 × 3 frames",
    );
    // Slave 3 (frame 1) stops answering its LRW: only that frame's counter is wrong.
    b.lock().unwrap().slaves[3].refuses_lrw = true;
    wait_for(
        || frame_counter(&frames(&e)[1], "wkc_errors") > 5,
        "wkc errors",
    );
    e.stop_cyclic();
    let f = frames(&e);
    assert_eq!(frame_counter(&f[0], "wkc_errors"), 0);
    assert_eq!(frame_counter(&f[2], "wkc_errors"), 0);
    assert_eq!(frame_counter(&f[1], "last_wkc"), 3);
    assert!(common::counter(&e, "wkc_errors") > 5);
    let recs = records(&e);
    assert!(recs
        .iter()
        .any(|r| r.wkc == 15 && r.flags & flags::WKC_ERROR != 0));
}

#[test]
fn a_lost_or_late_frame_is_counted_against_that_frame_only() {
    let b = bus(6);
    b.lock().unwrap().drop_at = vec![2 * 2 * AREA]; // frame 1 (slaves 2 and 3)
    let e = engine(&b);
    e.start_cyclic(plan(6, Order::SendAtWake)).unwrap();
    wait_for(
        || frame_counter(&frames(&e)[1], "lost") > 10,
        "losses of frame 1",
    );
    let f = frames(&e);
    assert_eq!(frame_counter(&f[0], "lost"), 0);
    assert_eq!(frame_counter(&f[2], "lost"), 0);
    // The other frames' inputs still arrive.
    let img = e.read_inputs().unwrap();
    assert_eq!(img[5 * 2 * AREA + AREA], 6);
    assert_eq!(img[2 * 2 * AREA + AREA], 0, "frame 1 never answered");
    let recs = records(&e);
    assert!(recs
        .iter()
        .any(|r| r.lost_mask == 0b010 && r.flags & flags::LOST != 0));
    assert!(recs.iter().all(|r| r.lost_mask & 0b101 == 0));
    // Now frame 2's replies come a cycle late in send_then_wait: counted late against it.
    e.stop_cyclic();
    {
        let mut bus = b.lock().unwrap();
        bus.drop_at.clear();
        bus.delay_at = vec![4 * 2 * AREA];
    }
    e.start_cyclic(plan(6, Order::SendThenWait)).unwrap();
    wait_for(
        || frame_counter(&frames(&e)[2], "late") > 10,
        "late replies of frame 2",
    );
    e.stop_cyclic();
    let f = frames(&e);
    assert_eq!(frame_counter(&f[0], "late"), 0);
    assert_eq!(frame_counter(&f[1], "late"), 0);
    assert!(frame_counter(&f[2], "lost") > 10);
    assert_eq!(common::counter(&e, "unmatched_frames"), 0);
}

#[test]
fn lrd_and_lwr_serve_a_slave_that_refuses_lrw() {
    let b = bus(2);
    b.lock().unwrap().slaves[1].refuses_lrw = true;
    let e = engine(&b);
    // With LRW for both, slave 1 is not served: working counter 3 of 6.
    e.start_cyclic(plan(2, Order::SendThenWait)).unwrap();
    wait_for(
        || frame_counter(&frames(&e)[0], "wkc_errors") > 3,
        "wkc errors",
    );
    e.stop_cyclic();
    // Slave 1 by LWR (+1) and LRD (+1).
    let mut p = plan(2, Order::SendThenWait);
    let dgs = &mut p.frames[0].datagrams;
    dgs.pop();
    dgs.push(logical(Logical::Lwr, 2 * AREA, AREA, 1));
    dgs.push(logical(Logical::Lrd, 3 * AREA, AREA, 1));
    e.reset_stats();
    e.start_cyclic(p).unwrap();
    e.write_outputs(2 * AREA, &[0x77; AREA]).unwrap();
    wait_for(
        || b.lock().unwrap().slaves[1].out == [0x77; AREA],
        "outputs through LWR",
    );
    wait_for(
        || e.read_inputs().unwrap()[3 * AREA..4 * AREA] == [2; AREA],
        "inputs through LRD",
    );
    wait_for(|| common::counter(&e, "cycles") > 10, "cycles");
    e.stop_cyclic();
    let f = frames(&e);
    assert_eq!(frame_counter(&f[0], "wkc_errors"), 0);
    assert_eq!(frame_counter(&f[0], "last_wkc"), 5);
}

#[test]
fn a_slower_frame_goes_out_every_nth_cycle() {
    let b = bus(4);
    let e = engine(&b);
    let mut p = plan(4, Order::SendAtWake);
    p.frames[1].every = 4;
    e.start_cyclic(p).unwrap();
    wait_for(
        || frame_counter(&frames(&e)[1], "sent") >= 25,
        "the slow frame",
    );
    e.stop_cyclic();
    let f = frames(&e);
    let (fast, slow) = (frame_counter(&f[0], "sent"), frame_counter(&f[1], "sent"));
    assert_eq!(f[1].every, 4);
    // Sent in cycles 0, 4, 8, ...: a quarter of the fast frame's count, rounded up.
    assert_eq!(slow, fast.div_ceil(4), "fast {fast}, slow {slow}");
    assert_eq!(frame_counter(&f[1], "lost"), 0);
    let seen = b.lock().unwrap().seen.clone();
    assert_eq!(seen.len(), 2);
}

#[test]
fn a_groups_own_watchdog_puts_only_its_frame_on_safe_outputs() {
    let b = bus(4);
    let e = engine(&b);
    let mut p = plan(4, Order::SendAtWake);
    // Frame 1 (slaves 2 and 3) is a group with its own 30 ms watchdog; the bus has none.
    p.frames[1].watchdog_ns = 30_000_000;
    e.start_cyclic(p).unwrap();
    let live = |i: usize| vec![0x10 + i as u8; AREA];
    for i in 0..4 {
        e.write_outputs(i * 2 * AREA, &live(i)).unwrap();
    }
    wait_for(
        || b.lock().unwrap().slaves[2].out == live(2),
        "live outputs of frame 1",
    );
    // Only slave 0 (frame 0) keeps being written: frame 1 falls to the safe image (0xEE).
    wait_for(
        || {
            e.write_outputs(0, &live(0)).unwrap();
            let bus = b.lock().unwrap();
            bus.slaves[2].out == [0xEE; AREA] && bus.slaves[3].out == [0xEE; AREA]
        },
        "frame 1 on safe outputs",
    );
    {
        let bus = b.lock().unwrap();
        assert_eq!(bus.slaves[0].out, live(0));
        assert_eq!(bus.slaves[1].out, live(1), "frame 0 keeps its live outputs");
    }
    assert_eq!(frame_counter(&frames(&e)[1], "watchdog_trips"), 1);
    assert_eq!(frame_counter(&frames(&e)[0], "watchdog_trips"), 0);
    assert_eq!(
        common::counter(&e, "watchdog_trips"),
        0,
        "the bus watchdog is off"
    );
    assert!(records(&e).iter().any(|r| r.flags & flags::WATCHDOG != 0));
    // A write to one of its slaves brings that slave's live outputs back; the trip voided
    // the group's commands from before it, so the other slave of the group stays safe until
    // it is commanded again (and frame 0 was never touched).
    e.write_outputs(3 * 2 * AREA, &live(3)).unwrap();
    wait_for(
        || b.lock().unwrap().slaves[3].out == live(3),
        "slave 3 live again",
    );
    {
        let bus = b.lock().unwrap();
        assert_eq!(
            bus.slaves[2].out, [0xEE; AREA],
            "slave 2's old command came back"
        );
        assert_eq!(bus.slaves[1].out, live(1), "frame 0 keeps its live outputs");
    }
    e.write_outputs(2 * 2 * AREA, &live(2)).unwrap();
    wait_for(
        || b.lock().unwrap().slaves[2].out == live(2),
        "slave 2 live once commanded",
    );
    e.stop_cyclic();
}
