//! The digital twin as one transport among others. Built with the feature `sim` (the default),
//! the coordinator runs the simulator in its own process ([`SimHandle`]), takes its ground truth
//! ([`Truth`], [`Poses`]) and injects body faults and kicks. Built without it, the coordinator
//! drives real robots only and links no physics engine: these types then stand in for the
//! simulator's and have no values, so every path that would need a simulation is one the
//! compiler knows is never taken.

#[cfg(feature = "sim")]
pub use simulator::runtime::{Poses, SimHandle, Truth};
#[cfg(feature = "sim")]
pub use simulator::BodyFault;

#[cfg(not(feature = "sim"))]
pub use absent::{BodyFault, Poses, SimHandle, Truth};

#[cfg(not(feature = "sim"))]
mod absent {
    use std::time::Duration;

    use world::Pose;

    /// No value: a coordinator built without the simulator never has one.
    #[derive(Clone, Copy, Debug, PartialEq, Eq)]
    pub enum Never {}

    /// A fault in a simulated robot's body; none exists without the simulator.
    #[derive(Clone, Copy, Debug, PartialEq)]
    pub enum BodyFault {}

    /// The simulation's handle; none exists without the simulator.
    #[derive(Clone, Debug)]
    pub enum SimHandle {}

    impl SimHandle {
        /// Never called: there is no simulation.
        pub fn set_link_up(&self, _: usize, _: bool) {
            match *self {}
        }

        /// Never called: there is no simulation.
        pub async fn truth(&self) -> Option<Truth> {
            match *self {}
        }

        /// Never called: there is no simulation.
        pub async fn poses(&self) -> Option<Poses> {
            match *self {}
        }

        /// Never called: there is no simulation.
        pub async fn displace(&self, _: usize, _: f64, _: f64, _: f64) -> Result<Pose, String> {
            match *self {}
        }

        /// Never called: there is no simulation.
        pub fn stop(&self) {
            match *self {}
        }
    }

    /// The simulator's ground truth, as the coordinator reads it; no value exists without the
    /// simulator (the field `never` has no value).
    #[derive(Clone, Debug)]
    pub struct Truth {
        /// Simulated time.
        pub now: Duration,
        /// Robot ids and true poses.
        pub robots: Vec<(u16, Pose)>,
        /// True distance each robot drove, metres.
        pub distances_m: Vec<f64>,
        /// Box poses.
        pub obstacles: Vec<Pose>,
        /// How far each box moved from its start, metres.
        pub obstacle_displacements_m: Vec<f64>,
        /// Robot–robot contacts so far.
        pub robot_collisions: usize,
        /// Each robot–robot contact: when it began (simulated seconds) and the two robot ids.
        pub collision_log: Vec<(f64, u16, u16)>,
        /// Robot–wall contacts so far.
        pub wall_contacts: usize,
        /// Each robot–wall contact: when it began (simulated seconds) and the robot's id.
        pub wall_contact_log: Vec<(f64, u16)>,
        /// Makes the type uninhabited.
        pub never: Never,
    }

    impl Truth {
        /// Never called: there is no simulation.
        pub fn longest_unattended_s(&self) -> f64 {
            match self.never {}
        }
    }

    /// True poses; no value exists without the simulator.
    #[derive(Clone, Debug)]
    pub struct Poses {
        /// Simulated time.
        pub now: Duration,
        /// Robot ids and true poses, in world order.
        pub robots: Vec<(u16, Pose)>,
        /// Makes the type uninhabited.
        pub never: Never,
    }
}
