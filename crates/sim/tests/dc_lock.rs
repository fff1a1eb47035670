//! Distributed clocks lock in both modes, on the manual clock: a line of four DC slaves with
//! drifting crystals is brought up as the master does it (latch, delays, offsets from the
//! master's time, static drift compensation), then runs 400 µs cycles:
//!
//! - `ref_follows_master`: every frame carries FPWR 0x0910 with the master's time at the
//!   planned send instant to the reference, then FRMW 0x0910 (reference → the others). The
//!   frame leaves 10..40 µs after the planned instant (wake-up latency), so the reference sees
//!   the written time that much late, with jitter. The reference must lock to the master's
//!   time (its filtered Δ near 0, its speed correction learning its drift, never saturating)
//!   and the others must lock to the reference.
//! - `master_follows_ref`: only the FRMW; the followers lock to the free-running reference to
//!   the nanosecond.

mod common;

use common::{assign_addresses, fprd, io_spec, station, xfer};
use ether_ros_protocol::{self as wire, Command, FrameBuilder};
use ether_ros_sim::Network;

const CYCLE_NS: u64 = 400_000;
/// DC system time = host time + this (the master's `time_offset_ns`: about 20 years).
const TIME_OFFSET_NS: u64 = 630_000_000_000_000_000;
const DRIFTS_PPM: [f64; 4] = [50.0, -7.5, 25.0, -3.0];
const SYSTEM_TIME: u16 = 0x0910;
/// What `python/ether_ros/master/dc.py` writes to the reference's 0x0930 and 0x0934 for a
/// 400 µs cycle.
const REFERENCE_SPEED_COUNTER_START: u16 = 0x7FFF;
const REFERENCE_FILTER_DEPTH: u8 = 6;
const SYSTEM_TIME_DIFF: u16 = 0x092C;

fn master_time(host: u64) -> u64 {
    host + TIME_OFFSET_NS
}

/// Deterministic uniform noise in [0, 1) (xorshift).
struct Noise(u64);

impl Noise {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

fn le_u32(d: &[u8], at: usize) -> u64 {
    u32::from_le_bytes(d[at..at + 4].try_into().unwrap()) as u64
}

fn le_u64(d: &[u8]) -> u64 {
    u64::from_le_bytes(d[..8].try_into().unwrap())
}

fn set_clock(net: &mut Network, host: u64) {
    let now = net.now();
    assert!(host >= now, "the manual clock only moves forward");
    net.advance_clock(host - now);
}

/// 0x092C of slave `pos` as a signed difference (bit 31: local smaller than received).
fn time_difference(net: &mut Network, pos: usize) -> i64 {
    let raw = le_u32(&fprd(net, station(pos), SYSTEM_TIME_DIFF, 4).0, 0) as u32;
    let magnitude = (raw & 0x7fff_ffff) as i64;
    if raw & 0x8000_0000 != 0 {
        -magnitude
    } else {
        magnitude
    }
}

/// Four DC slaves with drifting clocks, addressed, with delays and offsets set from the
/// master's time as `python/ether_ros/master/dc.py` does, and 3000 FRMW of static drift
/// compensation (16 per frame). Returns the network at the end of the bring-up.
fn bring_up() -> Network {
    let mut net = Network::with_manual_clock(5_000_000_000);
    for drift in DRIFTS_PPM {
        let mut spec = io_spec();
        spec.dc_supported = true;
        spec.drift_ppm = drift;
        spec.delay_ns = 800;
        net.add_slave(spec).unwrap();
    }
    assign_addresses(&mut net);
    // Latch: the master's time when the frame left; the frame passes the reference one hop
    // (800 ns) later, an offset error the reference's loop removes.
    let sent = net.now();
    assert_eq!(xfer(&mut net, Command::Bwr, 0x0900 << 16, &[0; 4]).1, 4);
    let n = DRIFTS_PPM.len();
    let mut loops = Vec::new();
    let mut locals = Vec::new();
    for pos in 0..n {
        let ports = fprd(&mut net, station(pos), 0x0900, 16).0;
        let (p0, p1) = (le_u32(&ports, 0), le_u32(&ports, 4));
        loops.push(if pos + 1 < n {
            p1.wrapping_sub(p0) & 0xffff_ffff
        } else {
            0
        });
        locals.push(le_u64(&fprd(&mut net, station(pos), 0x0918, 8).0));
    }
    let mut delay = 0u64;
    for pos in 0..n {
        if pos > 0 {
            delay += loops[pos - 1].saturating_sub(loops[pos]) / 2;
        }
        let offset = master_time(sent)
            .wrapping_add(delay)
            .wrapping_sub(locals[pos]);
        let st = station(pos);
        xfer(
            &mut net,
            Command::Fpwr,
            wire::fixed_address(st, 0x0920),
            &offset.to_le_bytes(),
        );
        xfer(
            &mut net,
            Command::Fpwr,
            wire::fixed_address(st, 0x0928),
            &(delay as u32).to_le_bytes(),
        );
        assert_eq!(delay, 800 * pos as u64, "propagation delay of slave {pos}");
    }
    // The reference's loop follows the master's noisy time: the master gives it a lower
    // bandwidth (speed counter start) and a deeper Δ filter, as `dc.py` does.
    let st = station(0);
    xfer(
        &mut net,
        Command::Fpwr,
        wire::fixed_address(st, 0x0930),
        &REFERENCE_SPEED_COUNTER_START.to_le_bytes(),
    );
    xfer(
        &mut net,
        Command::Fpwr,
        wire::fixed_address(st, 0x0934),
        &[REFERENCE_FILTER_DEPTH],
    );
    // Static drift compensation: 3000 FRMW from the reference, 16 per frame, 100 µs apart.
    for _ in 0..3000 / 16 {
        let t = net.now() + 100_000;
        set_clock(&mut net, t);
        let datagrams = [(Command::Frmw, [0u8; 8]); 16];
        send(&mut net, &datagrams);
    }
    net
}

/// One frame with the given datagrams (all addressed to the reference's 0x0910); returns the
/// data of each after the trip.
fn send(net: &mut Network, datagrams: &[(Command, [u8; 8])]) -> Vec<[u8; 8]> {
    let mut buf = [0u8; wire::MAX_FRAME_LEN];
    let mut b = FrameBuilder::new(&mut buf, wire::MASTER_MAC).unwrap();
    let address = wire::fixed_address(station(0), SYSTEM_TIME);
    let slots: Vec<_> = datagrams
        .iter()
        .map(|(cmd, data)| b.push(*cmd, 0x10, address, Some(data), 0).unwrap())
        .collect();
    let len = b.finish();
    assert!(net.process_frame(&mut buf[..len]), "frame answered");
    slots
        .iter()
        .map(|s| buf[s.data..s.data + 8].try_into().unwrap())
        .collect()
}

fn percentile_abs(values: &[i64], p: f64) -> i64 {
    let mut v: Vec<i64> = values.iter().map(|x| x.abs()).collect();
    v.sort_unstable();
    v[((v.len() as f64 * p) as usize).min(v.len() - 1)]
}

struct Run {
    /// Reference's filtered Δ (0x092C) per cycle, second half.
    reference_diffs: Vec<i64>,
    /// Reference system time − master time at the frame's arrival, second half.
    reference_vs_master: Vec<i64>,
    /// Followers' filtered Δ (0x092C) per cycle, second half.
    follower_diffs: Vec<i64>,
    /// Largest |speed correction| of the reference over the whole run (ppm).
    reference_peak_correction: f64,
}

/// Cyclic operation for `seconds`; the frame leaves 10..40 µs after the planned instant.
fn run_cycles(net: &mut Network, write_reference: bool, seconds: f64) -> Run {
    let mut noise = Noise(0x2545_F491_4F6C_DD1D);
    let start = net.now() + 100_000_000;
    let cycles = (seconds * 1e9) as u64 / CYCLE_NS;
    let mut run = Run {
        reference_diffs: Vec::new(),
        reference_vs_master: Vec::new(),
        follower_diffs: Vec::new(),
        reference_peak_correction: 0.0,
    };
    for k in 0..cycles {
        let planned = start + k * CYCLE_NS;
        let sent = planned + 10_000 + (30_000.0 * noise.next()) as u64;
        set_clock(net, sent);
        let mut datagrams = Vec::new();
        if write_reference {
            datagrams.push((Command::Fpwr, master_time(planned).to_le_bytes()));
        }
        datagrams.push((Command::Frmw, [0u8; 8]));
        let replies = send(net, &datagrams);
        let reference_time = le_u64(replies.last().unwrap());
        // The frame passed the reference one hop after it was sent.
        let arrival = sent + 800;
        run.reference_peak_correction = run
            .reference_peak_correction
            .max(net.slave(0).dc.correction_ppm().abs());
        if k >= cycles / 2 {
            run.reference_vs_master
                .push(reference_time.wrapping_sub(master_time(arrival)) as i64);
            run.reference_diffs.push(time_difference(net, 0));
            for pos in 1..DRIFTS_PPM.len() {
                run.follower_diffs.push(time_difference(net, pos));
            }
        }
    }
    run
}

#[test]
fn reference_follows_master_locks_without_saturating() {
    let mut net = bring_up();
    let run = run_cycles(&mut net, true, 4.0);
    let mean = run.reference_vs_master.iter().sum::<i64>() / run.reference_vs_master.len() as i64;
    let wander: Vec<i64> = run.reference_vs_master.iter().map(|d| d - mean).collect();
    eprintln!(
        "ref_follows_master: reference Δ p99 {} ns, reference − master at arrival: mean {mean} ns, \
         p99 around the mean {} ns; followers Δ p99 {} ns; reference correction {:.2} ppm \
         (peak {:.1})",
        percentile_abs(&run.reference_diffs, 0.99),
        percentile_abs(&wander, 0.99),
        percentile_abs(&run.follower_diffs, 0.99),
        net.slave(0).dc.correction_ppm(),
        run.reference_peak_correction,
    );
    // The reference trimmed its speed by its drift and nowhere near the ±500 ppm limit.
    assert!(run.reference_peak_correction < 200.0);
    assert!((net.slave(0).dc.correction_ppm() + 50.0).abs() < 10.0);
    // It keeps the written (planned-send) time at its arrival: Δ averages out to ~0 and the
    // reference runs the mean send lag (25 µs) + one hop behind the master's clock, steadily.
    assert!(percentile_abs(&run.reference_diffs, 0.99) < 10_000);
    assert!((-35_000..-15_000).contains(&mean), "mean {mean} ns");
    assert!(percentile_abs(&wander, 1.0) < 3_000);
    // The others follow the reference, whose speed keeps being trimmed (by a few ppm: the
    // written time's jitter): their corrections stay near the master's rate − their drift.
    assert!(percentile_abs(&run.follower_diffs, 1.0) < 2_000);
    for (pos, drift) in DRIFTS_PPM.iter().enumerate().skip(1) {
        let learned = net.slave(pos).dc.correction_ppm();
        assert!((learned + drift).abs() < 20.0, "slave {pos}: {learned} ppm");
    }
}

#[test]
fn master_follows_reference_followers_lock_to_the_nanosecond() {
    let mut net = bring_up();
    let run = run_cycles(&mut net, false, 2.0);
    eprintln!(
        "master_follows_ref: followers Δ p99 {} ns",
        percentile_abs(&run.follower_diffs, 0.99)
    );
    // Nobody writes the reference: it runs free.
    assert_eq!(net.slave(0).dc.correction_ppm(), 0.0);
    assert!(percentile_abs(&run.follower_diffs, 1.0) <= 5);
    for (pos, drift) in DRIFTS_PPM.iter().enumerate().skip(1) {
        let expected = DRIFTS_PPM[0] - drift;
        let learned = net.slave(pos).dc.correction_ppm();
        assert!(
            (learned - expected).abs() < 0.5,
            "slave {pos}: {learned} ppm"
        );
    }
}
