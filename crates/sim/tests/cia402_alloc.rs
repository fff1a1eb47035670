//! The CiA 402 drive model allocates nothing in `step` once running: through enabling, a CSP
//! ramp, a quick stop, an injected fault with its emergency and the fault reset (the simulator
//! runs it on its frame thread, which must keep its timing).

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicU64, Ordering};

use ether_ros_sim::device::DeviceApp;
use ether_ros_sim::devices::cia402::{dictionary, Cia402Config, Cia402Drive, PERIOD_NS};

struct Counting;

static ALLOCS: AtomicU64 = AtomicU64::new(0);

thread_local! {
    /// Count only on the thread under test, only while armed.
    static ARMED: Cell<bool> = const { Cell::new(false) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if ARMED.with(Cell::get) {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if ARMED.with(Cell::get) {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn step_allocates_nothing() {
    let mut od = dictionary(2);
    let mut drive = Cia402Drive::new(Cia402Config::from_params(&[]).unwrap());
    drive.reset(&mut od);
    let mut now = 1_000_000u64;
    let mut run = |od: &mut _, drive: &mut Cia402Drive, ms: u64| {
        for _ in 0..ms * 1_000_000 / PERIOD_NS {
            now += PERIOD_NS;
            drive.step(od, now, true);
        }
    };
    run(&mut od, &mut drive, 1); // first step resolves the dictionary
    ARMED.with(|a| a.set(true));
    od.set_int(0x6060, 0, 8);
    for word in [0x06, 0x07, 0x0F] {
        od.set_int(0x6040, 0, word);
        run(&mut od, &mut drive, 1);
    }
    for k in 1..=100 {
        od.set_int(0x607A, 0, k * 100);
        run(&mut od, &mut drive, 1);
    }
    od.set_int(0x6040, 0, 0x0B); // quick stop
    run(&mut od, &mut drive, 50);
    ARMED.with(|a| a.set(false));
    drive.inject_fault("encoder", 2).unwrap(); // the control path may allocate (error texts)
    ARMED.with(|a| a.set(true));
    run(&mut od, &mut drive, 5);
    while drive.take_emergency().is_some() {}
    od.set_int(0x6840, 0, 0x80); // fault reset on axis 2
    run(&mut od, &mut drive, 5);
    ARMED.with(|a| a.set(false));
    assert_eq!(
        od.get_int(0x6041, 0) & 0x4F,
        0x40,
        "axis 1 stopped: switch on disabled"
    );
    assert_eq!(od.get_int(0x6841, 0) & 0x4F, 0x40, "axis 2 reset");
    assert_eq!(ALLOCS.load(Ordering::Relaxed), 0, "allocations in step");
}
