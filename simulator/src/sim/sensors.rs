//! Reading the sensors off the world: true pose and distance driven, the floor under the line
//! sensor, acceleration, battery and temperature, and the boxes IR beams are traced against.

use nalgebra::Vector2;
use rayon::prelude::*;

use super::{Pose, SimRobot, Simulation, GRAVITY, PARALLEL_FROM};
use crate::ir::Obb;

impl Simulation {
    /// Reads every robot's sensors off the world at the current time.
    pub(super) fn read_sensors(&mut self) {
        let dt = self.physics_dt_ns() as f64 * 1e-9;
        let spec = &self.spec;
        let battery = &spec.battery;
        let bodies = &self.bodies;
        let sense = |r: &mut SimRobot| -> Obb {
            let b = &bodies[r.body];
            let x = f64::from(b.translation().x);
            let y = f64::from(b.translation().y);
            let theta_wrapped = f64::from(b.rotation().angle());
            let dtheta =
                world::wrap_angle(theta_wrapped - r.pose.theta.rem_euclid(std::f64::consts::TAU));
            let (dx, dy) = (x - r.pose.x, y - r.pose.y);
            r.distance_m += (dx * dx + dy * dy).sqrt();
            r.pose = Pose {
                x,
                y,
                theta: r.pose.theta + dtheta,
            };
            let (s, c) = theta_wrapped.sin_cos();
            let vel = Vector2::new(f64::from(b.linvel().x), f64::from(b.linvel().y));
            let acc = (vel - r.last_velocity) / dt;
            r.last_velocity = vel;
            let sensor = [
                x + c * spec.line_sensor_ahead_m,
                y + s * spec.line_sensor_ahead_m,
            ];
            r.sensor_path = [r.sensor_path[1], (sensor, (s, c))];
            let board = r.firmware.board_mut();
            board.place_floor_sensor(sensor, (s, c));
            let to_mg = |a: f64| (a / GRAVITY * 1000.0).clamp(-32000.0, 32000.0) as i16;
            board.accel = [
                to_mg(acc.x * c + acc.y * s),
                to_mg(-acc.x * s + acc.y * c),
                1000,
            ];
            let soc = (r.charge_ah / battery.capacity_ah).clamp(0.0, 1.0);
            let open = battery.empty_v + (battery.full_v - battery.empty_v) * soc;
            let volts = (open - r.current_a * battery.internal_ohm).max(0.0);
            board.battery_mv = (volts * 1000.0) as u16;
            board.current_ma = (r.current_a * 1000.0).min(32000.0) as i16;
            // Self-heating towards 25 °C + 40 °C/A with a one-minute time constant.
            r.temperature_c += (25.0 + 40.0 * r.current_a - r.temperature_c) * dt / 60.0;
            board.temperature_dc = (r.temperature_c * 10.0) as i16;
            Obb::new(
                [x, y],
                [spec.length_m * 0.5, spec.width_m * 0.5],
                theta_wrapped,
            )
        };
        if self.robots.len() >= PARALLEL_FROM {
            self.robots
                .par_iter_mut()
                .map(sense)
                .collect_into_vec(&mut self.robot_boxes);
        } else {
            self.robot_boxes.clear();
            self.robot_boxes.extend(self.robots.iter_mut().map(sense));
        }
        self.obstacle_boxes.clear();
        for o in &self.obstacles {
            let b = &self.bodies[o.body];
            self.obstacle_boxes.push(Obb::new(
                [f64::from(b.translation().x), f64::from(b.translation().y)],
                o.half,
                f64::from(b.rotation().angle()),
            ));
        }
        let arena = &self.world.arena;
        let cell = self.spec.ir_range_m.iter().cloned().fold(0.05, f64::max) + 0.01;
        self.grid.rebuild(
            arena.width_m,
            arena.height_m,
            cell,
            self.robot_boxes.iter().map(|b| b.center),
        );
    }
}
