//! One robot's drive train over a physics step: motors, tyres gripping or slipping, encoder
//! edges, and the battery's drain.

use firmware::hal::{EncoderEdge, Wheel};
use firmware::Instant;
use rapier2d::prelude::*;

use super::{BodyFault, SimRobot, GRAVITY};
use crate::drive::{inverse_mass_along, MotorStep, WheelState};
use crate::spec::RobotSpec;

/// What the drive train did to one robot's body over a physics step.
#[derive(Clone, Copy, Debug)]
pub(super) struct Drive {
    /// Linear and angular velocity rapier moves the body with over the step: the sub-steps'
    /// displacement divided by the step's length.
    pub(super) set: ([f64; 2], f64),
    /// Velocity the sub-steps ended with, for the body once rapier has stepped.
    pub(super) end: ([f64; 2], f64),
}

/// Motors, tyres and encoders of one robot over a physics step of `substeps` clock steps of
/// `dt` each, starting at `t0`.
///
/// The drive train is integrated on the clock step whatever the physics rate: between contacts a
/// robot's body moves only as its tyres push it, so the sub-steps carry its heading and position
/// forward themselves and hand rapier the step's displacement as a velocity. A coarser physics
/// step then coarsens only the contacts, not the coupling of motor, wheel and body.
pub(super) fn drive_robot(
    spec: &RobotSpec,
    r: &mut SimRobot,
    body: &RigidBody,
    t0: u64,
    dt: f64,
    substeps: u32,
) -> Drive {
    let pwm = r.firmware.board().pwm;
    let step = dt * f64::from(substeps);
    let v_body = [f64::from(body.linvel().x), f64::from(body.linvel().y)];
    let w_body = f64::from(body.angvel());
    let still = |w: &WheelState| w.omega == 0.0 && w.current_a == 0.0;
    if pwm == (0, 0)
        && r.wheels.iter().all(still)
        && v_body == [0.0; 2]
        && w_body == 0.0
        && r.shove.is_none()
    {
        // At rest with the motors off nothing turns, pushes or draws current: the step would
        // compute zeros. Only the battery's idle drain goes on.
        drain_battery(spec, r, pwm, step);
        return Drive {
            set: (v_body, w_body),
            end: (v_body, w_body),
        };
    }
    let volts = f64::from(r.firmware.board().battery_mv) / 1000.0;
    let mass = f64::from(body.mass());
    let inertia = f64::from(body.mass_properties().effective_angular_inertia());
    let (mut s, mut c) = f64::from(body.rotation().angle()).sin_cos();
    let fixed = DriveStep::new(spec, r, (mass, inertia), (s, c), pwm, volts, dt);
    let mut v = v_body;
    let mut omega = w_body;
    let (mut moved, mut turned) = ([0.0f64; 2], 0.0f64);
    for k in 0..substeps {
        if k > 0 {
            // Turned by the last sub-step's δ = ω·dt, at most a few degrees: the series is exact
            // to 1e-9 there.
            let d = omega * dt;
            let d2 = d * d;
            let (sd, cd) = (d * (1.0 - d2 / 6.0), 1.0 - d2 * 0.5 * (1.0 - d2 / 12.0));
            (s, c) = (s * cd + c * sd, c * cd - s * sd);
        }
        let t = t0 as f64 * 1e-9 + f64::from(k) * dt;
        (v, omega) = fixed.substep(r, (s, c), (v, omega), t);
        // A hand moving the body sets its velocity whatever the tyres did; they dragged meanwhile.
        if let Some(hand) = r.shove.and_then(|h| h.velocity(t + dt)) {
            (v, omega) = hand;
        }
        // As rapier integrates: the new velocity over the whole sub-step.
        moved[0] += v[0] * dt;
        moved[1] += v[1] * dt;
        turned += omega * dt;
    }
    drain_battery(spec, r, pwm, step);
    let set = if substeps == 1 {
        (v, omega)
    } else {
        ([moved[0] / step, moved[1] / step], turned / step)
    };
    Drive {
        set,
        end: (v, omega),
    }
}

/// Reciprocals of the inverse effective masses at one wheel's contact patch.
struct InverseMass {
    /// Along the heading, of the body alone.
    long: f64,
    /// Across the heading.
    lat: f64,
    /// Along the heading, of the body and the wheel's rim sharing the impulse.
    shared: f64,
}

/// What stays fixed over a physics step's clock steps of one robot's drive train, with the
/// divisions done once: the sub-steps are chains of dependent operations.
struct DriveStep<'a> {
    spec: &'a RobotSpec,
    radius: f64,
    inv_mass: f64,
    inv_inertia: f64,
    k: [InverseMass; 2],
    /// Wheel speed lost per unit of tyre impulse, radius / wheel inertia.
    tyre_spin: f64,
    /// Largest impulse one tyre transmits in a clock step, μ·m·g/2·dt.
    grip: f64,
    motor: [MotorStep; 2],
    volts: f64,
    pwm: (i16, i16),
    jammed: bool,
    counting: bool,
    dt: f64,
}

impl<'a> DriveStep<'a> {
    /// The fixed part of a physics step for a body of `mass` and `inertia` heading at
    /// `(sin, cos)`, its motors at duties `pwm` from `volts`, over clock steps of `dt`.
    fn new(
        spec: &'a RobotSpec,
        r: &SimRobot,
        (mass, inertia): (f64, f64),
        (s, c): (f64, f64),
        pwm: (i16, i16),
        volts: f64,
        dt: f64,
    ) -> Self {
        // The wheels' effective masses depend on where they sit on the body, not on its heading.
        let arms = [1.0f64, -1.0].map(|side| {
            let half = side * spec.wheel_gauge_m * 0.5;
            [
                c * spec.axle_offset_m - s * half,
                s * spec.axle_offset_m + c * half,
            ]
        });
        let radius = spec.wheel_radius_m();
        let wheel_k = radius * radius / spec.motor.inertia;
        DriveStep {
            spec,
            radius,
            inv_mass: 1.0 / mass,
            inv_inertia: 1.0 / inertia,
            k: arms.map(|arm| {
                let k_long = inverse_mass_along(mass, inertia, arm, [c, s]);
                let k_lat = inverse_mass_along(mass, inertia, arm, [-s, c]);
                InverseMass {
                    long: 1.0 / k_long,
                    lat: 1.0 / k_lat,
                    shared: 1.0 / (k_long + wheel_k),
                }
            }),
            tyre_spin: radius / spec.motor.inertia,
            grip: spec.tyre_friction * mass * GRAVITY * 0.5 * dt,
            motor: [pwm.0, pwm.1]
                .map(|duty| MotorStep::new(&spec.motor, f64::from(duty) / 1000.0, volts, dt)),
            volts,
            pwm,
            jammed: r.fault == Some(BodyFault::JammedWheels),
            counting: r.fault != Some(BodyFault::DeadEncoders),
            dt,
        }
    }

    /// One clock step of motors, tyres and encoders from the body's velocity `(v, omega)` with
    /// its heading's `(sin, cos)`, starting at `t0_s`; returns the body's new velocity.
    fn substep(
        &self,
        r: &mut SimRobot,
        (s, c): (f64, f64),
        (mut v, mut omega): ([f64; 2], f64),
        t0_s: f64,
    ) -> ([f64; 2], f64) {
        let spec = self.spec;
        let radius = self.radius;
        let omega_start = [r.wheels[0].omega, r.wheels[1].omega];
        for ((w, duty), motor) in r
            .wheels
            .iter_mut()
            .zip([self.pwm.0, self.pwm.1])
            .zip(&self.motor)
        {
            if self.jammed {
                w.jam(&spec.motor, f64::from(duty) / 1000.0, self.volts);
            } else {
                w.drive_with(&spec.motor, motor);
            }
        }
        let fwd = [c, s];
        let left = [-s, c];
        let grip = self.grip;
        for (k, side) in [(0usize, 1.0f64), (1, -1.0)] {
            let half = side * spec.wheel_gauge_m * 0.5;
            let arm = [
                fwd[0] * spec.axle_offset_m + left[0] * half,
                fwd[1] * spec.axle_offset_m + left[1] * half,
            ];
            let vp = [v[0] - omega * arm[1], v[1] + omega * arm[0]];
            let ground_long = vp[0] * fwd[0] + vp[1] * fwd[1];
            let ground_lat = vp[0] * left[0] + vp[1] * left[1];
            let inv_k = &self.k[k];
            let wheel = &mut r.wheels[k];
            // A blocked wheel is part of the chassis: the tyre brakes the body alone. A turning
            // one is gripped so that the contact point moves with the rim, the impulse shared
            // between the body and the wheel.
            let mut j_long = if self.jammed {
                -ground_long * inv_k.long
            } else {
                (wheel.rim_speed(radius) - ground_long) * inv_k.shared
            };
            let mut j_lat = -ground_lat * inv_k.lat;
            // The tyre transmits at most μ·N: a wheel asked for more slips. Squares compared
            // first, since the tyre holds in nearly every step and needs no root then.
            let total2 = j_long * j_long + j_lat * j_lat;
            if total2 > grip * grip {
                [j_long, j_lat] = slipping([j_long, j_lat], total2, grip);
            }
            if !self.jammed {
                wheel.omega -= j_long * self.tyre_spin;
            }
            let j = [
                fwd[0] * j_long + left[0] * j_lat,
                fwd[1] * j_long + left[1] * j_lat,
            ];
            v[0] += j[0] * self.inv_mass;
            v[1] += j[1] * self.inv_mass;
            omega += (arm[0] * j[1] - arm[1] * j[0]) * self.inv_inertia;
        }
        self.advance_encoders(r, omega_start, t0_s);
        (v, omega)
    }

    /// Turns each wheel's encoder stripes over the clock step from `omega_start`, timestamping
    /// each edge as the capture timer would from `t0_s`, unless the encoders are dead.
    fn advance_encoders(&self, r: &mut SimRobot, omega_start: [f64; 2], t0_s: f64) {
        let spec = self.spec;
        let dt = self.dt;
        let counting = self.counting;
        let board = r.firmware.board_mut();
        for (k, wheel_id) in [(0usize, Wheel::Left), (1, Wheel::Right)] {
            let capture = spec.capture_hz;
            let edges = &mut board.edges;
            r.wheels[k].advance(spec, omega_start[k], dt, |frac| {
                if !counting {
                    return;
                }
                let t = t0_s + frac * dt;
                let ticks = (t * capture).round();
                let at = Instant::from_nanos((ticks / capture * 1e9).round() as u64);
                edges.push_back(EncoderEdge {
                    wheel: wheel_id,
                    at,
                });
            });
        }
    }
}

/// A tyre's impulse `j` (squared length `total2`) cut to the largest it can transmit, `grip`.
///
/// Out of line, so that the compiler branches around the root and the division rather than
/// computing them in every sub-step as a select: they would then stand on the sub-step's chain of
/// dependent operations.
#[cold]
#[inline(never)]
fn slipping(j: [f64; 2], total2: f64, grip: f64) -> [f64; 2] {
    let scale = grip / total2.sqrt();
    [j[0] * scale, j[1] * scale]
}

/// The current the robot draws over the step (idle plus each motor's share of its duty), and
/// the charge it takes from the battery.
fn drain_battery(spec: &RobotSpec, r: &mut SimRobot, pwm: (i16, i16), dt: f64) {
    let motor_a: f64 = r
        .wheels
        .iter()
        .zip([pwm.0, pwm.1])
        .map(|(w, d)| (w.current_a * f64::from(d) / 1000.0).abs())
        .sum();
    r.current_a = spec.battery.idle_a + motor_a;
    r.charge_ah = (r.charge_ah - r.current_a * dt / 3600.0).max(0.0);
}
