//! The [`Behaviour`] trait: the hooks a behaviour implements, each answering with intents.

use crate::event::Event;
use crate::intent::Intent;
use crate::snapshot::{LocalisationEvent, WorldSnapshot};
use crate::team::{HeldPolicy, Team};
use crate::verdict::Verdict;

/// A behaviour: decision logic over snapshots and events, testable without actors.
///
/// Every hook gets the latest snapshot and the [`Team`], which keeps the books (outstanding
/// moves, follow speeds, held moves) and takes the verdict; each returns intents for the
/// supervisor's safety check. Once a verdict is given the hooks are no longer called.
pub trait Behaviour: Send + 'static {
    /// First intents, given the world as the experiment starts.
    fn start(&mut self, world: &WorldSnapshot, team: &mut Team) -> Vec<Intent>;
    /// Intents for a new snapshot (every 100 ms).
    fn on_snapshot(&mut self, _world: &WorldSnapshot, _team: &mut Team) -> Vec<Intent> {
        Vec::new()
    }
    /// Intents for a robot's event (a move finished, a sighting, a lost line, …).
    fn on_event(
        &mut self,
        _robot: u16,
        _event: &Event,
        _world: &WorldSnapshot,
        _team: &mut Team,
    ) -> Vec<Intent> {
        Vec::new()
    }
    /// Intents for an intent the supervisor's safety check held back (it never reached the
    /// robot). Moves come here under [`HeldPolicy::Tell`] at once, and under the default
    /// [`HeldPolicy::RetryThenReplan`] once they have been held for its patience.
    fn on_held(
        &mut self,
        _intent: &Intent,
        _reason: &str,
        _world: &WorldSnapshot,
        _team: &mut Team,
    ) -> Vec<Intent> {
        Vec::new()
    }
    /// Intents for a robot that was found lost or re-localised. When it is lost the supervisor
    /// has already stopped it (the team has dropped its outstanding moves) and holds its intents
    /// until `Found`; a behaviour that drives it must plan it again from its pose then.
    fn on_localisation(
        &mut self,
        _robot: u16,
        _event: &LocalisationEvent,
        _world: &WorldSnapshot,
        _team: &mut Team,
    ) -> Vec<Intent> {
        Vec::new()
    }
    /// What the team does with a move the safety check held back.
    fn held_policy(&self) -> HeldPolicy {
        HeldPolicy::default()
    }
    /// A verdict judged from the behaviour's own state, asked after every hook; `None` while it
    /// runs. A behaviour may instead give it through [`Team::finish`] or [`Team::fail`].
    fn verdict(&self) -> Option<Verdict> {
        None
    }
    /// Figures of the work done so far (tasks, passes, pushes), asked after every hook while the
    /// behaviour runs: a run stopped before its verdict (the time limit, Ctrl-C, the panel's
    /// stop) reports them with its failure.
    fn progress(&self) -> Vec<(String, f64)> {
        Vec::new()
    }
}
