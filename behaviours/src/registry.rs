//! [`Registry`]: behaviours by name, the five built-ins to start with.

use std::collections::BTreeMap;

use behaviour_api::{Constructor, Entry};

use crate::cooperative_push::CooperativePush;
use crate::line_follow::LineFollow;
use crate::square_walk::SquareWalk;
use crate::token_ring::TokenRing;
use crate::traffic_control::TrafficControl;

/// Behaviours by name.
#[derive(Clone, Debug, Default)]
pub struct Registry {
    entries: BTreeMap<&'static str, Entry>,
}

impl Registry {
    /// An empty registry.
    pub fn new() -> Self {
        Self::default()
    }

    /// The built-in behaviours.
    pub fn builtin() -> Self {
        let mut r = Self::new();
        r.add(Entry::of::<SquareWalk>(
            "square_walk",
            "every robot walks a 0.1 m square (thesis A.1); success when each closes within 10 mm \
             and its encoders measured the walk",
            "open",
        ));
        r.add(Entry::of::<CooperativePush>(
            "cooperative_push",
            "two robots find a box too heavy for one on the track and push it off together \
             (thesis A.2); success when it is clear and both lap again, pushes and laps measured by \
             their encoders",
            "push",
        ));
        r.add(Entry::of::<TokenRing>(
            "token_ring",
            "a token passes round robots following a track when they identify each other by IR \
             (thesis A.3), around a box, reversing each round; success after three rounds with \
             half a loop per round on each robot's encoders",
            "ring",
        ));
        r.add(Entry::of::<TrafficControl>(
            "traffic_control",
            "robots serve streams of goal nodes on a track graph with a deadlock-free plan \
             (LaCAM) run as a dependency graph, replanned when held up; success after 1.5 tasks \
             per robot (12 on junction, 18 on grid: well within the 600 s default) without \
             collision, the edges driven measured by the encoders",
            "junction",
        ));
        r.add(Entry::of::<LineFollow>(
            "line_follow",
            "robots follow a closed track at their own speeds, keeping their distance; success \
             when each has driven its laps, measured by its encoders",
            "oval",
        ));
        r
    }

    /// Adds (or replaces) a behaviour.
    pub fn add(&mut self, entry: Entry) {
        self.entries.insert(entry.name, entry);
    }

    /// Adds (or replaces) a behaviour that takes no parameters, built by `constructor`.
    pub fn register(
        &mut self,
        name: &'static str,
        description: &'static str,
        world: &'static str,
        constructor: Constructor,
    ) {
        self.add(Entry::from_fn(name, description, world, constructor));
    }

    /// A behaviour by name.
    pub fn get(&self, name: &str) -> Option<&Entry> {
        self.entries.get(name)
    }

    /// Every name, sorted.
    pub fn names(&self) -> Vec<&'static str> {
        self.entries.keys().copied().collect()
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use behaviour_api::BehaviourConfig;
    use world::presets;

    use super::*;

    /// A config on the behaviour's own world, as the coordinator builds it.
    fn config(entry: &Entry, params: &[(&str, &str)]) -> BehaviourConfig {
        let world = presets::preset(entry.world).expect("the behaviour's world is a preset");
        BehaviourConfig {
            robots: world.robots.iter().map(|r| r.id).collect(),
            params: params
                .iter()
                .map(|(k, v)| (k.to_string(), v.to_string()))
                .collect(),
            track: Arc::new(world.track),
            ..Default::default()
        }
    }

    #[test]
    fn every_builtin_declares_its_parameters_and_refuses_others_by_name() {
        let registry = Registry::builtin();
        let expected: &[(&str, &[&str])] = &[
            ("cooperative_push", &["box", "laps", "push", "speed"]),
            ("line_follow", &["laps", "spacing", "speed", "spread"]),
            ("square_walk", &["side"]),
            ("token_ring", &["reverse", "rounds", "speed"]),
            (
                "traffic_control",
                &["flow", "goals", "quota", "replan", "segment_m", "tasks"],
            ),
        ];
        assert_eq!(
            registry.names(),
            expected.iter().map(|(n, _)| *n).collect::<Vec<_>>()
        );
        for (name, keys) in expected {
            let entry = registry.get(name).expect("registered");
            let declared: Vec<_> = entry.params().iter().map(|p| p.name).collect();
            assert_eq!(declared, *keys, "{name}");
            assert!(entry.params().iter().all(|p| !p.doc.is_empty()), "{name}");
            entry
                .build(&config(entry, &[]))
                .unwrap_or_else(|e| panic!("{name}: {e}"));

            let err = entry.check(&config(entry, &[(keys[0], "x")])).unwrap_err();
            assert!(err.contains(keys[0]), "{name}: {err}");
            let err = entry.check(&config(entry, &[("bogus", "1")])).unwrap_err();
            assert_eq!(
                err,
                format!(
                    "unknown parameter \"bogus\" for {name}; its parameters: {}",
                    keys.join(", ")
                )
            );
            assert_eq!(
                entry.check_params(&[("bogus".into(), "1".into())].into()),
                Err(err)
            );
        }
    }

    #[test]
    fn traffic_control_checks_its_goals_against_the_world_without_building() {
        let registry = Registry::builtin();
        let entry = registry.get("traffic_control").expect("registered");
        let err = entry
            .check(&config(entry, &[("goals", "A,B")]))
            .unwrap_err();
        assert!(err.starts_with("goals:"), "{err}");
        // Without a world, only the declaration is checked.
        assert_eq!(
            entry.check_params(&[("goals".into(), "A,B".into())].into()),
            Ok(())
        );
    }
}
