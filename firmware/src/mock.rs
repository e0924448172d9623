//! A kinematic stand-in board: wheels with a first-order motor model and unequal encoder stripes,
//! a line sensor over a straight tape on the floor, and recorders for every output.
//!
//! It is the board of the firmware's host tests and of builds whose peripherals an emulator does not
//! model (the QEMU robot). The simulator replaces it with rigid-body physics.

use heapless::{Deque, Vec};
use protocol::packets::AnyPacket;
use protocol::settings::Settings;

use crate::firmware::Firmware;
use crate::hal::{
    Accelerometer, ColourSensor, EncoderCapture, EncoderEdge, IrFrame, IrTransmitter,
    LineSensorAdc, Motors, PowerMonitor, SettingsStorage, StatusLed, StorageError, Thermometer,
    Wheel,
};
use crate::time::{Duration, Instant};

/// Parameters of the kinematic wheel model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WheelModel {
    /// Free-running speed at full duty, m/s.
    pub max_speed_mps: f32,
    /// Duty (permille) below which static friction holds the wheel.
    pub deadband_pwm: f32,
    /// Time constant of the wheel speed, seconds (motor and the robot's own inertia).
    pub tau_s: f32,
    /// Wheel diameter, metres.
    pub diameter_m: f32,
    /// Encoder edges per revolution.
    pub edges_per_rev: u32,
    /// Share of a stripe pair taken by the black stripe (0.5 = equal stripes).
    pub black_fraction: f32,
}

impl Default for WheelModel {
    fn default() -> Self {
        Self {
            max_speed_mps: 0.64,
            deadband_pwm: 30.0,
            tau_s: 0.06,
            diameter_m: 0.009,
            edges_per_rev: 40,
            black_fraction: 0.4,
        }
    }
}

/// One wheel: speed lags the duty's steady-state speed; its travel produces encoder edges.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct KinematicWheel {
    /// Speed, m/s.
    pub speed_mps: f32,
    /// Distance rolled since start, metres (signed).
    pub travel_m: f64,
}

impl KinematicWheel {
    /// Advances by `dt` under duty `pwm`; calls `edge(fraction_of_dt)` for each stripe edge passed.
    pub fn step(&mut self, model: &WheelModel, pwm: i16, dt: f32, mut edge: impl FnMut(f32)) {
        let p = f32::from(pwm);
        let target = if p.abs() <= model.deadband_pwm {
            0.0
        } else {
            let share = (p.abs() - model.deadband_pwm) / (1000.0 - model.deadband_pwm);
            model.max_speed_mps * share.min(1.0) * p.signum()
        };
        let alpha = 1.0 - libm::expf(-dt / model.tau_s);
        let v0 = self.speed_mps;
        self.speed_mps += (target - v0) * alpha;
        let start = self.travel_m;
        let end = start + f64::from((v0 + self.speed_mps) * 0.5 * dt);
        self.travel_m = end;
        if end == start {
            return;
        }
        let pair = core::f64::consts::PI * f64::from(model.diameter_m) * 2.0
            / f64::from(model.edges_per_rev.max(2));
        let black = pair * f64::from(model.black_fraction.clamp(0.05, 0.95));
        let (lo, hi) = if end > start {
            (start, end)
        } else {
            (end, start)
        };
        // Edges sit at k·pair and k·pair + black.
        let mut k = libm::floor(lo / pair) as i64;
        loop {
            let base = k as f64 * pair;
            if base > hi {
                break;
            }
            for pos in [base, base + black] {
                if pos > lo && pos <= hi {
                    let frac = ((pos - start) / (end - start)) as f32;
                    edge(frac.clamp(0.0, 1.0));
                }
            }
            k += 1;
        }
    }
}

/// Pose in the plane: x, y metres, heading radians.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Pose {
    /// x, metres.
    pub x: f64,
    /// y, metres.
    pub y: f64,
    /// Heading, radians CCW from +x.
    pub theta: f64,
}

/// Floor under the robot: white, with a straight black tape along the world x axis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Floor {
    /// World y of the tape's centre line, metres.
    pub tape_y_m: f64,
    /// Tape width, metres.
    pub tape_width_m: f64,
    /// How far ahead of the wheel axle the line sensor sits, metres.
    pub sensor_ahead_m: f64,
    /// Distance between sensor spots, metres.
    pub spot_pitch_m: f64,
    /// Ambient light added to every detector reading.
    pub ambient: u16,
    /// Lit reading over white.
    pub white: u16,
    /// Lit reading over black.
    pub black: u16,
}

impl Default for Floor {
    fn default() -> Self {
        Self {
            tape_y_m: 0.0,
            tape_width_m: 0.006,
            sensor_ahead_m: 0.015,
            spot_pitch_m: 0.003,
            ambient: 200,
            white: 3000,
            black: 300,
        }
    }
}

/// The stand-in board.
#[derive(Clone, Debug)]
pub struct MockBoard {
    /// Wheel model.
    pub model: WheelModel,
    /// Wheels, left then right.
    pub wheels: [KinematicWheel; 2],
    /// Duty last set by the firmware.
    pub pwm: (i16, i16),
    /// Wheel gauge, metres.
    pub gauge_m: f32,
    /// True pose from integrating the wheels.
    pub pose: Pose,
    /// Floor under the line sensor.
    pub floor: Floor,
    /// Emitter mask last set.
    pub emitters: u8,
    /// Status LED.
    pub led: [u8; 3],
    /// Colour channels to report.
    pub colour: [u16; 4],
    /// Battery voltage to report.
    pub battery_mv: u16,
    /// IR transmissions (most recent 64).
    pub ir_sent: Deque<(u8, u8, IrFrame), 64>,
    /// Stored settings image.
    pub storage: Option<[u8; Settings::SIZE]>,
    edges: Deque<EncoderEdge, 64>,
}

impl Default for MockBoard {
    fn default() -> Self {
        Self {
            model: WheelModel::default(),
            wheels: [KinematicWheel::default(); 2],
            pwm: (0, 0),
            gauge_m: 0.026,
            pose: Pose::default(),
            floor: Floor::default(),
            emitters: 0,
            led: [0; 3],
            colour: [100, 100, 100, 300],
            battery_mv: 3900,
            ir_sent: Deque::new(),
            storage: None,
            edges: Deque::new(),
        }
    }
}

impl MockBoard {
    /// Moves the wheels and the pose by `dt`, queuing encoder edges stamped inside `[now, now+dt]`.
    pub fn step(&mut self, now: Instant, dt: Duration) {
        let dt_s = dt.as_secs_f32();
        let pwm = [self.pwm.0, self.pwm.1];
        let before = [self.wheels[0].travel_m, self.wheels[1].travel_m];
        for (i, wheel) in [Wheel::Left, Wheel::Right].into_iter().enumerate() {
            let model = self.model;
            let edges = &mut self.edges;
            self.wheels[i].step(&model, pwm[i], dt_s, |frac| {
                let at =
                    now + Duration::from_nanos((f64::from(frac) * dt.as_nanos() as f64) as u64);
                if edges.is_full() {
                    edges.pop_front();
                }
                let _ = edges.push_back(EncoderEdge { wheel, at });
            });
        }
        let dl = self.wheels[0].travel_m - before[0];
        let dr = self.wheels[1].travel_m - before[1];
        let d = (dl + dr) * 0.5;
        let dtheta = (dr - dl) / f64::from(self.gauge_m);
        let mid = self.pose.theta + dtheta * 0.5;
        self.pose.x += d * libm::cos(mid);
        self.pose.y += d * libm::sin(mid);
        self.pose.theta += dtheta;
    }

    /// Lit reading of one spot: white and black mixed by how much of the spot's 3 mm footprint
    /// the tape covers, so the line position varies smoothly as the tape slides under the sensor.
    fn spot_reflectance(&self, spot: usize) -> u16 {
        let f = &self.floor;
        let (s, c) = (libm::sin(self.pose.theta), libm::cos(self.pose.theta));
        let lateral = (spot as f64 - 3.5) * f.spot_pitch_m;
        // The sensor's rightward axis in the world is (sin θ, −cos θ); for small headings the
        // footprint's extent across the tape is its width over cos θ.
        let y = self.pose.y + f.sensor_ahead_m * s - lateral * c;
        let half_spot = 0.5 * f.spot_pitch_m * c.abs().max(0.2);
        let half_tape = f.tape_width_m * 0.5;
        let overlap = ((y + half_spot).min(f.tape_y_m + half_tape)
            - (y - half_spot).max(f.tape_y_m - half_tape))
        .max(0.0);
        let black_share = (overlap / (2.0 * half_spot)).min(1.0);
        (f64::from(f.white) + (f64::from(f.black) - f64::from(f.white)) * black_share) as u16
    }
}

impl Motors for MockBoard {
    fn set_pwm(&mut self, left: i16, right: i16) {
        self.pwm = (left, right);
    }
}

impl EncoderCapture for MockBoard {
    fn pop_edge(&mut self) -> Option<EncoderEdge> {
        self.edges.pop_front()
    }
}

impl LineSensorAdc for MockBoard {
    fn set_emitters(&mut self, mask: u8) {
        self.emitters = mask;
    }
    fn read_detectors(&mut self) -> [u16; 4] {
        let mut out = [self.floor.ambient; 4];
        for (det, v) in out.iter_mut().enumerate() {
            // Emitter `det` lights the spot left of the detector, emitter `det + 1` the right one.
            if self.emitters & (1 << det) != 0 {
                *v = v.saturating_add(self.spot_reflectance(2 * det));
            }
            if self.emitters & (1 << (det + 1)) != 0 {
                *v = v.saturating_add(self.spot_reflectance(2 * det + 1));
            }
            *v = (*v).min(4095);
        }
        out
    }
}

impl IrTransmitter for MockBoard {
    fn transmit(&mut self, led: u8, power: u8, frame: IrFrame) {
        if self.ir_sent.is_full() {
            self.ir_sent.pop_front();
        }
        let _ = self.ir_sent.push_back((led, power, frame));
    }
}

impl StatusLed for MockBoard {
    fn set_rgb(&mut self, red: u8, green: u8, blue: u8) {
        self.led = [red, green, blue];
    }
}

impl ColourSensor for MockBoard {
    fn read_colour(&mut self) -> [u16; 4] {
        self.colour
    }
}

impl Accelerometer for MockBoard {
    fn read_accel(&mut self) -> [i16; 3] {
        [0, 0, 1000]
    }
}

impl PowerMonitor for MockBoard {
    fn battery_mv(&mut self) -> u16 {
        self.battery_mv
    }
    fn current_ma(&mut self) -> i16 {
        ((i32::from(self.pwm.0.unsigned_abs()) + i32::from(self.pwm.1.unsigned_abs())) / 10) as i16
    }
}

impl Thermometer for MockBoard {
    fn temperature_dc(&mut self) -> i16 {
        250
    }
}

impl SettingsStorage for MockBoard {
    fn load(&mut self, buf: &mut [u8]) -> Result<(), StorageError> {
        let image = self.storage.as_ref().ok_or(StorageError::Empty)?;
        if buf.len() != image.len() {
            return Err(StorageError::Empty);
        }
        buf.copy_from_slice(image);
        Ok(())
    }
    fn store(&mut self, data: &[u8]) -> Result<(), StorageError> {
        let mut image = [0u8; Settings::SIZE];
        if data.len() != image.len() {
            return Err(StorageError::WriteFailed);
        }
        image.copy_from_slice(data);
        self.storage = Some(image);
        Ok(())
    }
}

/// Firmware on a mock board with a clock: the host side of a test.
pub struct MockRobot {
    /// The firmware under test.
    pub fw: Firmware<MockBoard>,
    /// Current time.
    pub now: Instant,
    /// Physics step.
    pub dt: Duration,
}

impl MockRobot {
    /// Boots the firmware on `board`.
    pub fn new(board: MockBoard) -> Self {
        Self {
            fw: Firmware::new(board),
            now: Instant::ZERO,
            dt: Duration::from_micros(100),
        }
    }

    /// Sends one host packet.
    pub fn send(&mut self, p: impl Into<AnyPacket>) {
        let mut buf = [0u8; protocol::MAX_PACKET];
        let n = p.into().encode(&mut buf).unwrap_or(0);
        self.fw.on_link_packet(self.now, &buf[..n]);
    }

    /// Advances one physics step and one firmware tick.
    pub fn step(&mut self) {
        self.fw.board_mut().step(self.now, self.dt);
        self.now = self.now + self.dt;
        self.fw.tick(self.now);
    }

    /// Runs for `d`, handing every packet the robot sends to `on_packet` with its send time.
    pub fn run(&mut self, d: Duration, mut on_packet: impl FnMut(Instant, AnyPacket)) {
        let end = self.now + d;
        while self.now < end {
            self.step();
            while let Some(p) = self.fw.pop_packet() {
                if let Ok(packet) = protocol::decode(&p) {
                    on_packet(self.now, packet);
                }
            }
        }
    }

    /// Runs until `until` returns true for a received packet or `limit` passes; returns the time.
    pub fn run_until(
        &mut self,
        limit: Duration,
        mut until: impl FnMut(&AnyPacket) -> bool,
    ) -> Option<Instant> {
        let end = self.now + limit;
        while self.now < end {
            self.step();
            while let Some(p) = self.fw.pop_packet() {
                if let Ok(packet) = protocol::decode(&p) {
                    if until(&packet) {
                        return Some(self.now);
                    }
                }
            }
        }
        None
    }

    /// Drains and decodes every waiting outgoing packet.
    pub fn drain(&mut self) -> Vec<AnyPacket, 32> {
        let mut out = Vec::new();
        while let Some(p) = self.fw.pop_packet() {
            if let Ok(packet) = protocol::decode(&p) {
                let _ = out.push(packet);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wheel_edges_alternate_narrow_and_wide() {
        let model = WheelModel::default();
        let mut w = KinematicWheel {
            speed_mps: 0.1,
            travel_m: 0.0,
        };
        let mut times = std::vec::Vec::new();
        let mut t = 0.0f32;
        let dt = 1e-4;
        // Duty holding 0.1 m/s: 0.1/0.64 of the span above the dead band.
        let pwm = (30.0 + 0.1 / 0.64 * 970.0) as i16;
        for _ in 0..2000 {
            w.step(&model, pwm, dt, |f| times.push(t + f * dt));
            t += dt;
        }
        let p: std::vec::Vec<f32> = times.windows(2).map(|w| w[1] - w[0]).collect();
        let (odd, even) = (p[11], p[12]);
        assert!(
            (odd / even - 1.0).abs() > 0.2,
            "stripes unequal: {odd} {even}"
        );
        let pair = std::f32::consts::PI * 0.009 / 20.0;
        assert!(((odd + even) - pair / 0.1).abs() / (pair / 0.1) < 0.02);
    }
}
