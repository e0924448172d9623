//! Leveled debug log (thesis 6.2.3) whose messages leave the robot as Log packets.
//!
//! `fw_log!(firmware, Warn, "module", "format {}", args)` formats into a fixed buffer (cut at
//! [`LOG_TEXT`] bytes) only when the level passes the configured
//! verbosity, so a disabled message costs one comparison.

use core::fmt::Write;

use protocol::packets::{Log, LogLevel, LOG_TEXT};

/// Logs a formatted message at a level through a [`Firmware`](crate::Firmware).
#[macro_export]
macro_rules! fw_log {
    ($fw:expr, $level:ident, $module:expr, $($arg:tt)*) => {
        $fw.log($crate::protocol::packets::LogLevel::$level, $module, format_args!($($arg)*))
    };
}

/// A fixed-capacity text buffer that silently truncates.
struct Truncating {
    buf: heapless::String<LOG_TEXT>,
}

impl Write for Truncating {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        for c in s.chars() {
            if self.buf.push(c).is_err() {
                break;
            }
        }
        Ok(())
    }
}

/// Formats a log packet, or `None` when `level` is more verbose than `max_level`.
pub fn format(
    level: LogLevel,
    max_level: u8,
    module: &str,
    args: core::fmt::Arguments<'_>,
) -> Option<Log> {
    if level as u8 > max_level {
        return None;
    }
    let mut t = Truncating {
        buf: heapless::String::new(),
    };
    let _ = t.write_fmt(args);
    Some(Log::new(level, module, &t.buf))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn filters_by_level_and_truncates() {
        assert!(format(
            LogLevel::Debug,
            LogLevel::Info as u8,
            "m",
            format_args!("x")
        )
        .is_none());
        let l = format(
            LogLevel::Warn,
            3,
            "proto",
            format_args!("bad checksum {}", 42),
        )
        .unwrap();
        assert_eq!(l.text(), "bad checksum 42");
        assert_eq!(l.module(), "proto");
        let long = format(LogLevel::Error, 3, "m", format_args!("{:>100}", 1)).unwrap();
        assert_eq!(long.text().len(), LOG_TEXT);
    }
}
