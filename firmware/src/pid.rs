//! Discrete PID controller with anti-windup (thesis 11.2.1).
//!
//! `u = Kp·e + Ki·Σe·dt + Kd·Δe/dt`, with the integral term clamped to `±i_limit` (so it cannot wind
//! up while the output saturates) and the output clamped to `±out_limit`.

use protocol::settings::PidSettings;

/// PID state; gains come from [`PidSettings`] on every update so the host can retune live.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Pid {
    integral: f32,
    last_error: Option<f32>,
}

impl Pid {
    /// A controller with no history.
    pub const fn new() -> Self {
        Self {
            integral: 0.0,
            last_error: None,
        }
    }

    /// Forgets the integral and derivative history.
    pub fn reset(&mut self) {
        *self = Self::new();
    }

    /// One step: the output for `error` after `dt` seconds.
    pub fn update(&mut self, gains: &PidSettings, error: f32, dt: f32) -> f32 {
        let (kp, ki, kd) = (gains.kp, gains.ki, gains.kd);
        let (i_limit, out_limit) = (gains.i_limit, gains.out_limit);
        if !error.is_finite() || dt.is_nan() || dt <= 0.0 {
            return 0.0;
        }
        // Anti-windup: the integral is kept in output units and clamped there, so a retuned Ki
        // does not make the stored sum jump.
        self.integral = clamp(self.integral + ki * error * dt, i_limit);
        let derivative = match self.last_error {
            Some(prev) => kd * (error - prev) / dt,
            None => 0.0,
        };
        self.last_error = Some(error);
        clamp(kp * error + self.integral + derivative, out_limit)
    }

    /// The integral term's current contribution to the output.
    pub fn integral(&self) -> f32 {
        self.integral
    }
}

fn clamp(v: f32, limit: f32) -> f32 {
    let l = if limit.is_finite() { limit.abs() } else { 0.0 };
    if v.is_nan() {
        0.0
    } else {
        v.clamp(-l, l)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gains(kp: f32, ki: f32, kd: f32) -> PidSettings {
        PidSettings {
            kp,
            ki,
            kd,
            i_limit: 10.0,
            out_limit: 100.0,
        }
    }

    #[test]
    fn proportional_only() {
        let mut p = Pid::new();
        assert_eq!(p.update(&gains(2.0, 0.0, 0.0), 3.0, 0.01), 6.0);
    }

    #[test]
    fn integral_accumulates_with_dt() {
        let mut p = Pid::new();
        let g = gains(0.0, 5.0, 0.0);
        for _ in 0..10 {
            p.update(&g, 1.0, 0.01);
        }
        assert!((p.integral() - 0.5).abs() < 1e-5);
    }

    #[test]
    fn derivative_uses_the_error_change() {
        let mut p = Pid::new();
        let g = gains(0.0, 0.0, 0.1);
        assert_eq!(
            p.update(&g, 1.0, 0.01),
            0.0,
            "no derivative kick on the first sample"
        );
        assert!((p.update(&g, 2.0, 0.01) - 10.0).abs() < 1e-4);
    }

    #[test]
    fn integral_does_not_wind_up_past_its_limit() {
        let mut p = Pid::new();
        let g = gains(1.0, 100.0, 0.0);
        for _ in 0..1000 {
            p.update(&g, 50.0, 0.01);
        }
        assert_eq!(p.integral(), 10.0);
        // Once the error reverses the output follows at once instead of unwinding a huge sum.
        let u = p.update(&g, -20.0, 0.01);
        assert!(u < -5.0, "{u}");
    }

    #[test]
    fn output_is_clamped_and_nan_safe() {
        let mut p = Pid::new();
        assert_eq!(p.update(&gains(1000.0, 0.0, 0.0), 1.0, 0.01), 100.0);
        assert_eq!(p.update(&gains(1.0, 0.0, 0.0), f32::NAN, 0.01), 0.0);
        assert_eq!(p.update(&gains(1.0, 0.0, 0.0), 1.0, 0.0), 0.0);
        let g = PidSettings {
            kp: 1.0,
            ki: 0.0,
            kd: 0.0,
            i_limit: f32::NAN,
            out_limit: f32::NAN,
        };
        assert_eq!(p.update(&g, 1.0, 0.01), 0.0);
    }
}
