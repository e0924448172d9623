//! The PocketBot2 firmware on an STM32F405, as QEMU's `netduinoplus2` models it.
//!
//! - USART1 (0x4001_1000) carries the host link, SLIP-framed.
//! - SysTick on the 168 MHz core clock is the monotonic clock and the 1 ms scheduler tick.
//! - QEMU models no motor driver, encoders or robot sensors, so the board's other peripherals are
//!   the firmware's kinematic stand-in ([`firmware::mock::MockBoard`]): the PWM the firmware sets
//!   drives first-order wheel models whose travel produces the encoder edges the firmware's speed
//!   meters and locomotion close their loops on; the line sensor looks at a straight tape.
//! - Between interrupts the core sleeps in `wfi`; a fault or panic reports and exits.
//!
//! Semihosting is used only to end the emulation with a failure status.

#![no_std]
#![no_main]

mod clock;
mod fault;
mod usart;

use core::sync::atomic::{AtomicBool, Ordering};

use cortex_m_rt::{entry, exception};
use firmware::hal::MonotonicClock;
use firmware::mock::MockBoard;
use firmware::{Duration, Firmware, Instant};
use protocol::slip;

use crate::clock::SysTickClock;

/// Longest stand-in physics step; longer gaps (a blocked link) are cut into steps this long.
const MAX_PHYSICS_STEP: Duration = Duration::from_millis(1);

/// Set by every interrupt, so the main loop does not sleep through work that arrived after it
/// looked.
static WOKEN: AtomicBool = AtomicBool::new(false);

#[entry]
fn main() -> ! {
    let cp = cortex_m::Peripherals::take().unwrap_or_else(|| fault::exit_failure());
    usart::init();
    let clock = SysTickClock::start(cp.SYST);

    let fw = cortex_m::singleton!(: Firmware<MockBoard> = Firmware::new(MockBoard::default()))
        .unwrap_or_else(|| fault::exit_failure());
    let mut rx = [0u8; 256];
    let mut tx = [0u8; slip::max_encoded_len(protocol::MAX_PACKET)];

    let mut last_step = clock.now();
    fw.tick(last_step);
    // A UART has no connection event: the link counts as up from reset.
    fw.on_link_connected(last_step);

    loop {
        WOKEN.store(false, Ordering::Relaxed);
        loop {
            let n = usart::take_received(&mut rx);
            if n == 0 {
                break;
            }
            fw.on_link_bytes(clock.now(), &rx[..n]);
        }
        let now = clock.now();
        advance_physics(fw.board_mut(), &mut last_step, now);
        fw.tick(now);
        while let Some(n) = fw.pop_slip(&mut tx) {
            usart::write_all(&tx[..n]);
        }
        // Masked, so an interrupt between the check and `wfi` still wakes it (WFI ignores PRIMASK).
        cortex_m::interrupt::free(|_| {
            if !WOKEN.load(Ordering::Relaxed) && !usart::has_received() {
                cortex_m::asm::wfi();
            }
        });
    }
}

/// Moves the stand-in wheels from `last` to `now`, queuing the encoder edges they pass.
fn advance_physics(board: &mut MockBoard, last: &mut Instant, now: Instant) {
    while *last < now {
        let dt = (now - *last).min(MAX_PHYSICS_STEP);
        board.step(*last, dt);
        *last = *last + dt;
    }
}

#[exception]
fn SysTick() {
    SysTickClock::on_interrupt();
    WOKEN.store(true, Ordering::Relaxed);
}

/// Without a device crate every peripheral interrupt lands here; only USART1 is enabled.
#[exception]
unsafe fn DefaultHandler(irqn: i16) {
    if irqn == usart::IRQ_NUMBER as i16 {
        usart::on_interrupt();
    }
    WOKEN.store(true, Ordering::Relaxed);
}
