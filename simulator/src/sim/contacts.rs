//! Contacts: which robots, walls and boxes touched, and when each contact began.

use rapier2d::prelude::*;

use super::Simulation;

/// Which pair of things touched.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum ContactKind {
    /// Two robots (indices).
    RobotRobot(usize, usize),
    /// A robot and the arena wall.
    RobotWall(usize),
    /// A robot and a box (robot index, box index).
    RobotObstacle(usize, usize),
}

/// A contact that began at a time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Contact {
    /// What touched.
    pub kind: ContactKind,
    /// When it began, seconds of simulated time.
    pub at_s: f64,
}

/// What a collider belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Owner {
    Robot(usize),
    Obstacle(usize),
    Wall,
}

impl Simulation {
    /// Every contact that began so far.
    pub fn contacts(&self) -> &[Contact] {
        &self.contacts
    }

    /// Robot–robot contacts that began so far.
    pub fn robot_collisions(&self) -> usize {
        self.contacts
            .iter()
            .filter(|c| matches!(c.kind, ContactKind::RobotRobot(..)))
            .count()
    }

    fn owner(&self, c: ColliderHandle) -> Option<Owner> {
        self.owners
            .binary_search_by_key(&c.into_raw_parts(), |&(h, _)| h.into_raw_parts())
            .ok()
            .map(|k| self.owners[k].1)
    }

    pub(super) fn record_contacts(&mut self, now_ns: u64) {
        let mut now_active = Vec::new();
        for pair in self.narrow_phase.contact_pairs() {
            if !pair.has_any_active_contact {
                continue;
            }
            let (Some(a), Some(b)) = (self.owner(pair.collider1), self.owner(pair.collider2))
            else {
                continue;
            };
            let kind = match (a, b) {
                (Owner::Robot(x), Owner::Robot(y)) => ContactKind::RobotRobot(x.min(y), x.max(y)),
                (Owner::Robot(x), Owner::Wall) | (Owner::Wall, Owner::Robot(x)) => {
                    ContactKind::RobotWall(x)
                }
                (Owner::Robot(x), Owner::Obstacle(o)) | (Owner::Obstacle(o), Owner::Robot(x)) => {
                    ContactKind::RobotObstacle(x, o)
                }
                _ => continue,
            };
            now_active.push(kind);
        }
        now_active.sort();
        now_active.dedup();
        let at_s = now_ns as f64 * 1e-9;
        for k in &now_active {
            if self.active_contacts.binary_search(k).is_err() {
                self.contacts.push(Contact { kind: *k, at_s });
            }
        }
        self.active_contacts = now_active;
    }
}
