//! SysTick on the 168 MHz core clock: a 1 ms scheduler tick and the monotonic clock.
//!
//! The interrupt counts whole milliseconds; `now` adds the counter's progress inside the current
//! millisecond, so link bytes and encoder steps are stamped to about 6 ns.

use core::cell::Cell;

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::{SCB, SYST};
use critical_section::Mutex;
use firmware::hal::MonotonicClock;
use firmware::Instant;

/// Core clock of the STM32F405 (and of QEMU's netduinoplus2).
pub const CORE_HZ: u32 = 168_000_000;
/// Core cycles per SysTick period (1 ms).
const RELOAD: u32 = CORE_HZ / 1000;
const NS_PER_TICK: u64 = 1_000_000;

static MILLIS: Mutex<Cell<u64>> = Mutex::new(Cell::new(0));

/// The clock; reading it needs no ownership, starting it takes the SysTick peripheral.
#[derive(Clone, Copy, Debug)]
pub struct SysTickClock;

impl SysTickClock {
    /// Starts SysTick with a 1 ms period on the core clock.
    pub fn start(mut syst: SYST) -> Self {
        syst.set_clock_source(SystClkSource::Core);
        syst.set_reload(RELOAD - 1);
        syst.clear_current();
        syst.enable_interrupt();
        syst.enable_counter();
        Self
    }

    /// Interrupt handler body: one more millisecond.
    pub fn on_interrupt() {
        critical_section::with(|cs| {
            let m = MILLIS.borrow(cs);
            m.set(m.get() + 1);
        });
    }
}

impl MonotonicClock for SysTickClock {
    fn now(&self) -> Instant {
        critical_section::with(|cs| {
            let millis = MILLIS.borrow(cs).get();
            // The counter runs down from RELOAD - 1. If it wrapped after interrupts were masked,
            // the pending interrupt has not counted that millisecond yet: re-read after the wrap.
            let mut down = SYST::get_current();
            let mut extra = 0;
            if SCB::is_pendst_pending() {
                extra = 1;
                down = SYST::get_current();
            }
            let cycles = u64::from(RELOAD - 1 - down.min(RELOAD - 1));
            let ns = (millis + extra) * NS_PER_TICK + cycles * 1_000_000_000 / u64::from(CORE_HZ);
            Instant::from_nanos(ns)
        })
    }
}
