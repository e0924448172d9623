//! The board hardware abstraction: one small trait per peripheral the firmware drives.
//!
//! A board (the simulator's `SimBoard`, the STM32F405 build, a mock in tests) implements these and
//! calls the firmware's entry points from its interrupts: `on_encoder_edge`, `on_ir_frame`,
//! `on_link_bytes`/`on_link_packet`, and `tick` from its timer.

use crate::time::Instant;

pub use protocol::packets::Side;

/// One of the two driven wheels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Wheel {
    /// Left wheel.
    Left = 0,
    /// Right wheel.
    Right = 1,
}

/// An encoder pulse captured by a timer input-capture channel (thesis 11.5.3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EncoderEdge {
    /// Which wheel's encoder.
    pub wheel: Wheel,
    /// Capture time of the edge.
    pub at: Instant,
}

/// One infrared frame of the proximity logical layer (thesis 7.2).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct IrFrame {
    /// Id of the transmitting robot.
    pub robot_id: u16,
    /// Index of the directed LED that sent it.
    pub led: u8,
    /// Transmit power level, 1 = weakest.
    pub power: u8,
    /// Message word attached by the host (0 = none).
    pub message: u16,
}

/// Motor drivers: PWM duty per wheel.
pub trait Motors {
    /// Sets the duties in permille of full power; the sign is the direction (positive = forward).
    fn set_pwm(&mut self, left: i16, right: i16);
}

/// Encoder input capture, for boards that queue edges instead of calling `on_encoder_edge`.
pub trait EncoderCapture {
    /// Takes the oldest captured edge, if any.
    fn pop_edge(&mut self) -> Option<EncoderEdge>;
}

/// Line sensor ADC with emitter control: 4 detectors interleaved with 5 emitters (thesis 11.3).
///
/// Emitter `i` sits left of detector `i` and emitter `i + 1` right of it, so with alternate
/// emitters lit each detector sees one spot at a time: 8 spots from 4 detectors.
pub trait LineSensorAdc {
    /// Lights the emitters whose bits are set in `mask` (bit `i` = emitter `i`, 0..5).
    fn set_emitters(&mut self, mask: u8);
    /// Converts the 4 detectors, 12-bit; brighter surfaces read higher.
    fn read_detectors(&mut self) -> [u16; 4];
}

/// Infrared transmitter of the proximity units.
pub trait IrTransmitter {
    /// Sends `frame` from directed LED `led` at power level `power`.
    fn transmit(&mut self, led: u8, power: u8, frame: IrFrame);
}

/// RGB status LED.
pub trait StatusLed {
    /// Sets the colour.
    fn set_rgb(&mut self, red: u8, green: u8, blue: u8);
}

/// Colour sensor under the robot.
pub trait ColourSensor {
    /// Reads red, green, blue and clear channels.
    fn read_colour(&mut self) -> [u16; 4];
}

/// Three-axis accelerometer.
pub trait Accelerometer {
    /// Reads x (forward), y (left), z (up) in milli-g.
    fn read_accel(&mut self) -> [i16; 3];
}

/// Battery voltage and current monitor.
pub trait PowerMonitor {
    /// Battery voltage in millivolts.
    fn battery_mv(&mut self) -> u16;
    /// Current drawn in milliamperes.
    fn current_ma(&mut self) -> i16;
}

/// Core temperature sensor.
pub trait Thermometer {
    /// Temperature in tenths of a degree Celsius.
    fn temperature_dc(&mut self) -> i16;
}

/// Why settings storage failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StorageError {
    /// Nothing valid is stored (blank or corrupt); the factory image applies.
    Empty,
    /// The medium refused the write.
    WriteFailed,
}

/// Non-volatile settings storage (the thesis's EEPROM).
pub trait SettingsStorage {
    /// Fills `buf` with the stored settings image.
    fn load(&mut self, buf: &mut [u8]) -> Result<(), StorageError>;
    /// Stores a settings image.
    fn store(&mut self, data: &[u8]) -> Result<(), StorageError>;
}

/// A monotonic clock, for boards that need to read time themselves (the firmware never does).
pub trait MonotonicClock {
    /// Now.
    fn now(&self) -> Instant;
}

/// Everything the firmware needs from a board.
pub trait Board:
    Motors
    + EncoderCapture
    + LineSensorAdc
    + IrTransmitter
    + StatusLed
    + ColourSensor
    + Accelerometer
    + PowerMonitor
    + Thermometer
    + SettingsStorage
{
}

impl<T> Board for T where
    T: Motors
        + EncoderCapture
        + LineSensorAdc
        + IrTransmitter
        + StatusLed
        + ColourSensor
        + Accelerometer
        + PowerMonitor
        + Thermometer
        + SettingsStorage
{
}
