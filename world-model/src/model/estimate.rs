//! A robot's estimate between updates: the correction from odometry to the corrected pose, its
//! covariance and the evidence counters, and the covariance's algebra (correction in Joseph form,
//! widening, 1σ figures).

use super::*;

/// The rigid transform taking a robot's odometry pose to its corrected pose.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(super) struct Correction {
    pub(super) dx: f64,
    pub(super) dy: f64,
    pub(super) dtheta: f64,
}

impl Correction {
    pub(super) fn apply(&self, p: Pose) -> Pose {
        let (s, c) = self.dtheta.sin_cos();
        Pose {
            x: c * p.x - s * p.y + self.dx,
            y: s * p.x + c * p.y + self.dy,
            theta: p.theta + self.dtheta,
        }
    }

    /// The correction that takes `odometry` to `corrected`.
    pub(super) fn between(odometry: Pose, corrected: Pose) -> Self {
        let dtheta = corrected.theta - odometry.theta;
        let (s, c) = dtheta.sin_cos();
        Self {
            dx: corrected.x - (c * odometry.x - s * odometry.y),
            dy: corrected.y - (s * odometry.x + c * odometry.y),
            dtheta,
        }
    }
}

/// Per robot: the correction, and how far it has followed tape without a match.
#[derive(Clone, Debug)]
pub(super) struct Estimate {
    pub(super) correction: Correction,
    pub(super) last_odometry: Option<Pose>,
    pub(super) unmatched_m: f64,
    /// Colour last seen under the sensor (`protocol::packets::Mark` as a byte).
    pub(super) last_mark: u8,
    /// Travel since the colour under the sensor last changed.
    pub(super) mark_held_m: f64,
    /// Covariance of the corrected pose (x, y, θ).
    pub(super) cov: Matrix3<f64>,
    /// Travel with no tape under the sensor where the model puts it squarely on one.
    pub(super) no_tape_m: f64,
    /// Travel with no tape under the sensor where the estimate's mean puts it plainly on one,
    /// however uncertain the estimate.
    pub(super) no_tape_plain_m: f64,
    /// Time standing still in that state.
    pub(super) no_tape_plain_at_rest: std::time::Duration,
    /// Time standing still in that state.
    pub(super) no_tape_at_rest: std::time::Duration,
    /// When the previous update was made.
    pub(super) last_at: Option<tokio::time::Instant>,
    /// Travel with tape under the sensor where the model has none.
    pub(super) stray_tape_m: f64,
    /// Whether the line sensor saw tape at the previous update.
    pub(super) saw_tape: bool,
    /// The line reading when the robot came to rest on a tape, and how many updates running
    /// have read it moved since.
    pub(super) rest_line: Option<i16>,
    pub(super) displaced_reads: u32,
    /// Whether the firmware followed a tape it saw at the previous update.
    pub(super) was_following: bool,
    /// Set while the robot is lost.
    pub(super) lost: Option<Lost>,
    pub(super) stats: LocalisationStats,
    /// The estimate over the last second, by the robot's uptime in milliseconds: a bump the
    /// robot reports after it ended takes the estimate back to where it stood before it, since
    /// the wheels it dragged counted travel (often the wrong way) that never happened.
    pub(super) recent: std::collections::VecDeque<(u32, Pose)>,
}

/// How much of the estimate's past is kept for a bump to go back to.
pub(super) const RECENT_MS: u32 = 1000;

impl Default for Estimate {
    fn default() -> Self {
        Self {
            correction: Correction::default(),
            last_odometry: None,
            unmatched_m: 0.0,
            last_mark: 0,
            mark_held_m: 0.0,
            cov: Matrix3::from_diagonal(&nalgebra::Vector3::new(
                START_SIGMA_M * START_SIGMA_M,
                START_SIGMA_M * START_SIGMA_M,
                START_SIGMA_RAD * START_SIGMA_RAD,
            )),
            no_tape_m: 0.0,
            no_tape_plain_m: 0.0,
            no_tape_plain_at_rest: std::time::Duration::ZERO,
            no_tape_at_rest: std::time::Duration::ZERO,
            last_at: None,
            stray_tape_m: 0.0,
            saw_tape: false,
            rest_line: None,
            displaced_reads: 0,
            was_following: false,
            lost: None,
            stats: LocalisationStats::default(),
            recent: std::collections::VecDeque::new(),
        }
    }
}

/// A tape the robot faces along, as the model has it under the line sensor.
#[derive(Clone, Copy, Debug)]
pub(super) struct TapeAlong {
    /// From the sensor's centre to the tape's centre line.
    pub(super) distance_m: f64,
    /// Cosine of the angle between the heading and the tape.
    pub(super) cos: f64,
    /// 1σ of the position across the tape.
    pub(super) sigma_m: f64,
    pub(super) width_m: f64,
}

/// A lost episode in progress.
#[derive(Clone, Debug)]
pub(super) struct Lost {
    pub(super) since: tokio::time::Instant,
    /// A tape found while lost has fixed the position across it.
    pub(super) fixed: bool,
}

/// The covariance after a correction of gain `k` (a column) on a measurement `h` (a row) of
/// variance `r`, in Joseph form, so it holds for a gain that is fixed rather than optimal.
pub(super) fn corrected(
    cov: &Matrix3<f64>,
    h: RowVector3<f64>,
    k: Vector3<f64>,
    r: f64,
) -> Matrix3<f64> {
    let a = Matrix3::identity() - k * h;
    a * cov * a.transpose() + k * k.transpose() * r
}

/// Raises the position's variance on each axis to at least `position_m`² and the heading's to
/// `heading_rad`²: what a contradiction says the estimate may be off by.
pub(super) fn widen(cov: &mut Matrix3<f64>, position_m: f64, heading_rad: f64) {
    for i in 0..2 {
        cov[(i, i)] = cov[(i, i)].max(position_m * position_m);
    }
    cov[(2, 2)] = cov[(2, 2)].max(heading_rad * heading_rad);
}

/// 1σ of the position along its worst direction, and of the heading.
pub(super) fn sigmas(cov: &Matrix3<f64>) -> PoseUncertainty {
    let (a, b, c) = (cov[(0, 0)], cov[(0, 1)], cov[(1, 1)]);
    let major = (a + c) / 2.0 + (((a - c) / 2.0).powi(2) + b * b).sqrt();
    PoseUncertainty {
        position_m: major.max(0.0).sqrt(),
        heading_rad: cov[(2, 2)].max(0.0).sqrt(),
    }
}

/// 1σ of the position along unit vector `n`.
pub(super) fn sigma_along(cov: &Matrix3<f64>, n: Vector2<f64>) -> f64 {
    let v = n.x * n.x * cov[(0, 0)] + 2.0 * n.x * n.y * cov[(0, 1)] + n.y * n.y * cov[(1, 1)];
    v.max(0.0).sqrt()
}

/// A tape sighting matched to the model: the corrected pose, the tape's normal the correction
/// moved it along, and the gain applied to the heading (0 when the heading was left alone).
pub(super) struct TapeMatch {
    pub(super) pose: Pose,
    pub(super) normal: Vector2<f64>,
    pub(super) heading_gain: f64,
}
