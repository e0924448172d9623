//! Faults and panics end the program instead of hanging: the cause goes to the host as an error
//! log packet on the link, then a semihosting exit with failure ends QEMU (on silicon without a
//! debugger the exit request itself faults, which locks the core up: the board then needs a reset
//! either way).

use core::fmt::Write;

use cortex_m_rt::ExceptionFrame;
use protocol::packets::{Log, LogLevel};
use protocol::slip;

use crate::usart;

/// Sends `text` as an error log packet from module `module`, bypassing the firmware's queue.
fn report(module: &str, text: &str) {
    let log = Log::new(LogLevel::Error, module, text);
    let mut packet = [0u8; protocol::MAX_PACKET];
    let Ok(n) = protocol::encode(&log, &mut packet) else {
        return;
    };
    let mut framed = [0u8; slip::max_encoded_len(protocol::MAX_PACKET)];
    if let Ok(m) = slip::encode(&packet[..n], &mut framed) {
        usart::write_all(&framed[..m]);
    }
}

/// Ends the emulation with a failure status.
pub fn exit_failure() -> ! {
    loop {
        cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_FAILURE);
    }
}

/// A fixed-capacity text buffer that keeps what fits.
struct Text {
    buf: [u8; protocol::packets::LOG_TEXT],
    len: usize,
}

impl Write for Text {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        for c in s.chars() {
            let mut utf8 = [0u8; 4];
            let e = c.encode_utf8(&mut utf8).as_bytes();
            if self.len + e.len() > self.buf.len() {
                return Ok(());
            }
            self.buf[self.len..self.len + e.len()].copy_from_slice(e);
            self.len += e.len();
        }
        Ok(())
    }
}

impl Text {
    fn new() -> Self {
        Self {
            buf: [0; protocol::packets::LOG_TEXT],
            len: 0,
        }
    }

    fn as_str(&self) -> &str {
        // Only whole characters are ever copied in.
        core::str::from_utf8(&self.buf[..self.len]).unwrap_or("")
    }
}

#[cortex_m_rt::exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    cortex_m::interrupt::disable();
    let mut text = Text::new();
    let _ = write!(
        text,
        // Hex without prefixes, so all four fit in one log packet.
        "HardFault pc={:08x} lr={:08x} hfsr={:08x} cfsr={:08x}",
        frame.pc(),
        frame.lr(),
        // SAFETY: HFSR and CFSR are read-only status registers of the SCB.
        unsafe { core::ptr::read_volatile(0xE000_ED2C as *const u32) },
        unsafe { core::ptr::read_volatile(0xE000_ED28 as *const u32) },
    );
    report("fault", text.as_str());
    exit_failure()
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo<'_>) -> ! {
    cortex_m::interrupt::disable();
    let mut text = Text::new();
    let _ = write!(text, "panic: {}", info.message());
    if let Some(at) = info.location() {
        let _ = write!(text, " at {}:{}", at.file(), at.line());
    }
    report("panic", text.as_str());
    exit_failure()
}
