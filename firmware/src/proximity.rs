//! Proximity logical layer (thesis 7.2): the IR transmit cycle, and turning received frames into
//! obstacle and robot-encounter events.
//!
//! Every frame carries {robot id, LED index, power level}. Our own frame coming back is a
//! reflection off an obstacle; another robot's frame identifies it, its LED index tells which way
//! it faces and the weakest power level that still reaches us how close it is. Sightings are kept
//! per (robot id, receiver side) in a fixed table of [`MAX_SIGHTINGS`] entries.

use heapless::Vec;
use protocol::packets::{Obstacle, RobotEncountered};
use protocol::settings::ProximitySettings;
use protocol::state::ProximityState;

use crate::hal::{IrFrame, Side};
use crate::time::{Duration, Instant};

/// Most (robot id, side) sightings tracked at once; a new one evicts the least recently seen.
pub const MAX_SIGHTINGS: usize = 8;

/// Something the proximity sensors found, ready to be sent to the host.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ProximityEvent {
    /// Our own light came back: an obstacle.
    Obstacle(Obstacle),
    /// Another robot's frame was received.
    Robot(RobotEncountered),
}

/// The LED and power level of one received frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Reading {
    power: u8,
    led: u8,
}

impl Reading {
    /// Lower power reaching us means closer, so the weakest reading is the one worth reporting.
    fn weakest(a: Option<Reading>, b: Reading) -> Reading {
        match a {
            Some(a) if a.power <= b.power => a,
            _ => b,
        }
    }
}

#[derive(Clone, Copy, Debug)]
struct Sighting {
    robot_id: u16,
    side: Side,
    /// Set from the last frame rather than fixed at creation, so a live change of our id cannot
    /// leave a stale classification behind.
    obstacle: bool,
    last_seen: Instant,
    /// `None` until the first sighting has been reported.
    last_report: Option<Instant>,
    /// Weakest reading since the last report; `None` once reported, so a sighting that stopped
    /// being seen is not reported again.
    pending: Option<Reading>,
    /// Reading of the last report, kept for [`Proximity::state`] after `pending` is cleared.
    reported: Option<Reading>,
    message: u16,
}

impl Sighting {
    fn weakest_power(&self) -> u8 {
        match (self.pending, self.reported) {
            (Some(p), Some(r)) => p.power.min(r.power),
            (Some(x), None) | (None, Some(x)) => x.power,
            (None, None) => 0,
        }
    }
}

/// Proximity sensing state: transmit cycle position and the table of current sightings.
#[derive(Clone, Debug)]
pub struct Proximity {
    slot: u8,
    sightings: Vec<Sighting, MAX_SIGHTINGS>,
    /// The weakest power of our own light seen back on each side (front, rear; 0 none) in the
    /// transmit cycle under way, and in the one before it.
    reflections: [[u8; 2]; 2],
    last_robot: Option<(u16, Side, u8)>,
    encounters: u16,
}

impl Default for Proximity {
    fn default() -> Self {
        Self::new()
    }
}

impl Proximity {
    /// Nothing transmitted or seen yet.
    pub const fn new() -> Self {
        Self {
            slot: 0,
            sightings: Vec::new(),
            reflections: [[0; 2]; 2],
            last_robot: None,
            encounters: 0,
        }
    }

    /// Next slot of the transmit cycle over LEDs × power levels (weakest power first for each
    /// LED): returns (led, power, frame) for the board's
    /// [`IrTransmitter`](crate::hal::IrTransmitter).
    ///
    /// LEDs are 0-based, power levels 1-based. The counts are clamped to the sizes of the
    /// settings' angle and range tables, and a count of 0 is taken as 1 so the robot stays
    /// visible to others whatever the host wrote.
    pub fn next_transmission(
        &mut self,
        robot_id: u16,
        message: u16,
        settings: &ProximitySettings,
    ) -> (u8, u8, IrFrame) {
        let leds = led_count(settings);
        let powers = power_levels(settings);
        // The modulo keeps the cycle valid when the host shrinks the counts mid-cycle.
        let slot = self.slot % (leds * powers);
        self.slot = (slot + 1) % (leds * powers);
        if slot == 0 {
            self.reflections = [[0; 2], self.reflections[0]];
        }
        let led = slot / powers;
        let power = slot % powers + 1;
        let frame = IrFrame {
            robot_id,
            led,
            power,
            message,
        };
        (led, power, frame)
    }

    /// A frame received on `side`.
    ///
    /// Frames carrying `own_id` are reflections of our own light off an obstacle. A frame with
    /// power level 0 cannot come from a transmitter (levels start at 1) and is ignored.
    pub fn on_frame(&mut self, now: Instant, side: Side, frame: IrFrame, own_id: u16) {
        if frame.power == 0 {
            return;
        }
        let reading = Reading {
            power: frame.power,
            led: frame.led,
        };
        let obstacle = frame.robot_id == own_id;
        if obstacle {
            let seen = &mut self.reflections[0][side as usize];
            if *seen == 0 || frame.power < *seen {
                *seen = frame.power;
            }
        }
        if let Some(s) = self
            .sightings
            .iter_mut()
            .find(|s| s.robot_id == frame.robot_id && s.side == side)
        {
            s.obstacle = obstacle;
            s.last_seen = s.last_seen.max(now);
            s.pending = Some(Reading::weakest(s.pending, reading));
            s.message = frame.message;
            return;
        }
        if self.sightings.is_full() {
            if let Some(oldest) =
                (0..self.sightings.len()).min_by_key(|&i| self.sightings[i].last_seen)
            {
                self.sightings.swap_remove(oldest);
            }
        }
        // Cannot fail: a slot was freed above if the table was full.
        let _ = self.sightings.push(Sighting {
            robot_id: frame.robot_id,
            side,
            obstacle,
            last_seen: now,
            last_report: None,
            pending: Some(reading),
            reported: None,
            message: frame.message,
        });
    }

    /// Events due now: first sighting of a robot/obstacle on a side is reported at once; while it
    /// keeps being seen it is reported again at most every report_period_ms with the weakest
    /// power seen in that period; sightings older than 2 report periods are forgotten (so
    /// obstacle state returns to 0).
    ///
    /// Returns one event per call; call until `None`. Forgetting happens here because this is the
    /// only entry point that knows both the time and the period.
    pub fn poll_event(
        &mut self,
        now: Instant,
        settings: &ProximitySettings,
    ) -> Option<ProximityEvent> {
        let period = Duration::from_millis(u64::from(settings.report_period_ms));
        let forget_after = period + period;
        // A first sighting is kept until reported even when stale, so a robot that passed by
        // while events were not polled is still announced once.
        self.sightings
            .retain(|s| s.last_report.is_none() || now.since(s.last_seen) <= forget_after);

        let index = self
            .sightings
            .iter()
            .enumerate()
            .filter(|(_, s)| s.last_report.is_none())
            .min_by_key(|(_, s)| s.last_seen)
            .or_else(|| {
                self.sightings
                    .iter()
                    .enumerate()
                    .filter(|(_, s)| match s.last_report {
                        Some(at) => s.pending.is_some() && now.since(at) >= period,
                        None => false,
                    })
                    .min_by_key(|(_, s)| s.last_report)
            })
            .map(|(i, _)| i)?;

        let s = &mut self.sightings[index];
        let first = s.last_report.is_none();
        let reading = s.pending.take()?;
        s.reported = Some(reading);
        s.last_report = Some(now);
        let side = s.side;
        if s.obstacle {
            return Some(ProximityEvent::Obstacle(Obstacle {
                at_ms: 0,
                seq: 0,
                side: side as u8,
                power_level: reading.power,
                led: reading.led,
            }));
        }
        let (robot_id, message) = (s.robot_id, s.message);
        if first {
            self.encounters = self.encounters.wrapping_add(1);
        }
        self.last_robot = Some((robot_id, side, reading.power));
        Some(ProximityEvent::Robot(RobotEncountered {
            at_ms: 0,
            seq: 0,
            robot_id,
            side: side as u8,
            led: reading.led,
            power_level: reading.power,
            relative_heading_deg: relative_heading(side, reading.led, settings),
            range_mm: range(reading.power, settings),
            message,
        }))
    }

    /// The weakest power at which our own light came back on `side` within the last whole
    /// transmit cycle (0: none): what stands there now. [`Proximity::state`]'s obstacles are
    /// remembered for the event reports' two periods, a second by default, which after a turn
    /// away still show what stood ahead before it.
    pub fn reflection(&self, side: Side) -> u8 {
        let [now, before] = self.reflections;
        match (now[side as usize], before[side as usize]) {
            (0, x) | (x, 0) => x,
            (a, b) => a.min(b),
        }
    }

    /// Summary for RobotState.proximity (front/rear obstacle = weakest power of a current
    /// reflection, 0 = none; last robot; encounter count).
    ///
    /// "Current" is since the start of the last reported period, up to the moment
    /// [`poll_event`](Self::poll_event) forgets the sighting. `encounters` counts first sightings
    /// reported, so a robot that stays in view counts once.
    pub fn state(&self) -> ProximityState {
        let obstacle = |side: Side| {
            self.sightings
                .iter()
                .filter(|s| s.obstacle && s.side == side)
                .map(Sighting::weakest_power)
                .filter(|&p| p != 0)
                .min()
                .unwrap_or(0)
        };
        let (last_robot_id, last_robot_side, last_robot_power) = match self.last_robot {
            Some((id, side, power)) => (id, side as u8, power),
            None => (0, 0, 0),
        };
        ProximityState {
            front_obstacle: obstacle(Side::Front),
            rear_obstacle: obstacle(Side::Rear),
            last_robot_id,
            last_robot_side,
            last_robot_power,
            encounters: self.encounters,
        }
    }
}

fn led_count(settings: &ProximitySettings) -> u8 {
    let table = settings.led_angle_deg;
    settings.led_count.clamp(1, table.len() as u8)
}

fn power_levels(settings: &ProximitySettings) -> u8 {
    let table = settings.range_mm;
    settings.power_levels.clamp(1, table.len() as u8)
}

/// Our receiver at bearing `b` sees the other robot's LED pointing back at us, i.e. along
/// `b + 180` in our frame and along `a` in its own, so its heading in ours is `b + 180 − a`.
fn relative_heading(side: Side, led: u8, settings: &ProximitySettings) -> i16 {
    let angles = settings.led_angle_deg;
    let a = i32::from(angles[usize::from(led).min(angles.len() - 1)]);
    let b = match side {
        Side::Front => 0,
        Side::Rear => 180,
    };
    let h = (b + 180 - a).rem_euclid(360);
    (if h > 180 { h - 360 } else { h }) as i16
}

fn range(power: u8, settings: &ProximitySettings) -> u16 {
    let ranges = settings.range_mm;
    ranges[usize::from(power.max(1) - 1).min(ranges.len() - 1)]
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use protocol::settings::Settings;
    use std::collections::HashSet;

    const ME: u16 = 1;

    fn settings() -> ProximitySettings {
        Settings::default().proximity
    }

    fn ms(t: u64) -> Instant {
        Instant::from_millis(t)
    }

    fn frame(robot_id: u16, led: u8, power: u8) -> IrFrame {
        IrFrame {
            robot_id,
            led,
            power,
            message: 0,
        }
    }

    fn drain(
        p: &mut Proximity,
        now: Instant,
        s: &ProximitySettings,
    ) -> std::vec::Vec<ProximityEvent> {
        core::iter::from_fn(|| p.poll_event(now, s)).collect()
    }

    fn robot(e: ProximityEvent) -> RobotEncountered {
        match e {
            ProximityEvent::Robot(r) => r,
            other => panic!("expected a robot, got {other:?}"),
        }
    }

    #[test]
    fn transmit_cycle_visits_every_pair_once_weakest_power_first() {
        for (leds, powers) in [(6u8, 4u8), (2, 3), (1, 1)] {
            let mut s = settings();
            s.led_count = leds;
            s.power_levels = powers;
            let n = usize::from(leds) * usize::from(powers);
            let mut p = Proximity::new();
            let first: std::vec::Vec<(u8, u8)> = (0..n)
                .map(|_| {
                    let (led, power, f) = p.next_transmission(7, 0xBEEF, &s);
                    assert_eq!(
                        f,
                        IrFrame {
                            robot_id: 7,
                            led,
                            power,
                            message: 0xBEEF
                        }
                    );
                    (led, power)
                })
                .collect();
            let distinct: HashSet<_> = first.iter().copied().collect();
            let expected: HashSet<_> = (0..leds)
                .flat_map(|l| (1..=powers).map(move |w| (l, w)))
                .collect();
            assert_eq!(distinct, expected, "{leds}×{powers}");
            assert_eq!(
                first.len(),
                distinct.len(),
                "a pair repeated within one cycle"
            );
            for chunk in first.chunks(usize::from(powers)) {
                let order: std::vec::Vec<u8> = chunk.iter().map(|&(_, w)| w).collect();
                assert_eq!(
                    order,
                    (1..=powers).collect::<std::vec::Vec<_>>(),
                    "weakest first"
                );
                assert!(
                    chunk.iter().all(|&(l, _)| l == chunk[0].0),
                    "one LED per power sweep"
                );
            }
            let second: std::vec::Vec<(u8, u8)> = (0..n)
                .map(|_| {
                    let (l, w, _) = p.next_transmission(7, 0, &s);
                    (l, w)
                })
                .collect();
            assert_eq!(first, second, "the next cycle starts over");
        }
    }

    #[test]
    fn robots_facing_each_other_read_opposite_heading() {
        let s = settings();
        let mut p = Proximity::new();
        p.on_frame(ms(10), Side::Front, frame(2, 1, 3), ME);
        let r = robot(p.poll_event(ms(10), &s).unwrap());
        assert_eq!({ r.relative_heading_deg }, 180);
        assert_eq!(
            (r.robot_id, r.side, r.led, r.power_level),
            (2, Side::Front as u8, 1, 3)
        );
    }

    #[test]
    fn robot_behind_seen_from_its_front_led_heads_our_way() {
        let s = settings();
        let mut p = Proximity::new();
        p.on_frame(ms(10), Side::Rear, frame(2, 1, 2), ME);
        let r = robot(p.poll_event(ms(10), &s).unwrap());
        assert_eq!({ r.relative_heading_deg }, 0);
        assert_eq!({ r.side }, Side::Rear as u8);
    }

    #[test]
    fn heading_is_normalised_into_half_open_circle() {
        let s = settings();
        // Front receiver, its LED 0 (+30°): 0 + 180 − 30 = 150.
        assert_eq!(relative_heading(Side::Front, 0, &s), 150);
        // Rear receiver, its LED 0 (+30°): 330 → −30.
        assert_eq!(relative_heading(Side::Rear, 0, &s), -30);
        // Front receiver, its rear LED 4 (180°): it drives ahead of us the same way.
        assert_eq!(relative_heading(Side::Front, 4, &s), 0);
        // Front receiver, its LED 5 (−150°): 330 → −30.
        assert_eq!(relative_heading(Side::Front, 5, &s), -30);
        let mut odd = s;
        odd.led_angle_deg = [i16::MIN, i16::MAX, 0, 0, 0, 0];
        for side in [Side::Front, Side::Rear] {
            for led in [0, 1, 200] {
                let h = relative_heading(side, led, &odd);
                assert!(h > -180 && h <= 180, "{h}");
            }
        }
    }

    #[test]
    fn range_follows_weakest_power_with_clamped_index() {
        let s = settings();
        let mut p = Proximity::new();
        p.on_frame(ms(0), Side::Front, frame(2, 0, 2), ME);
        assert_eq!({ robot(p.poll_event(ms(0), &s).unwrap()).range_mm }, 60);
        assert_eq!(range(1, &s), 30);
        assert_eq!(range(4, &s), 150);
        assert_eq!(range(9, &s), 150);
    }

    #[test]
    fn first_sighting_at_once_then_at_most_every_period_with_weakest_power() {
        let s = settings(); // 500 ms
        let mut p = Proximity::new();
        let mut with_msg = frame(2, 1, 3);
        with_msg.message = 42;
        p.on_frame(ms(100), Side::Front, with_msg, ME);
        let r = robot(p.poll_event(ms(100), &s).unwrap());
        assert_eq!((r.power_level, r.message), (3, 42));
        assert_eq!(p.poll_event(ms(100), &s), None, "reported once");

        p.on_frame(ms(200), Side::Front, frame(2, 1, 4), ME);
        p.on_frame(ms(300), Side::Front, frame(2, 2, 1), ME);
        p.on_frame(ms(400), Side::Front, frame(2, 1, 2), ME);
        assert_eq!(p.poll_event(ms(599), &s), None, "not before the period");
        let r = robot(p.poll_event(ms(600), &s).unwrap());
        assert_eq!(
            (r.power_level, r.led, r.range_mm),
            (1, 2, 30),
            "weakest in the period wins"
        );
        assert_eq!(p.poll_event(ms(600), &s), None);

        // Not seen during the next period: no repeat.
        assert_eq!(p.poll_event(ms(1_100), &s), None);
        assert_eq!(
            { p.state().encounters },
            1,
            "a robot staying in view counts once"
        );
    }

    #[test]
    fn own_frame_is_an_obstacle_not_a_robot() {
        let s = settings();
        let mut p = Proximity::new();
        p.on_frame(ms(5), Side::Rear, frame(ME, 4, 2), ME);
        assert_eq!(
            p.poll_event(ms(5), &s),
            Some(ProximityEvent::Obstacle(Obstacle {
                at_ms: 0,
                seq: 0,
                side: Side::Rear as u8,
                power_level: 2,
                led: 4,
            }))
        );
        let st = p.state();
        assert_eq!((st.front_obstacle, st.rear_obstacle), (0, 2));
        assert_eq!({ st.last_robot_id }, 0);
        assert_eq!({ st.encounters }, 0);
    }

    #[test]
    fn a_reflection_is_current_for_one_whole_transmit_cycle_not_the_reports_two_periods() {
        let s = settings();
        let cycle = usize::from(s.led_count) * usize::from(s.power_levels);
        let mut p = Proximity::new();
        let transmit = |p: &mut Proximity, n: usize| {
            for _ in 0..n {
                p.next_transmission(ME, 0, &s);
            }
        };
        transmit(&mut p, 3);
        p.on_frame(ms(10), Side::Front, frame(ME, 1, 2), ME);
        p.on_frame(ms(11), Side::Front, frame(ME, 0, 1), ME);
        p.on_frame(ms(12), Side::Front, frame(7, 0, 1), ME);
        assert!(p.poll_event(ms(12), &s).is_some());
        assert_eq!(
            p.reflection(Side::Front),
            1,
            "the weakest of our own frames"
        );
        assert_eq!(p.reflection(Side::Rear), 0);
        // The rest of this cycle and the whole next one: still what stands there.
        transmit(&mut p, cycle - 3 + cycle);
        assert_eq!(p.reflection(Side::Front), 1);
        // Two cycles on with nothing seen: gone, while the reports still remember it.
        transmit(&mut p, 1);
        assert_eq!(p.reflection(Side::Front), 0);
        assert_eq!({ p.state().front_obstacle }, 1);
        // Another robot's light is no reflection.
        p.on_frame(ms(300), Side::Front, frame(7, 0, 1), ME);
        assert_eq!(p.reflection(Side::Front), 0);
    }

    #[test]
    fn sightings_are_forgotten_after_two_periods() {
        let s = settings();
        let mut p = Proximity::new();
        p.on_frame(ms(0), Side::Front, frame(ME, 1, 3), ME);
        p.on_frame(ms(0), Side::Rear, frame(2, 1, 3), ME);
        assert_eq!(drain(&mut p, ms(0), &s).len(), 2);
        assert_eq!({ p.state().front_obstacle }, 3);
        assert!(drain(&mut p, ms(1_000), &s).is_empty());
        assert_eq!(
            { p.state().front_obstacle },
            3,
            "exactly two periods is still current"
        );
        assert!(drain(&mut p, ms(1_001), &s).is_empty());
        assert_eq!({ p.state().front_obstacle }, 0);
        assert_eq!(p.sightings.len(), 0);

        // After being forgotten it is a new encounter, reported at once.
        p.on_frame(ms(1_100), Side::Rear, frame(2, 1, 3), ME);
        assert_eq!(drain(&mut p, ms(1_100), &s).len(), 1);
        assert_eq!({ p.state().encounters }, 2);
    }

    #[test]
    fn more_than_eight_robots_keep_the_newest() {
        let s = settings();
        let mut p = Proximity::new();
        for id in 10..22u16 {
            p.on_frame(ms(u64::from(id)), Side::Front, frame(id, 0, 1), ME);
        }
        let ids: HashSet<u16> = drain(&mut p, ms(30), &s)
            .into_iter()
            .map(|e| robot(e).robot_id)
            .collect();
        assert_eq!(ids, (14..22).collect());
        assert_eq!(
            { p.state().last_robot_id },
            21,
            "oldest sighting reported first, newest last"
        );
    }

    #[test]
    fn eviction_keeps_a_robot_that_is_still_seen() {
        let s = settings();
        let mut p = Proximity::new();
        for id in 10..18u16 {
            p.on_frame(ms(u64::from(id)), Side::Front, frame(id, 0, 1), ME);
        }
        p.on_frame(ms(20), Side::Front, frame(10, 0, 1), ME);
        p.on_frame(ms(21), Side::Front, frame(99, 0, 1), ME);
        let ids: HashSet<u16> = drain(&mut p, ms(21), &s)
            .into_iter()
            .map(|e| robot(e).robot_id)
            .collect();
        assert!(
            ids.contains(&10) && ids.contains(&99) && !ids.contains(&11),
            "{ids:?}"
        );
    }

    #[test]
    fn zero_and_odd_settings_do_not_panic() {
        let mut s = settings();
        s.led_count = 0;
        s.power_levels = 0;
        s.report_period_ms = 0;
        let mut p = Proximity::new();
        let (led, power, _) = p.next_transmission(ME, 0, &s);
        assert_eq!((led, power), (0, 1));
        s.led_count = 255;
        s.power_levels = 255;
        for _ in 0..100 {
            let (led, power, _) = p.next_transmission(ME, 0, &s);
            assert!(led < 6 && (1..=4).contains(&power));
        }
        p.on_frame(ms(1), Side::Front, frame(3, 255, 255), ME);
        p.on_frame(ms(1), Side::Front, frame(4, 0, 0), ME);
        let r = robot(p.poll_event(ms(1), &s).unwrap());
        assert_eq!({ r.range_mm }, 150);
        assert_eq!(p.poll_event(ms(1), &s), None, "power 0 frames are ignored");
        p.on_frame(ms(2), Side::Front, frame(3, 1, 1), ME);
        assert!(
            p.poll_event(ms(2), &s).is_some(),
            "period 0 reports every new sighting"
        );
        assert!(drain(&mut p, ms(3), &s).is_empty());
        assert_eq!(p.sightings.len(), 0);
    }

    proptest! {
        #[test]
        fn arbitrary_settings_and_frames_never_panic(
            led_count in any::<u8>(),
            power_levels in any::<u8>(),
            led_angle_deg in any::<[i16; 6]>(),
            range_mm in any::<[u16; 4]>(),
            report_period_ms in any::<u16>(),
            frames in proptest::collection::vec(
                (0u64..5_000, any::<bool>(), 0u16..12, any::<u8>(), any::<u8>(), any::<u16>()),
                0..64,
            ),
        ) {
            let s = ProximitySettings {
                led_count,
                power_levels,
                led_angle_deg,
                range_mm,
                report_period_ms,
            };
            let mut p = Proximity::new();
            let mut now = 0;
            for (dt, rear, id, led, power, message) in frames {
                now += dt;
                let (l, w, _) = p.next_transmission(ME, message, &s);
                prop_assert!(usize::from(l) < 6 && (1..=4).contains(&w));
                let side = if rear { Side::Rear } else { Side::Front };
                p.on_frame(ms(now), side, IrFrame { robot_id: id, led, power, message }, ME);
                prop_assert!(p.sightings.len() <= MAX_SIGHTINGS);
                while let Some(e) = p.poll_event(ms(now), &s) {
                    if let ProximityEvent::Robot(r) = e {
                        let h = r.relative_heading_deg;
                        prop_assert!(h > -180 && h <= 180);
                    }
                }
                let _ = p.state();
            }
        }
    }
}
