//! Control of a running simulation: ground truth, faults, kicks and jobs between two steps.

use std::time::Duration;

use tokio::sync::{mpsc, oneshot};

use super::{Command, Poses, Truth};
use crate::sim::{Pose, Simulation};

/// Control of a running simulation.
#[derive(Clone)]
pub struct SimHandle {
    pub(super) commands: mpsc::UnboundedSender<Command>,
}

impl SimHandle {
    /// Cuts (`false`) or restores (`true`) robot `index`'s link.
    pub fn set_link_up(&self, index: usize, up: bool) {
        let _ = self.commands.send(Command::SetLinkUp(index, up));
    }

    /// Ground truth now; `None` once the simulation has stopped.
    pub async fn truth(&self) -> Option<Truth> {
        let (tx, rx) = oneshot::channel();
        self.commands.send(Command::Truth(tx)).ok()?;
        rx.await.ok()
    }

    /// The robots' true poses now, without the rest of [`Truth`] (contact logs, obstacles);
    /// `None` once the simulation has stopped.
    pub async fn poses(&self) -> Option<Poses> {
        let (tx, rx) = oneshot::channel();
        self.commands.send(Command::Poses(tx)).ok()?;
        rx.await.ok()
    }

    /// Kicks robot `index` by (`dx`, `dy`) metres and `dtheta` radians between two steps (see
    /// [`Simulation::displace`]) and returns its new true pose.
    ///
    /// # Errors
    /// There is no such robot, the displacement is not finite, or the simulation has stopped.
    pub async fn displace(
        &self,
        index: usize,
        dx: f64,
        dy: f64,
        dtheta: f64,
    ) -> Result<Pose, String> {
        let (tx, rx) = oneshot::channel();
        let stopped = || "cannot displace a robot: the simulation has stopped".to_string();
        self.commands
            .send(Command::Displace(index, [dx, dy, dtheta], tx))
            .map_err(|_| stopped())?;
        rx.await.map_err(|_| stopped())?
    }

    /// Kicks robot `index` by `by` (x, y metres, turn radians) as `how` says, at simulated time
    /// `at` exactly however fast the simulation runs (at once if that time has passed). The
    /// outcome is logged.
    pub fn kick_at(&self, at: Duration, index: usize, by: [f64; 3], how: world::cli::KickHow) {
        let _ = self.commands.send(Command::DisplaceAt(at, index, by, how));
    }

    /// Runs `f` on the simulation between two steps and returns its result: any ground truth a
    /// test needs, or a fault to inject. `None` once the simulation has stopped.
    pub async fn inspect<T: Send + 'static>(
        &self,
        f: impl FnOnce(&mut Simulation) -> T + Send + 'static,
    ) -> Option<T> {
        let (tx, rx) = oneshot::channel();
        let job = Box::new(move |sim: &mut Simulation| {
            let _ = tx.send(f(sim));
        });
        self.commands.send(Command::Inspect(job)).ok()?;
        rx.await.ok()
    }

    /// Runs `f` on the simulation once its clock reaches `at` (at once if it has), however fast
    /// it runs: what a test waits on instead of the wall clock. `None` once it has stopped.
    pub async fn at<T: Send + 'static>(
        &self,
        at: Duration,
        f: impl FnOnce(&mut Simulation) -> T + Send + 'static,
    ) -> Option<T> {
        let (tx, rx) = oneshot::channel();
        let job = Box::new(move |sim: &mut Simulation| {
            let _ = tx.send(f(sim));
        });
        self.commands.send(Command::At(at, job)).ok()?;
        rx.await.ok()
    }

    /// Stops the stepping task.
    pub fn stop(&self) {
        let _ = self.commands.send(Command::Stop);
    }
}
