//! ethercrab-probe: bring a bus to OP with ethercrab and exchange process data, then print one
//! JSON line with what happened. The acceptance tests run it against the simulator, so that a
//! master we did not write checks the virtual slaves.
//!
//! Usage: ethercrab-probe --interface IF [--cycles N] [--cycle-us N] [--dc --shift-us N]
//!        [--expect-slaves N] [--expect-wkc N] [--set SLAVE:BYTE:HEX]...
//!        [--expect-input SLAVE:BYTE:HEX]
//!
//! `--set 1:0:ff00` writes the bytes ff 00 at byte 0 of slave 1's outputs in every cycle.
//! `--expect-input 0:0:a5` keeps exchanging after the N cycles, for at most 5 s more, until slave
//! 0's inputs hold a5 at byte 0 (a loaded host may have starved the run long enough for the
//! slave's watchdog to take its outputs to the safe state near the end); the report's inputs are
//! those of the last exchange either way.
//! Exit status: 0 when every expectation held, 1 otherwise (the JSON line says why), 2 for bad
//! arguments.

use std::process::ExitCode;
use std::sync::Arc;
use std::time::{Duration, Instant};

use ethercrab::std::{ethercat_now, tx_rx_task};
use ethercrab::subdevice_group::DcConfiguration;
use ethercrab::{DcSync, MainDevice, MainDeviceConfig, PduStorage, RetryBehaviour, Timeouts};

const MAX_SUBDEVICES: usize = 16;
const MAX_PDU_DATA: usize = PduStorage::element_size(1100);
const MAX_FRAMES: usize = 16;
const PDI_LEN: usize = 4096;

static PDU_STORAGE: PduStorage<MAX_FRAMES, MAX_PDU_DATA> = PduStorage::new();

struct Args {
    interface: String,
    cycles: u32,
    cycle: Duration,
    dc: bool,
    shift: Duration,
    expect_slaves: Option<usize>,
    expect_wkc: Option<u16>,
    sets: Vec<(usize, usize, Vec<u8>)>,
    expect_input: Option<(usize, usize, Vec<u8>)>,
}

fn parse_args() -> Result<Args, String> {
    let mut a = Args {
        interface: String::new(),
        cycles: 10_000,
        cycle: Duration::from_micros(1000),
        dc: false,
        shift: Duration::ZERO,
        expect_slaves: None,
        expect_wkc: None,
        sets: Vec::new(),
        expect_input: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        if flag == "--dc" {
            a.dc = true;
            continue;
        }
        let value = it.next().ok_or_else(|| format!("{flag} needs a value"))?;
        let num = |v: &str| {
            v.parse::<u64>()
                .map_err(|_| format!("{flag}: not a number: {v}"))
        };
        match flag.as_str() {
            "--interface" => a.interface = value,
            "--cycles" => a.cycles = num(&value)? as u32,
            "--cycle-us" => a.cycle = Duration::from_micros(num(&value)?),
            "--shift-us" => a.shift = Duration::from_micros(num(&value)?),
            "--expect-slaves" => a.expect_slaves = Some(num(&value)? as usize),
            "--expect-wkc" => a.expect_wkc = Some(num(&value)? as u16),
            "--set" => a.sets.push(parse_set(&value)?),
            "--expect-input" => a.expect_input = Some(parse_set(&value)?),
            other => return Err(format!("unknown argument {other}")),
        }
    }
    if a.interface.is_empty() {
        return Err("--interface is required".into());
    }
    Ok(a)
}

fn parse_set(v: &str) -> Result<(usize, usize, Vec<u8>), String> {
    let parts: Vec<&str> = v.split(':').collect();
    let bad = || format!("--set {v}: expected SLAVE:BYTE:HEX");
    if parts.len() != 3 || !parts[2].len().is_multiple_of(2) {
        return Err(bad());
    }
    let slave = parts[0].parse().map_err(|_| bad())?;
    let byte = parts[1].parse().map_err(|_| bad())?;
    let bytes = (0..parts[2].len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&parts[2][i..i + 2], 16))
        .collect::<Result<Vec<u8>, _>>()
        .map_err(|_| bad())?;
    Ok((slave, byte, bytes))
}

fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

/// What the run saw, printed as one JSON line.
#[derive(Default)]
struct Report {
    slaves: Vec<String>,
    op: bool,
    cycles: u32,
    wkc_first: u16,
    wkc_errors: u32,
    /// The first wrong working counters: (cycle, working counter), to tell a slave that
    /// missed one cycle from one that left OP.
    wkc_wrong: Vec<(u32, u16)>,
    tx_rx_errors: u32,
    inputs: Vec<String>,
    outputs: Vec<String>,
    error: Option<String>,
}

impl Report {
    fn json(&self) -> String {
        let list = |v: &[String]| {
            let items: Vec<String> = v.iter().map(|s| format!("\"{s}\"")).collect();
            format!("[{}]", items.join(","))
        };
        format!(
            "{{\"slaves\":[{}],\"op\":{},\"cycles\":{},\"wkc_first\":{},\"wkc_errors\":{},\
             \"wkc_wrong\":[{}],\"tx_rx_errors\":{},\"inputs\":{},\"outputs\":{},\"error\":{}}}",
            self.slaves.join(","),
            self.op,
            self.cycles,
            self.wkc_first,
            self.wkc_errors,
            self.wkc_wrong
                .iter()
                .map(|(c, w)| format!("[{c},{w}]"))
                .collect::<Vec<_>>()
                .join(","),
            self.tx_rx_errors,
            list(&self.inputs),
            list(&self.outputs),
            match &self.error {
                Some(e) => format!("\"{}\"", e.replace('"', "'")),
                None => "null".into(),
            }
        )
    }
}

fn main() -> ExitCode {
    let args = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("ethercrab-probe: {e}");
            return ExitCode::from(2);
        }
    };
    let mut report = Report::default();
    let result = smol::block_on(run(&args, &mut report));
    if let Err(e) = result {
        report.error = Some(e);
    }
    println!("{}", report.json());
    if report.error.is_none() {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    }
}

/// Exchange process data until every slave reports OP (at most 10 s): after `request_into_op`
/// the slaves enter OP once valid outputs arrive. Written once for both group kinds, like
/// `cycle_loop!`.
macro_rules! enter_op {
    ($group:expr, $maindevice:expr, $args:expr, $report:expr, $tx_rx:ident) => {{
        let deadline = Instant::now() + Duration::from_secs(10);
        while !$report.op {
            let r = $group
                .$tx_rx($maindevice)
                .await
                .map_err(|e| format!("tx/rx while entering OP: {e}"))?;
            $report.op = r.all_op();
            if Instant::now() > deadline {
                return Err("slaves did not reach OP within 10 s".into());
            }
            smol::Timer::after($args.cycle).await;
        }
    }};
}

/// The cyclic exchange, written once for both kinds of OP group (with DC: `tx_rx_dc`, free run:
/// `tx_rx`): the group types differ, the loop does not.
macro_rules! cycle_loop {
    ($group:expr, $maindevice:expr, $args:expr, $report:expr, $tx_rx:ident) => {{
        let (group, maindevice, args, report) = ($group, $maindevice, $args, $report);
        let mut next = Instant::now();
        let mut n: u32 = 0;
        loop {
            if n >= args.cycles {
                let seen = match &args.expect_input {
                    None => true,
                    Some((slave, byte, bytes)) => match group.subdevice(maindevice, *slave) {
                        Ok(sd) => {
                            let io = sd.io_raw();
                            io.inputs().get(*byte..*byte + bytes.len()) == Some(&bytes[..])
                        }
                        Err(e) => return Err(format!("--expect-input: slave {slave}: {e}")),
                    },
                };
                if seen || n >= args.cycles + 5000 {
                    break;
                }
            }
            for (slave, byte, bytes) in &args.sets {
                let sd = group
                    .subdevice(maindevice, *slave)
                    .map_err(|e| format!("--set: slave {slave}: {e}"))?;
                let mut out = sd.outputs_raw_mut();
                let end = byte + bytes.len();
                if end > out.len() {
                    return Err(format!(
                        "--set: slave {slave} has {} output bytes, not {end}",
                        out.len()
                    ));
                }
                out[*byte..end].copy_from_slice(bytes);
            }
            match group.$tx_rx(maindevice).await {
                Ok(r) => {
                    if n == 0 {
                        report.wkc_first = r.working_counter;
                    }
                    let expected = args.expect_wkc.unwrap_or(report.wkc_first);
                    if r.working_counter != expected {
                        report.wkc_errors += 1;
                        if report.wkc_wrong.len() < 10 {
                            report.wkc_wrong.push((n, r.working_counter));
                        }
                    }
                }
                Err(_) => report.tx_rx_errors += 1,
            }
            report.cycles = n + 1;
            n += 1;
            next += args.cycle;
            let now = Instant::now();
            if next > now {
                smol::Timer::at(next).await;
            } else {
                next = now;
            }
        }
        for sd in group.iter(maindevice) {
            let io = sd.io_raw();
            report.inputs.push(hex(&io.inputs()));
            report.outputs.push(hex(&io.outputs()));
        }
        finish(report)
    }};
}

/// The verdict on a finished exchange.
fn finish(report: &Report) -> Result<(), String> {
    if report.wkc_errors > 0 {
        return Err(format!(
            "{} of {} cycles had a wrong working counter",
            report.wkc_errors, report.cycles
        ));
    }
    // Lost frames are the host's business (this VM has spikes); more than 1 % is not.
    if report.tx_rx_errors * 100 > report.cycles {
        return Err(format!(
            "{} of {} cycles failed to exchange",
            report.tx_rx_errors, report.cycles
        ));
    }
    Ok(())
}

async fn run(args: &Args, report: &mut Report) -> Result<(), String> {
    let (tx, rx, pdu_loop) = PDU_STORAGE.try_split().map_err(|_| "PDU storage split")?;
    let maindevice = Arc::new(MainDevice::new(
        pdu_loop,
        Timeouts {
            wait_loop_delay: Duration::from_millis(2),
            state_transition: Duration::from_secs(10),
            // A loaded VM may hold a frame back for a while: wait longer, and send a lost
            // frame again (below) instead of failing the bring-up on the first.
            pdu: Duration::from_millis(1000),
            mailbox_response: Duration::from_millis(1000),
            // ethercrab's 10 ms for one EEPROM poll is one round trip on a quiet machine; a
            // loaded VM with a long bus needs more (the slaves answer at once: busy is 0).
            eeprom: Duration::from_millis(200),
            ..Timeouts::default()
        },
        MainDeviceConfig {
            dc_static_sync_iterations: 1000,
            retry_behaviour: RetryBehaviour::Count(3),
        },
    ));
    let task = tx_rx_task(&args.interface, tx, rx).map_err(|e| format!("tx/rx task: {e}"))?;
    smol::spawn(task).detach();

    let mut group = maindevice
        .init_single_group::<MAX_SUBDEVICES, PDI_LEN>(ethercat_now)
        .await
        .map_err(|e| format!("init: {e}"))?;
    for mut sd in group.iter_mut(&maindevice) {
        if args.dc && !matches!(sd.dc_support(), ethercrab::DcSupport::None) {
            sd.set_dc_sync(DcSync::Sync0);
        }
    }
    for sd in group.iter(&maindevice) {
        let id = sd.identity();
        report.slaves.push(format!(
            "{{\"name\":\"{}\",\"vendor_id\":{},\"product_code\":{},\"revision\":{},\
             \"serial\":{},\"dc\":\"{:?}\",\"propagation_delay\":{}}}",
            sd.name(),
            id.vendor_id,
            id.product_id,
            id.revision,
            id.serial,
            sd.dc_support(),
            sd.propagation_delay()
        ));
    }
    if let Some(n) = args.expect_slaves {
        if group.len() != n {
            return Err(format!("found {} slaves, expected {n}", group.len()));
        }
    }

    if args.dc {
        let group = group
            .into_pre_op_pdi(&maindevice)
            .await
            .map_err(|e| format!("PRE-OP with PDI: {e}"))?;
        // Let the clocks settle: a few hundred system-time distributions.
        for _ in 0..200 {
            group
                .tx_rx_sync_system_time(&maindevice)
                .await
                .map_err(|e| format!("sync system time: {e}"))?;
            smol::Timer::after(Duration::from_millis(1)).await;
        }
        let group = group
            .configure_dc_sync(
                &maindevice,
                DcConfiguration {
                    start_delay: Duration::from_millis(50),
                    sync0_period: args.cycle,
                    sync0_shift: args.shift,
                },
            )
            .await
            .map_err(|e| format!("configure DC sync: {e}"))?;
        let group = group
            .into_safe_op(&maindevice)
            .await
            .map_err(|e| format!("PRE-OP -> SAFE-OP: {e}"))?;
        let group = group
            .request_into_op(&maindevice)
            .await
            .map_err(|e| format!("request OP: {e}"))?;
        // Cyclic exchange starts after the request: the slaves go to OP on valid outputs.
        enter_op!(&group, &maindevice, args, report, tx_rx_dc);
        cycle_loop!(&group, &maindevice, args, report, tx_rx_dc)
    } else {
        // ethercrab's own order: request OP, then start the cyclic exchange; the slaves
        // enter OP once valid outputs arrive (`into_op` would wait without sending any).
        let group = group
            .into_safe_op(&maindevice)
            .await
            .map_err(|e| format!("PRE-OP -> SAFE-OP: {e}"))?
            .request_into_op(&maindevice)
            .await
            .map_err(|e| format!("request OP: {e}"))?;
        enter_op!(&group, &maindevice, args, report, tx_rx);
        cycle_loop!(&group, &maindevice, args, report, tx_rx)
    }
}
