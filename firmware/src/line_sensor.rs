//! Line sensor: ambient-suppressed sampling of 8 spots, calibration, line position (thesis 11.3).

use crate::hal::LineSensorAdc;
use protocol::packets::{CalibrationAction, Mark};
use protocol::settings::{ColourSettings, LineSensorSettings, Settings};

/// Number of spots: 4 detectors, each seen through its left and its right emitter.
pub const SPOTS: usize = 8;

/// Emitters E0, E2, E4: each detector sees the spot lit by one of its two neighbours.
const PHASE_A_MASK: u8 = 0b10101;
/// Emitters E1, E3: each detector sees the spot lit by its other neighbour.
const PHASE_B_MASK: u8 = 0b01010;
/// Spot seen by detector `d` in phase A.
const PHASE_A_SPOTS: [usize; 4] = [0, 3, 4, 7];
/// Spot seen by detector `d` in phase B.
const PHASE_B_SPOTS: [usize; 4] = [1, 2, 5, 6];

/// Darkness (permille) subtracted before the centroid, so that the noise of the white spots far from
/// the line does not pull the position toward the sensor centre.
const CENTROID_FLOOR: u16 = 150;
/// Smallest raw range (max − min) over which a spot's calibration sweep counts as having seen both
/// floor and tape; a flatter spot keeps its old calibration rather than amplifying noise.
const MIN_CALIBRATION_RANGE: u16 = 100;

/// One processed line-sensor measurement.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LineReading {
    /// Calibrated darkness per spot in permille, 0 = white floor, 1000 = black tape; spot 0 is
    /// leftmost.
    pub darkness: [u16; SPOTS],
    /// Line centre relative to the sensor centre in micrometres, positive = to the right. While
    /// [`lost`](Self::lost) it holds the edge nearest to where the line was last seen.
    pub position_um: i16,
    /// No spot is dark enough to be on the line.
    pub lost: bool,
}

/// Line sensor state: calibration recording and the last position the line was seen at.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LineSensor {
    calibrating: bool,
    min: [u16; SPOTS],
    max: [u16; SPOTS],
    /// Last position at which the line was seen, in micrometres; `None` before the first sighting.
    last_seen_um: Option<i32>,
}

impl Default for LineSensor {
    fn default() -> Self {
        Self::new()
    }
}

impl LineSensor {
    /// A sensor that has not seen a line and is not calibrating.
    pub const fn new() -> Self {
        Self {
            calibrating: false,
            min: [u16::MAX; SPOTS],
            max: [0; SPOTS],
            last_seen_um: None,
        }
    }

    /// Runs dark / phase A / dark / phase B on the ADC and returns the ambient-suppressed reading of
    /// each spot (lit − dark, saturating at 0). The emitters are left off.
    pub fn sample<A: LineSensorAdc + ?Sized>(&mut self, adc: &mut A) -> [u16; SPOTS] {
        adc.set_emitters(0);
        let dark_before = adc.read_detectors();
        adc.set_emitters(PHASE_A_MASK);
        let lit_a = adc.read_detectors();
        adc.set_emitters(0);
        let dark_between = adc.read_detectors();
        adc.set_emitters(PHASE_B_MASK);
        let lit_b = adc.read_detectors();
        adc.set_emitters(0);

        let mut out = [0u16; SPOTS];
        for d in 0..4 {
            // Phase A is bracketed by two dark reads; their mean cancels ambient light that drifts
            // linearly during the sample (mains flicker, the robot moving under a lamp).
            let dark_a =
                (u32::from(dark_before[d]) + u32::from(dark_between[d])).div_ceil(2) as u16;
            out[PHASE_A_SPOTS[d]] = lit_a[d].saturating_sub(dark_a);
            out[PHASE_B_SPOTS[d]] = lit_b[d].saturating_sub(dark_between[d]);
        }
        out
    }

    /// Calibrated darkness, width-independent position and lost flag from one
    /// [`sample`](Self::sample); while calibrating also records each spot's extremes.
    pub fn process(
        &mut self,
        suppressed: &[u16; SPOTS],
        settings: &LineSensorSettings,
    ) -> LineReading {
        if self.calibrating {
            for (i, &v) in suppressed.iter().enumerate() {
                self.min[i] = self.min[i].min(v);
                self.max[i] = self.max[i].max(v);
            }
        }

        let white = settings.white;
        let black = settings.black;
        let pitch = i64::from(settings.spot_pitch_um);
        let lost_threshold = settings.lost_threshold;

        let mut darkness = [0u16; SPOTS];
        for i in 0..SPOTS {
            darkness[i] = spot_darkness(suppressed[i], white[i], black[i]);
        }

        // Centroid of the (floored) darkness profile: a symmetric dark band of any width has its
        // centroid at its centre, so the line width does not bias the position (thesis 11.3).
        // Positions are in half micrometres so the spot centres (odd multiples of pitch / 2) are
        // integers.
        let mut sum_w: i64 = 0;
        let mut sum_wx: i64 = 0;
        let mut max_d = 0u16;
        for (i, &d) in darkness.iter().enumerate() {
            max_d = max_d.max(d);
            let w = i64::from(d.saturating_sub(CENTROID_FLOOR));
            sum_w += w;
            sum_wx += w * (2 * i as i64 - (SPOTS as i64 - 1)) * pitch;
        }

        let lost = max_d < lost_threshold || sum_w == 0;
        let position = if lost {
            // Report the edge on the side the line left by, so a follower keeps turning back
            // toward it; with no side known, straight ahead is the least harmful guess.
            let edge = (SPOTS as i64 - 1) * pitch / 2;
            match self.last_seen_um {
                Some(p) if p > 0 => edge,
                Some(p) if p < 0 => -edge,
                _ => 0,
            }
        } else {
            let p = div_round(sum_wx, 2 * sum_w);
            self.last_seen_um = Some(p.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32);
            p
        };

        LineReading {
            darkness,
            position_um: position.clamp(i64::from(i16::MIN), i64::from(i16::MAX)) as i16,
            lost,
        }
    }

    /// Applies a calibration command to `settings`.
    ///
    /// `Start` forgets the recorded extremes and starts recording; `Finish` adopts each spot's
    /// recorded maximum as white and minimum as black where the spot saw a meaningful range;
    /// `Reset` restores the factory white and black.
    pub fn calibrate(&mut self, action: CalibrationAction, settings: &mut LineSensorSettings) {
        match action {
            CalibrationAction::Start => {
                self.calibrating = true;
                self.min = [u16::MAX; SPOTS];
                self.max = [0; SPOTS];
            }
            CalibrationAction::Finish => {
                if !self.calibrating {
                    // Without a Start the extremes are stale or empty; adopting them would
                    // corrupt a good calibration.
                    return;
                }
                self.calibrating = false;
                let mut white = settings.white;
                let mut black = settings.black;
                for i in 0..SPOTS {
                    // A spot that never saw both floor and tape (max ≤ min, or a small range)
                    // keeps its previous values.
                    if self.max[i] >= self.min[i].saturating_add(MIN_CALIBRATION_RANGE) {
                        white[i] = self.max[i];
                        black[i] = self.min[i];
                    }
                }
                settings.white = white;
                settings.black = black;
            }
            CalibrationAction::Reset => {
                self.calibrating = false;
                let factory = Settings::default().line_sensor;
                settings.white = factory.white;
                settings.black = factory.black;
            }
        }
    }

    /// Whether a calibration sweep is being recorded.
    pub fn is_calibrating(&self) -> bool {
        self.calibrating
    }
}

/// Darkness of one spot in permille; an uncalibrated spot (white ≤ black) reads white so it cannot
/// fake a line.
fn spot_darkness(v: u16, white: u16, black: u16) -> u16 {
    if white <= black {
        return 0;
    }
    let range = i32::from(white) - i32::from(black);
    let d = (i32::from(white) - i32::from(v)) * 1000 / range;
    d.clamp(0, 1000) as u16
}

/// `n / d` rounded half away from zero, `d > 0`.
fn div_round(n: i64, d: i64) -> i64 {
    if n >= 0 {
        (n + d / 2) / d
    } else {
        -((-n + d / 2) / d)
    }
}

/// Mark under the robot from colour channels `[r, g, b, clear]`: a channel must beat both others
/// by `mark_ratio` on a surface bright enough to trust.
pub fn classify_mark(rgbc: [u16; 4], settings: &ColourSettings) -> Mark {
    let ratio = settings.mark_ratio;
    let min_clear = settings.min_clear;
    let [r, g, b, clear] = rgbc;
    if clear < min_clear {
        return Mark::None;
    }
    let (r, g, b) = (f32::from(r), f32::from(g), f32::from(b));
    // NaN ratios fail every comparison and so classify as no mark.
    if r > ratio * g && r > ratio * b {
        Mark::Red
    } else if b > ratio * r && b > ratio * g {
        Mark::Blue
    } else {
        Mark::None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Floor reflectance per spot (the lit signal above ambient) plus a constant ambient level on
    /// every detector, clamped to the 12-bit ADC range.
    struct FakeAdc {
        spot: [u16; SPOTS],
        ambient: u16,
        mask: u8,
    }

    impl FakeAdc {
        fn new(spot: [u16; SPOTS], ambient: u16) -> Self {
            Self {
                spot,
                ambient,
                mask: 0xff,
            }
        }
    }

    impl LineSensorAdc for FakeAdc {
        fn set_emitters(&mut self, mask: u8) {
            self.mask = mask;
        }
        fn read_detectors(&mut self) -> [u16; 4] {
            let mut out = [0u16; 4];
            for (d, o) in out.iter_mut().enumerate() {
                // Emitter d sits left of detector d and lights spot 2d; emitter d + 1 lights 2d + 1.
                let mut v = u32::from(self.ambient);
                if self.mask & (1 << d) != 0 {
                    v += u32::from(self.spot[2 * d]);
                }
                if self.mask & (1 << (d + 1)) != 0 {
                    v += u32::from(self.spot[2 * d + 1]);
                }
                *o = v.min(4095) as u16;
            }
            out
        }
    }

    const PITCH: f64 = 3000.0;

    fn spot_x(i: usize) -> f64 {
        (i as f64 - 3.5) * PITCH
    }

    /// Fraction of spot `i`'s footprint covered by a line `[centre ± width / 2]`. The footprint is a
    /// triangle of half-width one pitch, so neighbouring spots overlap as real IR spots do.
    fn coverage(i: usize, centre: f64, width: f64) -> f64 {
        let (a, b) = (centre - width / 2.0, centre + width / 2.0);
        let x = spot_x(i);
        // Integrate the triangle numerically; exactness is not the point, smoothness is.
        let n = 600;
        let (lo, hi) = (x - PITCH, x + PITCH);
        let step = (hi - lo) / n as f64;
        let mut covered = 0.0;
        for k in 0..n {
            let t = lo + (k as f64 + 0.5) * step;
            if t >= a && t <= b {
                covered += (1.0 - (t - x).abs() / PITCH) * step;
            }
        }
        covered / PITCH
    }

    /// Lit signal per spot for a black line of `width` at `centre` over white floor.
    fn floor(centre_um: f64, width_um: f64, white: u16, black: u16) -> [u16; SPOTS] {
        let mut s = [0u16; SPOTS];
        for (i, v) in s.iter_mut().enumerate() {
            let c = coverage(i, centre_um, width_um);
            *v = (f64::from(white) - (f64::from(white) - f64::from(black)) * c).round() as u16;
        }
        s
    }

    fn settings_for(white: u16, black: u16) -> LineSensorSettings {
        let mut s = Settings::default().line_sensor;
        s.white = [white; SPOTS];
        s.black = [black; SPOTS];
        s.spot_pitch_um = PITCH as u16;
        s
    }

    fn read_line(centre: f64, width: f64) -> LineReading {
        let settings = settings_for(3000, 300);
        let mut adc = FakeAdc::new(floor(centre, width, 3000, 300), 0);
        let mut sensor = LineSensor::new();
        let s = sensor.sample(&mut adc);
        sensor.process(&s, &settings)
    }

    #[test]
    fn line_sample_maps_detectors_and_phases_to_spots() {
        let spots = [100, 200, 300, 400, 500, 600, 700, 800];
        let mut adc = FakeAdc::new(spots, 1000);
        let mut sensor = LineSensor::new();
        assert_eq!(sensor.sample(&mut adc), spots);
        assert_eq!(adc.mask, 0, "emitters must be left dark");
    }

    #[test]
    fn line_sample_never_goes_negative() {
        // The ADC saturates with the emitters lit, so lit − dark would underflow if dark were
        // somehow higher; a fake with the lit phases dimmer than the dark phase checks it.
        struct Inverted(u8);
        impl LineSensorAdc for Inverted {
            fn set_emitters(&mut self, mask: u8) {
                self.0 = mask;
            }
            fn read_detectors(&mut self) -> [u16; 4] {
                if self.0 == 0 {
                    [4000; 4]
                } else {
                    [10; 4]
                }
            }
        }
        assert_eq!(LineSensor::new().sample(&mut Inverted(0)), [0; SPOTS]);
    }

    #[test]
    fn line_ambient_light_does_not_move_the_position() {
        // White 1500 keeps white + ambient 2500 below the ADC ceiling.
        let settings = settings_for(1500, 150);
        let spots = floor(2100.0, 4000.0, 1500, 150);
        let mut positions = [0i16; 4];
        for (k, &ambient) in [0u16, 500, 1500, 2500].iter().enumerate() {
            let mut adc = FakeAdc::new(spots, ambient);
            let mut sensor = LineSensor::new();
            let s = sensor.sample(&mut adc);
            let r = sensor.process(&s, &settings);
            assert!(!r.lost);
            positions[k] = r.position_um;
        }
        for p in positions {
            assert!(
                (i32::from(p) - i32::from(positions[0])).abs() <= 1,
                "{positions:?}"
            );
        }
        assert!(
            (i32::from(positions[0]) - 2100).abs() < 300,
            "{positions:?}"
        );
    }

    #[test]
    fn line_ambient_is_suppressed_per_phase() {
        // Ambient rising by 100 on every read: each lit phase must be suppressed by the dark reads
        // around it rather than by a stale one.
        struct Drifting {
            mask: u8,
            ambient: u16,
        }
        impl LineSensorAdc for Drifting {
            fn set_emitters(&mut self, mask: u8) {
                self.mask = mask;
            }
            fn read_detectors(&mut self) -> [u16; 4] {
                let a = self.ambient;
                self.ambient += 100;
                let lit = if self.mask == 0 { 0 } else { 1000 };
                [a + lit; 4]
            }
        }
        let s = LineSensor::new().sample(&mut Drifting {
            mask: 0,
            ambient: 0,
        });
        // Phase A (read 2) between darks 1 and 3 cancels exactly; phase B (read 4) after dark 3
        // is off by one drift step.
        assert_eq!(s[0], 1000);
        assert_eq!(s[1], 1100);
    }

    #[test]
    fn line_centred_between_spots_3_and_4_is_zero() {
        let r = read_line(0.0, 3000.0);
        assert!(!r.lost);
        assert!(r.position_um.abs() <= 10, "{r:?}");
        assert_eq!(r.darkness[3], r.darkness[4]);
        assert!(
            r.darkness[3] > 300 && r.darkness[0] < 50 && r.darkness[7] < 50,
            "{r:?}"
        );
    }

    #[test]
    fn line_under_spot_5_is_one_and_a_half_pitch_right() {
        let truth = spot_x(5);
        assert_eq!(truth, 1.5 * PITCH);
        let r = read_line(truth, 3000.0);
        assert!(!r.lost);
        assert!(
            (f64::from(r.position_um) - truth).abs() < 0.1 * truth,
            "{r:?}"
        );
        let l = read_line(-truth, 3000.0);
        assert!(
            (f64::from(l.position_um) + truth).abs() < 0.1 * truth,
            "{l:?}"
        );
    }

    #[test]
    fn line_width_does_not_bias_the_position() {
        for truth in [-5200.0, -1234.0, 0.0, 700.0, 2600.0] {
            let narrow = read_line(truth, 3000.0);
            let wide = read_line(truth, 9000.0);
            assert!(!narrow.lost && !wide.lost);
            let (n, w) = (f64::from(narrow.position_um), f64::from(wide.position_um));
            assert!((n - w).abs() < 300.0, "{truth}: narrow {n}, wide {w}");
            assert!((n - truth).abs() < 300.0, "{truth}: narrow {n}");
            assert!((w - truth).abs() < 300.0, "{truth}: wide {w}");
        }
    }

    #[test]
    fn line_position_is_monotonic_across_the_sensor() {
        let mut last = i16::MIN;
        let mut x = -9000.0;
        while x <= 9000.0 {
            let r = read_line(x, 3000.0);
            assert!(!r.lost, "{x}");
            assert!(r.position_um >= last, "{x}: {} after {last}", r.position_um);
            last = r.position_um;
            x += 250.0;
        }
    }

    #[test]
    fn line_lost_holds_the_edge_it_left_by() {
        let settings = settings_for(3000, 300);
        let white = [3000u16; SPOTS];
        let edge = (3.5 * PITCH) as i16;
        for (seen_at, expect) in [(6000.0, edge), (-6000.0, -edge)] {
            let mut sensor = LineSensor::new();
            let r = sensor.process(&floor(seen_at, 3000.0, 3000, 300), &settings);
            assert!(!r.lost);
            let r = sensor.process(&white, &settings);
            assert!(r.lost);
            assert_eq!(r.position_um, expect);
            // Still lost: the held edge must not drift or flip.
            let r = sensor.process(&white, &settings);
            assert!(r.lost);
            assert_eq!(r.position_um, expect);
        }
        // Never seen: no side to prefer.
        let r = LineSensor::new().process(&white, &settings);
        assert!(r.lost);
        assert_eq!(r.position_um, 0);
    }

    #[test]
    fn line_faint_grey_counts_as_lost() {
        let settings = settings_for(3000, 300);
        // 20 % darkness everywhere is below the 25 % lost threshold.
        let grey = [3000 - 540; SPOTS];
        let r = LineSensor::new().process(&grey, &settings);
        assert!(r.lost);
        assert!(r.darkness.iter().all(|&d| d == 200), "{r:?}");
    }

    #[test]
    fn line_darkness_is_clamped_and_guards_bad_calibration() {
        let mut settings = settings_for(3000, 300);
        let mut sensor = LineSensor::new();
        let r = sensor.process(&[4000, 3000, 1650, 300, 0, 0, 0, 0], &settings);
        assert_eq!(&r.darkness[..5], &[0, 0, 500, 1000, 1000]);
        let mut black = settings.black;
        black[0] = 3000;
        settings.black = black;
        let r = sensor.process(&[0; SPOTS], &settings);
        assert_eq!(r.darkness[0], 0, "white <= black must not read as a line");
    }

    #[test]
    fn line_position_saturates_into_i16() {
        let mut settings = settings_for(3000, 300);
        settings.spot_pitch_um = 20_000;
        let mut spots = [3000u16; SPOTS];
        spots[7] = 300;
        let r = LineSensor::new().process(&spots, &settings);
        assert_eq!(r.position_um, i16::MAX);
        spots = [3000; SPOTS];
        spots[0] = 300;
        let r = LineSensor::new().process(&spots, &settings);
        assert_eq!(r.position_um, i16::MIN);
    }

    #[test]
    fn line_calibration_adopts_extremes_and_ignores_flat_spots() {
        let mut settings = settings_for(3000, 300);
        let mut sensor = LineSensor::new();
        assert!(!sensor.is_calibrating());
        sensor.calibrate(CalibrationAction::Start, &mut settings);
        assert!(sensor.is_calibrating());
        // Spots 0..7 sweep between 2500 and 400 + 10·i; spot 7 stays at 2000 ± 40.
        for k in 0..20u16 {
            let mut s = [0u16; SPOTS];
            for (i, v) in s.iter_mut().enumerate().take(7) {
                *v = if k % 2 == 0 {
                    2500 - k
                } else {
                    400 + 10 * i as u16 + k
                };
            }
            s[7] = 2000 + (k % 3) * 20;
            sensor.process(&s, &settings);
        }
        sensor.calibrate(CalibrationAction::Finish, &mut settings);
        assert!(!sensor.is_calibrating());
        let (white, black) = (settings.white, settings.black);
        for i in 0..7 {
            assert_eq!(white[i], 2500, "spot {i}");
            assert_eq!(black[i], 400 + 10 * i as u16 + 1, "spot {i}");
        }
        assert_eq!(
            (white[7], black[7]),
            (3000, 300),
            "flat spot keeps its calibration"
        );

        // A later Finish without Start changes nothing.
        let before = settings;
        sensor.process(&[0; SPOTS], &settings);
        sensor.calibrate(CalibrationAction::Finish, &mut settings);
        assert_eq!(settings, before);

        settings.spot_pitch_um = 2500;
        sensor.calibrate(CalibrationAction::Reset, &mut settings);
        let factory = Settings::default().line_sensor;
        assert_eq!({ settings.white }, { factory.white });
        assert_eq!({ settings.black }, { factory.black });
        assert_eq!(
            { settings.spot_pitch_um },
            2500,
            "geometry is not calibration"
        );
    }

    #[test]
    fn line_calibration_start_forgets_old_extremes() {
        let mut settings = settings_for(3000, 300);
        let mut sensor = LineSensor::new();
        sensor.calibrate(CalibrationAction::Start, &mut settings);
        sensor.process(&[4000; SPOTS], &settings);
        sensor.process(&[10; SPOTS], &settings);
        sensor.calibrate(CalibrationAction::Start, &mut settings);
        sensor.process(&[2000; SPOTS], &settings);
        sensor.process(&[500; SPOTS], &settings);
        sensor.calibrate(CalibrationAction::Finish, &mut settings);
        assert_eq!({ settings.white }, [2000; SPOTS]);
        assert_eq!({ settings.black }, [500; SPOTS]);
    }

    #[test]
    fn line_classify_mark_cases() {
        let c = Settings::default().colour;
        assert_eq!(classify_mark([800, 300, 300, 1200], &c), Mark::Red);
        assert_eq!(classify_mark([300, 300, 800, 1200], &c), Mark::Blue);
        // Too dim to trust, even with a clear colour cast.
        assert_eq!(classify_mark([80, 30, 30, 150], &c), Mark::None);
        // White, black and green are not marks.
        assert_eq!(classify_mark([900, 900, 900, 2500], &c), Mark::None);
        assert_eq!(classify_mark([20, 20, 20, 250], &c), Mark::None);
        assert_eq!(classify_mark([200, 800, 200, 1200], &c), Mark::None);
        // Red must beat both green and blue by the ratio: magenta is neither.
        assert_eq!(classify_mark([800, 200, 600, 1200], &c), Mark::None);
        // The ratio is strict at the boundary.
        assert_eq!(classify_mark([480, 300, 300, 1000], &c), Mark::None);
        assert_eq!(classify_mark([481, 300, 300, 1000], &c), Mark::Red);
    }
}
