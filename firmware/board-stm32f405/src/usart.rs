//! USART1 (0x4001_1000) carrying the SLIP-framed host link.
//!
//! Receive is interrupt driven: the handler moves each byte into a bounded queue that the main loop
//! drains. Transmit is polled; QEMU's model completes every write at once, and on silicon a packet
//! at 115 200 Bd costs at most a few milliseconds of the main loop.

use core::cell::RefCell;
use core::ptr;

use critical_section::Mutex;
use heapless::Deque;

const USART1: usize = 0x4001_1000;
const SR: usize = USART1;
const DR: usize = USART1 + 0x04;
const BRR: usize = USART1 + 0x08;
const CR1: usize = USART1 + 0x0C;

const SR_RXNE: u32 = 1 << 5;
const SR_TXE: u32 = 1 << 7;
const CR1_RE: u32 = 1 << 2;
const CR1_TE: u32 = 1 << 3;
const CR1_RXNEIE: u32 = 1 << 5;
const CR1_UE: u32 = 1 << 13;

const RCC_AHB1ENR: usize = 0x4002_3830;
const RCC_APB2ENR: usize = 0x4002_3844;
const GPIOA_MODER: usize = 0x4002_0000;
const GPIOA_AFRH: usize = 0x4002_0024;

/// APB2 clock with the 168 MHz core clock (APB2 prescaler 2).
const PCLK2_HZ: u32 = 84_000_000;
/// Line rate on silicon; QEMU ignores it.
pub const BAUD: u32 = 115_200;

/// Bytes received but not yet handed to the firmware; more than a few whole packets.
const RX_QUEUE: usize = 1024;

static RX: Mutex<RefCell<Deque<u8, RX_QUEUE>>> = Mutex::new(RefCell::new(Deque::new()));

/// The USART1 interrupt request, for the NVIC.
#[derive(Clone, Copy, Debug)]
pub struct Usart1Irq;

// SAFETY: 37 is USART1's position in the STM32F405 vector table (RM0090 table 61).
unsafe impl cortex_m::interrupt::InterruptNumber for Usart1Irq {
    fn number(self) -> u16 {
        IRQ_NUMBER
    }
}

/// USART1's interrupt number.
pub const IRQ_NUMBER: u16 = 37;

fn read(addr: usize) -> u32 {
    // SAFETY: `addr` is one of the USART1/RCC/GPIOA registers above, valid for 32-bit access.
    unsafe { ptr::read_volatile(addr as *const u32) }
}

fn write(addr: usize, value: u32) {
    // SAFETY: as in `read`.
    unsafe { ptr::write_volatile(addr as *mut u32, value) }
}

/// Clocks the USART and its pins (PA9 TX, PA10 RX, alternate function 7), sets 115 200 Bd 8N1 and
/// enables the receive interrupt.
pub fn init() {
    write(RCC_AHB1ENR, read(RCC_AHB1ENR) | 1); // GPIOA
    write(RCC_APB2ENR, read(RCC_APB2ENR) | (1 << 4)); // USART1
    let moder = read(GPIOA_MODER) & !(0b1111 << 18);
    write(GPIOA_MODER, moder | (0b1010 << 18));
    let afrh = read(GPIOA_AFRH) & !(0xFF << 4);
    write(GPIOA_AFRH, afrh | (0x77 << 4));
    write(BRR, (PCLK2_HZ + BAUD / 2) / BAUD);
    write(CR1, CR1_UE | CR1_TE | CR1_RE | CR1_RXNEIE);
    // SAFETY: the handler only touches the RX queue through its critical section.
    unsafe { cortex_m::peripheral::NVIC::unmask(Usart1Irq) };
}

/// Sends `bytes`, waiting for the transmit register before each one.
pub fn write_all(bytes: &[u8]) {
    for &b in bytes {
        while read(SR) & SR_TXE == 0 {}
        write(DR, u32::from(b));
    }
}

/// Interrupt handler body: queues every received byte; a full queue drops it (the SLIP decoder
/// then sees a damaged frame and counts it).
pub fn on_interrupt() {
    while read(SR) & SR_RXNE != 0 {
        // Reading DR clears RXNE (and an overrun flag with it).
        let byte = read(DR) as u8;
        critical_section::with(|cs| {
            let _ = RX.borrow_ref_mut(cs).push_back(byte);
        });
    }
}

/// Moves queued received bytes into `out`, returning how many.
pub fn take_received(out: &mut [u8]) -> usize {
    critical_section::with(|cs| {
        let mut rx = RX.borrow_ref_mut(cs);
        let mut n = 0;
        while n < out.len() {
            match rx.pop_front() {
                Some(b) => {
                    out[n] = b;
                    n += 1;
                }
                None => break,
            }
        }
        n
    })
}

/// Whether received bytes are waiting.
pub fn has_received() -> bool {
    critical_section::with(|cs| !RX.borrow_ref(cs).is_empty())
}
