//! Stepping the clock: which clock steps run physics, and the physics step itself (drive trains,
//! rapier, the boxes' floor friction, contacts and sensors).

use rapier2d::prelude::*;
use rayon::prelude::*;

use super::drivetrain::{drive_robot, Drive};
use super::{SimRobot, Simulation, GRAVITY, PARALLEL_FROM};

impl Simulation {
    /// Runs `steps` steps.
    pub fn run_steps(&mut self, steps: u64) {
        for _ in 0..steps {
            self.step();
        }
    }

    /// Runs for at least `d` of simulated time.
    pub fn run_for(&mut self, d: std::time::Duration) {
        let end = self.now_ns + d.as_nanos() as u64;
        while self.now_ns < end {
            self.step();
        }
    }

    /// Length of one physics step, nanoseconds.
    pub(super) fn physics_dt_ns(&self) -> u64 {
        self.dt_ns * self.physics_every
    }

    /// Advances the world by one step of the clock.
    pub fn step(&mut self) {
        if self.robots.len() >= PARALLEL_FROM && rayon::current_thread_index().is_none() {
            // One hand-over to the pool per step instead of one per parallel pass: the caller
            // sleeps once, and the passes split between workers that are already awake.
            rayon::scope(|_| self.step_in_pool());
        } else {
            self.step_in_pool();
        }
    }

    fn step_in_pool(&mut self) {
        // Physics starts on the step after the firmware's boot tick and every `physics_every`
        // steps from there, so a duty the main loop sets on its period moves the body at once.
        let k = self.physics_every;
        if (self.now_ns / self.dt_ns) % k == 1 % k {
            self.physics_step();
        }
        self.now_ns += self.dt_ns;
        self.serve_firmware();
    }

    /// Motors, tyres, rapier and box friction over one physics step from now, then the body
    /// sensors at its end.
    fn physics_step(&mut self) {
        let dt = self.physics_dt_ns() as f64 * 1e-9;
        let t0 = self.now_ns;
        self.physics_span = (t0, t0 + self.physics_dt_ns());
        let spec = &self.spec;
        let bodies = &self.bodies;
        let clock_dt = self.dt_ns as f64 * 1e-9;
        let substeps = self.physics_every as u32;
        let drive =
            |r: &mut SimRobot| drive_robot(spec, r, &bodies[r.body], t0, clock_dt, substeps);
        let drives: Vec<Drive> = if self.robots.len() >= PARALLEL_FROM {
            self.robots.par_iter_mut().map(drive).collect()
        } else {
            self.robots.iter_mut().map(drive).collect()
        };
        let end_s = (t0 + self.physics_dt_ns()) as f64 * 1e-9;
        for r in &mut self.robots {
            if r.shove.is_some_and(|h| h.over(end_s)) {
                r.shove = None;
            }
        }
        for (r, d) in self.robots.iter().zip(&drives) {
            let (v, w) = d.set;
            let body = &mut self.bodies[r.body];
            body.set_linvel(vector![v[0] as f32, v[1] as f32], true);
            body.set_angvel(w as f32, true);
        }
        let obstacle_start: Vec<(Vector<Real>, Real)> = self
            .obstacles
            .iter()
            .map(|o| {
                let b = &self.bodies[o.body];
                (*b.translation(), b.rotation().angle())
            })
            .collect();
        self.pipeline.step(
            &vector![0.0, 0.0],
            &self.params,
            &mut self.islands,
            &mut self.broad_phase,
            &mut self.narrow_phase,
            &mut self.bodies,
            &mut self.colliders,
            &mut self.impulse_joints,
            &mut self.multibody_joints,
            &mut self.ccd,
            &(),
            &(),
        );
        if substeps > 1 {
            // Rapier moved each body with the sub-steps' mean velocity; it goes on from their
            // last, with whatever rapier's contacts changed.
            for (r, d) in self.robots.iter().zip(&drives) {
                let body = &mut self.bodies[r.body];
                let (set, end) = (d.set, d.end);
                let v = body.linvel();
                let w = body.angvel();
                body.set_linvel(
                    vector![
                        (end.0[0] + (f64::from(v.x) - set.0[0])) as f32,
                        (end.0[1] + (f64::from(v.y) - set.0[1])) as f32
                    ],
                    true,
                );
                body.set_angvel((end.1 + (f64::from(w) - set.1)) as f32, true);
            }
        }
        self.floor_friction(&obstacle_start, dt);
        self.record_contacts(t0 + self.dt_ns);
        self.read_sensors();
    }

    /// Coulomb floor friction of boxes: removes up to μ·g·dt of speed and redoes the position
    /// update with what is left, so a push weaker than static friction moves nothing.
    fn floor_friction(&mut self, start: &[(Vector<Real>, Real)], dt: f64) {
        for (o, &(p0, a0)) in self.obstacles.iter().zip(start) {
            let b = &mut self.bodies[o.body];
            let v = [f64::from(b.linvel().x), f64::from(b.linvel().y)];
            let speed = v[0].hypot(v[1]);
            let dv = o.friction * GRAVITY * dt;
            let keep = if speed > dv {
                (speed - dv) / speed
            } else {
                0.0
            };
            let v1 = [v[0] * keep, v[1] * keep];
            // Dry friction over the footprint: torque ≈ μ·m·g·r̄ with r̄ about a third of the diagonal.
            let mass = f64::from(b.mass());
            let inertia = f64::from(b.mass_properties().effective_angular_inertia());
            let r_mean = o.half[0].hypot(o.half[1]) * 2.0 / 3.0;
            let dw = if inertia > 0.0 {
                o.friction * mass * GRAVITY * r_mean * dt / inertia
            } else {
                0.0
            };
            let w = f64::from(b.angvel());
            let w1 = if w.abs() > dw {
                w - dw * w.signum()
            } else {
                0.0
            };
            b.set_linvel(vector![v1[0] as f32, v1[1] as f32], true);
            b.set_angvel(w1 as f32, true);
            b.set_translation(
                vector![p0.x + (v1[0] * dt) as f32, p0.y + (v1[1] * dt) as f32],
                true,
            );
            b.set_rotation(Rotation::new(a0 + (w1 * dt) as f32), true);
        }
    }
}
