//! The factory "EEPROM image": every setting's default value.

use super::{
    BumpSettings, ColourSettings, GeometrySettings, IdentitySettings, LineFollowSettings,
    LineSensorSettings, LocomotionSettings, LogSettings, MotorSettings, PidSettings,
    ProximitySettings, ReflectorSettings, ReflexSettings, SchedulerSettings, Settings,
    SpeedMeterSettings, WatchdogSettings,
};

impl Default for IdentitySettings {
    fn default() -> Self {
        let mut name = [0u8; 12];
        name[..10].copy_from_slice(b"PocketBot2");
        Self { robot_id: 1, name }
    }
}

impl Default for Settings {
    fn default() -> Self {
        Self {
            identity: IdentitySettings::default(),
            geometry: GeometrySettings {
                wheel_diameter_m: 0.009,
                wheel_gauge_m: 0.026,
                ticks_per_rev: 40,
            },
            scheduler: SchedulerSettings {
                main_period_us: 5_000,
                line_period_us: 2_000,
                ir_slot_us: 4_000,
            },
            motor: MotorSettings {
                max_pwm: 1000,
                min_pwm: 60,
            },
            speed_meter: SpeedMeterSettings { timeout_us: 60_000 },
            wheel_pid: PidSettings {
                kp: 2500.0,
                ki: 12000.0,
                kd: 0.0,
                i_limit: 600.0,
                out_limit: 1000.0,
            },
            speed_pid: PidSettings {
                kp: 2500.0,
                ki: 12000.0,
                kd: 0.0,
                i_limit: 600.0,
                out_limit: 1000.0,
            },
            balance_pid: PidSettings {
                kp: 150.0,
                ki: 600.0,
                kd: 0.0,
                i_limit: 0.3,
                out_limit: 0.6,
            },
            line_pid: PidSettings {
                kp: 40.0,
                ki: 0.0,
                kd: 0.6,
                i_limit: 0.0,
                out_limit: 0.4,
            },
            locomotion: LocomotionSettings {
                accel_distance_m: 0.02,
                decel_distance_m: 0.025,
                min_speed_mps: 0.03,
                max_speed_mps: 0.5,
                pwm_per_mps: 1400.0,
                coast_s: 0.06,
            },
            line_sensor: LineSensorSettings {
                white: [3000; 8],
                black: [300; 8],
                spot_pitch_um: 3000,
                lost_threshold: 250,
            },
            line_follow: LineFollowSettings {
                speed_mps: 0.2,
                red_factor: 0.5,
                blue_factor: 1.5,
                lost_timeout_ms: 400,
            },
            colour: ColourSettings {
                mark_ratio: 1.6,
                min_clear: 200,
            },
            proximity: ProximitySettings {
                led_count: 6,
                power_levels: 4,
                led_angle_deg: [30, 0, -30, 150, 180, -150],
                range_mm: [30, 60, 100, 150],
                report_period_ms: 500,
            },
            reflector: ReflectorSettings {
                mode: 1,
                period_ms: 50,
            },
            watchdog: WatchdogSettings { timeout_ms: 500 },
            log: LogSettings { level: 3 },
            bump: BumpSettings {
                threshold_mg: 250,
                min_moved_mm: 6,
                idle_ticks: 3,
            },
            reflex: ReflexSettings { power_level: 1 },
        }
    }
}
