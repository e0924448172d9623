//! Every physical number of the simulated PocketBot2 in one place, with the thesis's values where it
//! gives them (ch. 8: 48 × 32 mm, ~20 g, 9 mm wheels, 40-pulse encoders, 32 MHz timer). The
//! geometry the host also needs (body, wheels, line sensor, IR layout) comes from
//! [`world::robot`], so the world model and the safety check see the body the physics simulates.

use world::robot;

/// Geometry, mass, drive train, sensors and battery of one PocketBot2.
#[derive(Clone, Debug, PartialEq)]
pub struct RobotSpec {
    /// Body length along the heading, metres.
    pub length_m: f64,
    /// Body width, metres.
    pub width_m: f64,
    /// Mass, kilograms.
    pub mass_kg: f64,
    /// Wheel diameter, metres.
    pub wheel_diameter_m: f64,
    /// Distance between the wheels' contact points (the gauge), metres.
    pub wheel_gauge_m: f64,
    /// Wheel axle position ahead of the body centre, metres.
    pub axle_offset_m: f64,
    /// Tyre–floor Coulomb friction coefficient.
    pub tyre_friction: f64,
    /// Drive train per wheel.
    pub motor: MotorSpec,
    /// Encoder edges per wheel revolution.
    pub encoder_edges_per_rev: u32,
    /// Share of a black+white stripe pair taken by the (narrower) black stripe.
    pub encoder_black_fraction: f64,
    /// Input-capture timer frequency that quantises edge timestamps, Hz.
    pub capture_hz: f64,
    /// Line sensor centre ahead of the body centre, metres.
    pub line_sensor_ahead_m: f64,
    /// Distance between line sensor spots, metres.
    pub spot_pitch_m: f64,
    /// Lit detector reading over a perfect white surface (12-bit ADC counts).
    pub line_gain: f64,
    /// Detector reading per unit of ambient light.
    pub ambient_gain: f64,
    /// Directions of the IR LEDs relative to the heading, degrees (front three, rear three).
    pub ir_led_angle_deg: [f64; 6],
    /// Half-angle of each LED's cone, degrees (thesis 7.1: ±15°).
    pub ir_cone_half_deg: f64,
    /// Reach of each power level to another robot's receiver, metres.
    pub ir_range_m: [f64; 4],
    /// Battery.
    pub battery: BatterySpec,
}

/// DC gear motor and wheel, expressed at the wheel (after the gearbox).
#[derive(Clone, Debug, PartialEq)]
pub struct MotorSpec {
    /// Winding resistance, ohms.
    pub resistance_ohm: f64,
    /// Torque constant at the wheel, N·m/A (equal to the back-EMF constant in V·s/rad).
    pub k_t: f64,
    /// Viscous friction at the wheel, N·m·s/rad.
    pub viscous: f64,
    /// Coulomb (dry) friction torque at the wheel, N·m.
    pub coulomb_nm: f64,
    /// Rotor and wheel inertia reflected to the wheel, kg·m².
    pub inertia: f64,
}

/// Single-cell lithium battery.
#[derive(Clone, Debug, PartialEq)]
pub struct BatterySpec {
    /// Capacity, ampere-hours.
    pub capacity_ah: f64,
    /// Open-circuit voltage when full, volts.
    pub full_v: f64,
    /// Open-circuit voltage when empty, volts.
    pub empty_v: f64,
    /// Internal resistance, ohms (voltage sag under load).
    pub internal_ohm: f64,
    /// Current drawn by the electronics alone, amperes.
    pub idle_a: f64,
    /// State of charge at start, 0..1.
    pub initial_charge: f64,
}

impl Default for RobotSpec {
    fn default() -> Self {
        Self {
            length_m: robot::LENGTH_M,
            width_m: robot::WIDTH_M,
            mass_kg: 0.020,
            wheel_diameter_m: robot::WHEEL_DIAMETER_M,
            wheel_gauge_m: robot::WHEEL_GAUGE_M,
            axle_offset_m: 0.0,
            tyre_friction: 0.8,
            motor: MotorSpec::default(),
            encoder_edges_per_rev: 40,
            encoder_black_fraction: 0.4,
            capture_hz: 32e6,
            line_sensor_ahead_m: robot::LINE_SENSOR_AHEAD_M,
            spot_pitch_m: robot::LINE_SPOT_PITCH_M,
            line_gain: 3000.0,
            ambient_gain: 2000.0,
            ir_led_angle_deg: robot::IR_LED_ANGLE_DEG,
            ir_cone_half_deg: robot::IR_CONE_HALF_DEG,
            ir_range_m: robot::IR_RANGE_M,
            battery: BatterySpec::default(),
        }
    }
}

impl Default for MotorSpec {
    fn default() -> Self {
        // Free speed ≈ 0.6 m/s at 3.9 V; stall torque ≈ 0.6 mN·m per wheel, above what the tyre
        // can transmit (μ·m·g/2 · r ≈ 0.35 mN·m), so a blocked robot spins its wheels; mechanical
        // time constant ≈ 20 ms.
        let k_t = 0.028;
        let resistance_ohm = 180.0;
        Self {
            resistance_ohm,
            k_t,
            viscous: 2.0e-7,
            coulomb_nm: 2.0e-5,
            inertia: 0.02 * k_t * k_t / resistance_ohm,
        }
    }
}

impl Default for BatterySpec {
    fn default() -> Self {
        Self {
            capacity_ah: 0.1,
            full_v: 4.15,
            empty_v: 3.4,
            internal_ohm: 0.6,
            idle_a: 0.025,
            initial_charge: 0.9,
        }
    }
}

impl RobotSpec {
    /// Wheel radius, metres.
    pub fn wheel_radius_m(&self) -> f64 {
        self.wheel_diameter_m * 0.5
    }

    /// Wheel travel between two encoder edges, metres (thesis 11.5: ≈ 0.7 mm).
    pub fn edge_pitch_m(&self) -> f64 {
        std::f64::consts::PI * self.wheel_diameter_m / f64::from(self.encoder_edges_per_rev.max(1))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thesis_numbers() {
        let s = RobotSpec::default();
        // 40 pulses per revolution of a 9 mm wheel: about 14 pulses per centimetre (thesis 8.1.4).
        let per_cm = 0.01 / s.edge_pitch_m();
        assert!((per_cm - 14.1).abs() < 0.2, "{per_cm}");
        assert_eq!((s.length_m, s.width_m, s.mass_kg), (0.048, 0.032, 0.020));
    }

    #[test]
    fn the_firmwares_default_settings_describe_the_simulated_robot() {
        let s = RobotSpec::default();
        let settings = protocol::Settings::default();
        let g = settings.geometry;
        // Copied out: the settings are packed, so their fields cannot be borrowed.
        let (diameter, gauge, ticks) = (g.wheel_diameter_m, g.wheel_gauge_m, g.ticks_per_rev);
        assert_eq!(diameter, s.wheel_diameter_m as f32);
        assert_eq!(gauge, s.wheel_gauge_m as f32);
        assert_eq!(u32::from(ticks), s.encoder_edges_per_rev);
        let pitch_um = settings.line_sensor.spot_pitch_um;
        assert!((f64::from(pitch_um) * 1e-6 - s.spot_pitch_m).abs() < 1e-12);
    }

    #[test]
    fn a_blocked_wheel_out_torques_its_tyre() {
        let s = RobotSpec::default();
        let stall = s.motor.k_t * s.battery.full_v / s.motor.resistance_ohm;
        let grip = s.tyre_friction * s.mass_kg * 9.81 * 0.5 * s.wheel_radius_m();
        assert!(stall > grip * 1.3, "stall {stall} grip {grip}");
    }
}
