//! `SimBoard`: the firmware's hardware traits implemented over values the simulator sets each step
//! (floor under the line sensor, colour, acceleration, battery) and outputs it collects (motor duty,
//! IR frames, LED), so the unmodified firmware runs against the physics world.

use std::collections::VecDeque;
use std::sync::Arc;

use firmware::hal::{
    Accelerometer, ColourSensor, EncoderCapture, EncoderEdge, IrFrame, IrTransmitter,
    LineSensorAdc, Motors, PowerMonitor, SettingsStorage, StatusLed, StorageError, Thermometer,
};
use nalgebra::Point2;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use crate::world::{Surface, Track};

/// Where the line and colour sensors are, so the board can look at the floor when the firmware
/// actually samples (500 Hz line, 200 Hz colour) rather than on every physics step.
#[derive(Clone, Debug)]
pub struct FloorView {
    /// The floor; private, as the looks below hold for this floor only.
    track: Arc<Track>,
    /// Line sensor centre, metres.
    pub sensor: [f64; 2],
    /// Sine and cosine of the heading.
    pub sin_cos: (f64, f64),
    /// Distance between spots, metres.
    pub spot_pitch_m: f64,
    /// Colour channel counts for a reflectance of 1.
    pub colour_scale: f32,
    /// What each spot (and, last, the colour sensor) saw where it last looked, and how far from
    /// there the floor is known to look the same.
    looks: [Look; 9],
}

/// One sensor's last look at the floor.
#[derive(Clone, Copy, Debug)]
struct Look {
    at: Point2<f64>,
    surface: Surface,
    /// Square of the radius around `at` with the same floor; 0 before the first look.
    radius2: f64,
}

impl FloorView {
    /// The floor `track` seen by a line sensor centred at `sensor` with its heading's (sin, cos).
    pub fn new(
        track: Arc<Track>,
        sensor: [f64; 2],
        sin_cos: (f64, f64),
        spot_pitch_m: f64,
        colour_scale: f32,
    ) -> Self {
        let unseen = Look {
            at: Point2::origin(),
            surface: Surface::WHITE,
            radius2: 0.0,
        };
        Self {
            track,
            sensor,
            sin_cos,
            spot_pitch_m,
            colour_scale,
            looks: [unseen; 9],
        }
    }

    /// The floor at `p` for sensor `k`: what it saw last time if `p` is within that look's
    /// radius (the same answer, without the geometry), else a fresh look.
    fn floor_at(&mut self, k: usize, p: Point2<f64>) -> Surface {
        let look = &mut self.looks[k];
        if (p - look.at).norm_squared() < look.radius2 {
            return look.surface;
        }
        let (surface, radius) = self.track.floor_at_within(p);
        *look = Look {
            at: p,
            surface,
            radius2: radius * radius,
        };
        surface
    }
}

/// Inputs from the world, outputs to it, and the board's own storage.
#[derive(Clone, Debug)]
pub struct SimBoard {
    /// Duty last set by the firmware, permille.
    pub pwm: (i16, i16),
    /// Encoder edges waiting for the firmware.
    pub edges: VecDeque<EncoderEdge>,
    /// IR reflectance of the floor under each line sensor spot (0 black .. 1 white), left to right.
    pub spots: [f32; 8],
    /// Ambient light level, 0..1.
    pub ambient: f32,
    /// Relative noise on sensor readings.
    pub noise: f32,
    /// Lit detector reading over perfect white, ADC counts.
    pub line_gain: f32,
    /// Detector reading per unit of ambient light.
    pub ambient_gain: f32,
    /// Emitters lit, bit per emitter.
    pub emitters: u8,
    /// Colour channels under the robot.
    pub colour: [u16; 4],
    /// Acceleration in the robot frame, milli-g.
    pub accel: [i16; 3],
    /// Battery terminal voltage, millivolts.
    pub battery_mv: u16,
    /// Current drawn, milliamperes.
    pub current_ma: i16,
    /// Core temperature, tenths of °C.
    pub temperature_dc: i16,
    /// Status LED colour.
    pub led: [u8; 3],
    /// IR frames the firmware transmitted since the simulator last took them: (led, power, frame).
    pub ir_out: Vec<(u8, u8, IrFrame)>,
    /// The settings image in "EEPROM".
    pub storage: Option<Vec<u8>>,
    /// The floor under the robot; `None` keeps `spots` and `colour` as set.
    pub floor: Option<FloorView>,
    /// Whether `spots` and `colour` were read off the floor since the robot last moved.
    fresh: (bool, bool),
    rng: ChaCha8Rng,
}

impl SimBoard {
    /// A board with a settings image in storage and its own noise stream.
    pub fn new(storage: Option<Vec<u8>>, rng: ChaCha8Rng) -> Self {
        Self {
            pwm: (0, 0),
            edges: VecDeque::new(),
            spots: [1.0; 8],
            ambient: 0.2,
            noise: 0.01,
            line_gain: 3000.0,
            ambient_gain: 2000.0,
            emitters: 0,
            colour: [0; 4],
            accel: [0, 0, 1000],
            battery_mv: 3900,
            current_ma: 0,
            temperature_dc: 250,
            led: [0; 3],
            ir_out: Vec::new(),
            storage,
            floor: None,
            fresh: (false, false),
            rng,
        }
    }

    /// Puts the line sensor's centre at `sensor` with its heading's (sin, cos); the floor is
    /// looked at again only if that moved it, so a robot standing still reads the same spots
    /// without the lookups.
    pub fn place_floor_sensor(&mut self, sensor: [f64; 2], sin_cos: (f64, f64)) {
        if let Some(f) = &mut self.floor {
            if f.sensor == sensor && f.sin_cos == sin_cos {
                return;
            }
            f.sensor = sensor;
            f.sin_cos = sin_cos;
        }
        self.fresh = (false, false);
    }

    fn look_at_floor(&mut self) {
        if self.fresh.0 {
            return;
        }
        self.fresh.0 = true;
        let Some(f) = &mut self.floor else { return };
        let (s, c) = f.sin_cos;
        for (k, spot) in self.spots.iter_mut().enumerate() {
            let lateral = (k as f64 - 3.5) * f.spot_pitch_m;
            // The sensor's rightward axis is (sin θ, −cos θ).
            let p = Point2::new(f.sensor[0] + lateral * s, f.sensor[1] - lateral * c);
            *spot = f.floor_at(k, p).ir_reflectance;
        }
    }

    fn look_at_colour(&mut self) {
        if self.fresh.1 {
            return;
        }
        self.fresh.1 = true;
        let Some(f) = &mut self.floor else { return };
        let rgb = f.floor_at(8, Point2::new(f.sensor[0], f.sensor[1])).rgb;
        let ch = |v: f32| (v * f.colour_scale).clamp(0.0, 65535.0) as u16;
        let (r, g, b) = (ch(rgb[0]), ch(rgb[1]), ch(rgb[2]));
        self.colour = [
            r,
            g,
            b,
            ((u32::from(r) + u32::from(g) + u32::from(b)) / 3) as u16,
        ];
    }

    fn noisy(&mut self, v: f32) -> f32 {
        if self.noise > 0.0 {
            v * (1.0 + self.noise * (self.rng.gen::<f32>() * 2.0 - 1.0))
        } else {
            v
        }
    }
}

impl Motors for SimBoard {
    fn set_pwm(&mut self, left: i16, right: i16) {
        self.pwm = (left, right);
    }
}

impl EncoderCapture for SimBoard {
    fn pop_edge(&mut self) -> Option<EncoderEdge> {
        self.edges.pop_front()
    }
}

impl LineSensorAdc for SimBoard {
    fn set_emitters(&mut self, mask: u8) {
        self.emitters = mask;
    }

    fn read_detectors(&mut self) -> [u16; 4] {
        self.look_at_floor();
        let mut out = [0u16; 4];
        for (det, slot) in out.iter_mut().enumerate() {
            let mut v = self.ambient * self.ambient_gain;
            // Emitter `det` lights the spot left of detector `det`, emitter `det + 1` the right one.
            if self.emitters & (1 << det) != 0 {
                v += self.spots[2 * det] * self.line_gain;
            }
            if self.emitters & (1 << (det + 1)) != 0 {
                v += self.spots[2 * det + 1] * self.line_gain;
            }
            *slot = self.noisy(v).clamp(0.0, 4095.0) as u16;
        }
        out
    }
}

impl IrTransmitter for SimBoard {
    fn transmit(&mut self, led: u8, power: u8, frame: IrFrame) {
        self.ir_out.push((led, power, frame));
    }
}

impl StatusLed for SimBoard {
    fn set_rgb(&mut self, red: u8, green: u8, blue: u8) {
        self.led = [red, green, blue];
    }
}

impl ColourSensor for SimBoard {
    fn read_colour(&mut self) -> [u16; 4] {
        self.look_at_colour();
        self.colour
    }
}

impl Accelerometer for SimBoard {
    fn read_accel(&mut self) -> [i16; 3] {
        self.accel
    }
}

impl PowerMonitor for SimBoard {
    fn battery_mv(&mut self) -> u16 {
        self.battery_mv
    }
    fn current_ma(&mut self) -> i16 {
        self.current_ma
    }
}

impl Thermometer for SimBoard {
    fn temperature_dc(&mut self) -> i16 {
        self.temperature_dc
    }
}

impl SettingsStorage for SimBoard {
    fn load(&mut self, buf: &mut [u8]) -> Result<(), StorageError> {
        match &self.storage {
            Some(image) if image.len() == buf.len() => {
                buf.copy_from_slice(image);
                Ok(())
            }
            _ => Err(StorageError::Empty),
        }
    }

    fn store(&mut self, data: &[u8]) -> Result<(), StorageError> {
        self.storage = Some(data.to_vec());
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn detectors_see_their_lit_spots_plus_ambient() {
        let mut b = SimBoard::new(None, ChaCha8Rng::seed_from_u64(1));
        b.noise = 0.0;
        b.spots = [1.0, 0.1, 1.0, 1.0, 1.0, 1.0, 1.0, 0.1];
        b.set_emitters(0);
        let dark = b.read_detectors();
        assert_eq!(dark, [400; 4]);
        b.set_emitters(0b10101);
        let a = b.read_detectors();
        assert_eq!(a, [3400, 3400, 3400, 700], "phase A: spots 0, 3, 4, 7");
        b.set_emitters(0b01010);
        let bb = b.read_detectors();
        assert_eq!(bb, [700, 3400, 3400, 3400], "phase B: spots 1, 2, 5, 6");
    }

    #[test]
    fn storage_round_trips() {
        let mut b = SimBoard::new(None, ChaCha8Rng::seed_from_u64(1));
        let mut buf = [0u8; 4];
        assert_eq!(b.load(&mut buf), Err(StorageError::Empty));
        b.store(&[1, 2, 3, 4]).unwrap();
        b.load(&mut buf).unwrap();
        assert_eq!(buf, [1, 2, 3, 4]);
    }
}
