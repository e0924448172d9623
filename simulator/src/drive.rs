//! The drive train of one wheel: DC motor with back-EMF and friction driven by PWM from the battery,
//! the wheel's encoder stripes, and the tyre's grip on the floor.
//!
//! The motor integrates implicitly in its linear terms (stable at any step), dry friction holds a
//! wheel whose drive torque cannot beat it, and the tyre transmits at most μ·N: a wheel asked for
//! more spins.

use crate::spec::{MotorSpec, RobotSpec};

/// State of one wheel.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct WheelState {
    /// Angular speed, rad/s (positive drives the robot forward).
    pub omega: f64,
    /// Angle turned since start, radians.
    pub angle: f64,
    /// Current through the motor last step, amperes (signed).
    pub current_a: f64,
    /// Two neighbouring encoder edge angles around `angle`, as [`advance`](Self::advance)
    /// works them out: a step that stays between them crosses no edge, which is most steps.
    /// (0, 0) until known.
    between: (f64, f64),
}

impl WheelState {
    /// Integrates the motor for `dt` at `duty` (−1..1) from a battery at `volts`, before the tyre
    /// acts; the tyre's impulse then slows it by radius / inertia per unit.
    pub fn drive(&mut self, m: &MotorSpec, duty: f64, volts: f64, dt: f64) {
        self.drive_with(m, &MotorStep::new(m, duty, volts, dt));
    }

    /// [`drive`](Self::drive) with the step's constants worked out once, for a physics step that
    /// drives the wheel over several clock steps at one duty.
    pub fn drive_with(&mut self, m: &MotorSpec, p: &MotorStep) {
        let free = (self.omega + p.drive_dv) * p.damping_inv;
        self.omega = if free.abs() <= p.coulomb_dv {
            // Dry friction holds the wheel (or stops it within this step).
            0.0
        } else {
            free - p.coulomb_dv * free.signum()
        };
        self.current_a = (p.volts - m.k_t * self.omega) / m.resistance_ohm;
    }

    /// The wheel is blocked: it does not turn, and the motor draws the stall current of `duty`
    /// from a battery at `volts`.
    pub fn jam(&mut self, m: &MotorSpec, duty: f64, volts: f64) {
        self.omega = 0.0;
        self.current_a = volts * duty.clamp(-1.0, 1.0) / m.resistance_ohm;
    }

    /// Rim speed, m/s.
    pub fn rim_speed(&self, radius: f64) -> f64 {
        self.omega * radius
    }

    /// Advances the angle by the step's rotation and reports each encoder edge crossed as the
    /// fraction of the step at which it happened.
    pub fn advance(
        &mut self,
        spec: &RobotSpec,
        omega_start: f64,
        dt: f64,
        mut edge: impl FnMut(f64),
    ) {
        let start = self.angle;
        let end = start + 0.5 * (omega_start + self.omega) * dt;
        self.angle = end;
        if end == start {
            return;
        }
        let (lo, hi) = if end > start {
            (start, end)
        } else {
            (end, start)
        };
        // No edge lies strictly between two neighbouring ones.
        if self.between.0 <= lo && hi < self.between.1 {
            return;
        }
        let pair = 2.0 * std::f64::consts::TAU / f64::from(spec.encoder_edges_per_rev.max(2));
        let black = pair * spec.encoder_black_fraction.clamp(0.05, 0.95);
        // Edges sit at k·pair and k·pair + black for every whole k; those of a k below lo's are
        // below lo, since black is at most 0.95 of a pair.
        let mut k = (lo / pair).floor();
        while k * pair <= hi {
            for pos in [k * pair, k * pair + black] {
                if pos > lo && pos <= hi {
                    edge(((pos - start) / (end - start)).clamp(0.0, 1.0));
                }
            }
            k += 1.0;
        }
        // The edges around the new angle, computed as the loop above computes them.
        let k = (end / pair).floor();
        let around = [
            (k - 1.0) * pair + black,
            k * pair,
            k * pair + black,
            (k + 1.0) * pair,
            (k + 1.0) * pair + black,
        ];
        self.between = around
            .windows(2)
            .find(|w| w[0] <= end && end < w[1])
            .map_or((0.0, 0.0), |w| (w[0], w[1]));
    }
}

/// What one clock step of a motor at one duty and battery voltage adds, worked out once.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotorStep {
    /// Voltage across the motor, volts (signed).
    volts: f64,
    /// Speed the drive torque adds over the step before damping, rad/s.
    drive_dv: f64,
    /// The implicit step's factor, 1 / (1 + dt·damping / inertia).
    damping_inv: f64,
    /// Speed dry friction takes over the step, rad/s.
    coulomb_dv: f64,
}

impl MotorStep {
    /// The constants of a step of `dt` at `duty` (−1..1) from a battery at `volts`.
    pub fn new(m: &MotorSpec, duty: f64, volts: f64, dt: f64) -> Self {
        let v = volts * duty.clamp(-1.0, 1.0);
        // τ = k_t·(v − k_t·ω)/R − b·ω − τ_c·sign(ω): implicit in ω for the linear part.
        let damping = m.k_t * m.k_t / m.resistance_ohm + m.viscous;
        let drive = m.k_t * v / m.resistance_ohm;
        Self {
            volts: v,
            drive_dv: dt / m.inertia * drive,
            damping_inv: 1.0 / (1.0 + dt / m.inertia * damping),
            coulomb_dv: m.coulomb_nm * dt / m.inertia,
        }
    }
}

/// Inverse effective mass of a rigid body at a point offset `r` from its centre, along unit `n`.
pub fn inverse_mass_along(mass: f64, inertia: f64, r: [f64; 2], n: [f64; 2]) -> f64 {
    let cross = r[0] * n[1] - r[1] * n[0];
    1.0 / mass + cross * cross / inertia
}

#[cfg(test)]
mod tests {
    use super::*;

    fn free_speed(volts: f64, duty: f64) -> f64 {
        let spec = RobotSpec::default();
        let mut w = WheelState::default();
        for _ in 0..2000 {
            w.drive(&spec.motor, duty, volts, 0.001);
        }
        w.rim_speed(spec.wheel_radius_m())
    }

    #[test]
    fn speed_saturates_and_follows_the_battery() {
        let full = free_speed(4.1, 1.0);
        assert!((0.45..0.75).contains(&full), "free speed {full}");
        let sagging = free_speed(3.5, 1.0);
        assert!(sagging < full * 0.9, "{sagging} vs {full}");
        let half = free_speed(4.1, 0.5);
        assert!(half < full * 0.55 && half > full * 0.35, "{half}");
        assert_eq!(
            free_speed(4.1, 0.02),
            0.0,
            "dry friction holds a wheel at tiny duty"
        );
        assert!(free_speed(4.1, -1.0) < -0.45);
    }

    #[test]
    fn mechanical_time_constant_is_tens_of_ms() {
        let spec = RobotSpec::default();
        let mut w = WheelState::default();
        let full = free_speed(4.1, 1.0);
        let mut t = 0;
        while w.rim_speed(spec.wheel_radius_m()) < 0.632 * full {
            w.drive(&spec.motor, 1.0, 4.1, 0.001);
            t += 1;
        }
        assert!((10..40).contains(&t), "{t} ms");
    }

    #[test]
    fn a_wheel_going_back_and_forth_reports_every_edge_it_crosses_and_no_other() {
        // Every edge between the start and end angle of each step, found by listing all edges of
        // the turns the walk covers.
        let spec = RobotSpec::default();
        let pair = 2.0 * std::f64::consts::TAU / f64::from(spec.encoder_edges_per_rev);
        let black = pair * spec.encoder_black_fraction;
        let mut w = WheelState::default();
        let (mut reported, mut expected) = (0usize, 0usize);
        for i in 0..20_000u32 {
            // Speeds that wander across zero, with steps that end on an edge now and then.
            let o = w.omega;
            w.omega = 30.0 * (f64::from(i) * 0.0031).sin() + 3.0 * (f64::from(i) * 0.7).cos();
            let before = w.angle;
            let mut fracs = Vec::new();
            w.advance(&spec, o, 1e-3, |f| fracs.push(f));
            let (lo, hi) = (before.min(w.angle), before.max(w.angle));
            let crossed = (-400..400)
                .flat_map(|k| [f64::from(k) * pair, f64::from(k) * pair + black])
                .filter(|&e| e > lo && e <= hi)
                .count();
            assert_eq!(fracs.len(), crossed, "step {i}: {before} -> {}", w.angle);
            assert!(fracs.iter().all(|f| (0.0..=1.0).contains(f)));
            reported += fracs.len();
            expected += crossed;
        }
        assert_eq!(reported, expected);
        assert!(
            reported > 1000,
            "the walk must cross many edges: {reported}"
        );
    }

    #[test]
    fn edges_alternate_narrow_and_wide_and_count_forty_per_turn() {
        let spec = RobotSpec::default();
        let mut w = WheelState {
            omega: 10.0,
            ..Default::default()
        };
        let mut times = Vec::new();
        let mut t = 0.0;
        let dt = 1e-4;
        while w.angle < std::f64::consts::TAU - 1e-9 {
            let o = w.omega;
            w.advance(&spec, o, dt, |f| times.push(t + f * dt));
            t += dt;
        }
        assert_eq!(times.len(), 40);
        let p: Vec<f64> = times.windows(2).map(|w| w[1] - w[0]).collect();
        assert!(
            (p[1] / p[2] - 1.5).abs() < 0.05 || (p[2] / p[1] - 1.5).abs() < 0.05,
            "{p:?}"
        );
    }
}
