use super::*;
use world::presets;

#[test]
fn goals_name_track_nodes_and_count_robots() {
    let w = presets::preset("junction").unwrap();
    let mut cfg = BehaviourConfig {
        robots: vec![1, 2],
        track: Arc::new(w.track),
        ..Default::default()
    };
    cfg.params.insert("goals".into(), "Y,T".into());
    assert!(TrafficControl::from_config(&cfg).is_ok());
    cfg.params.insert("goals".into(), "Y,nowhere".into());
    let e = TrafficControl::from_config(&cfg).err().unwrap();
    assert!(e.contains("nowhere"), "{e}");
    cfg.params.insert("goals".into(), "Y".into());
    assert!(TrafficControl::from_config(&cfg).is_err());
}

#[test]
fn a_curve_is_driven_in_segments_that_stay_on_the_tape() {
    let w = presets::preset("junction").unwrap();
    let cfg = BehaviourConfig {
        robots: vec![1],
        track: Arc::new(w.track),
        ..Default::default()
    };
    let t = TrafficControl::from_config(&cfg).unwrap();
    for (u, v) in [("B", "D"), ("D", "B"), ("M", "P2"), ("F", "P1")] {
        let mut leg = leg_between(&t, u, v);
        let (edge, u, v) = (leg.edge, node(&t, u), leg.to);
        // A robot on u facing the wrong way: it turns, then follows the tape segment by
        // segment, each segment ending on the tape, until the last ends on v.
        let p = t.position(u);
        let mut pose = Pose {
            x: p.x,
            y: p.y,
            theta: 1.0,
        };
        for _ in 0..20 {
            let r = t.segment(pose, &mut leg);
            let end = Point2::new(r.end.x, r.end.y);
            assert!(t.track.nearest_on(edge, end).distance_m < 1e-6, "{r:?}");
            pose = r.end;
            if leg.last {
                break;
            }
        }
        assert!(leg.last);
        assert!((Point2::new(pose.x, pose.y) - t.position(v)).norm() < 1e-6);
    }
}

use behaviour_api::testing::{world, Harness};
/// The plan's drive of the edge from node `u` to node `v`.
fn leg_between(t: &TrafficControl, u: &str, v: &str) -> EdgeDrive {
    let (u, v) = (node(t, u), node(t, v));
    let (edge, forward) = t.edge_between(u, v).unwrap();
    EdgeDrive {
        index: Some(0),
        edge,
        forward,
        to: v,
        last: false,
        back: false,
    }
}

/// Robot 1 of `t` on node `u` facing along the tape to `v`, about to drive that edge.
fn on_edge_start(t: &mut TrafficControl, u: &str, v: &str) -> (usize, Pose) {
    let leg = leg_between(t, u, v);
    let (edge, forward, u) = (leg.edge, leg.forward, node(t, u));
    t.bots[0].driving = Some(leg);
    let len = t.track.edge_length(edge);
    let (_, tangent) = t.track.point_at(edge, if forward { 0.0 } else { len });
    let dir = if forward { tangent } else { -tangent };
    let p = t.position(u);
    let pose = Pose {
        x: p.x,
        y: p.y,
        theta: dir.y.atan2(dir.x),
    };
    (edge, pose)
}

fn at(pose: Pose) -> WorldSnapshot {
    snapshot(0, &[(1, pose.x, pose.y, pose.theta.to_degrees())])
}

#[test]
fn an_edge_is_driven_with_the_next_segment_queued_behind_the_running_one() {
    let config = |flow: &str| BehaviourConfig {
        robots: vec![1],
        track: Arc::new(presets::preset("junction").unwrap().track),
        params: [("flow".to_string(), flow.to_string())].into(),
        ..Default::default()
    };
    let mut t = TrafficControl::from_config(&config("true")).unwrap();
    let (edge, start) = on_edge_start(&mut t, "B", "D");
    let forward_moves = |out: &[Intent]| {
        out.iter()
            .filter(|i| {
                matches!(
                    i,
                    Intent::Move {
                        command: MoveCommand::Arc { .. } | MoveCommand::Straight { .. },
                        ..
                    }
                )
            })
            .count()
    };
    // Two segments at once, so that the robot never waits at the first joint.
    let out = t.drive(0, &at(start));
    assert_eq!(forward_moves(&out), 2, "{out:?}");
    let (mut first_end, mut tail_end) = t.bots[0].tail.expect("a tail to queue behind");
    let mut segments = 2;
    loop {
        // The robot ended the running segment 5 mm to the left of where it was planned to:
        // the segment queued now is planned from where the tail will then end, and ends on
        // the tape.
        let off = first_end.compose(Pose {
            x: 0.0,
            y: 0.005,
            theta: 0.0,
        });
        let out = t.drive_ahead(0, &at(off));
        assert_eq!(forward_moves(&out), 1, "{out:?}");
        segments += 1;
        let leg = t.bots[0].driving.unwrap();
        let Some((from, to)) = t.bots[0].tail else {
            assert!(
                leg.last,
                "only the edge's last segment has nothing behind it"
            );
            break;
        };
        assert!(!leg.last);
        let end = Point2::new(to.x, to.y);
        assert!(t.track.nearest_on(edge, end).distance_m < 1e-6, "{to:?}");
        let predicted = off.compose(tail_end.relative_to(first_end));
        assert!((predicted.x - from.x).abs() < 1e-9 && (predicted.y - from.y).abs() < 1e-9);
        (first_end, tail_end) = (from, to);
        assert!(segments < 20, "the edge ends");
    }
    assert!(segments >= 3, "{segments} segments");

    // `flow=false` sends one segment at a time; the default flows.
    for (mut t, sent) in [
        (TrafficControl::from_config(&config("false")).unwrap(), 1),
        (junction(&[1]), 2),
    ] {
        let (_, start) = on_edge_start(&mut t, "B", "D");
        let out = t.drive(0, &at(start));
        assert_eq!(forward_moves(&out), sent, "{out:?}");
        assert_eq!(t.bots[0].tail.is_some(), sent == 2);
    }
}

fn junction(robots: &[u16]) -> TrafficControl {
    let w = presets::preset("junction").unwrap();
    let cfg = BehaviourConfig {
        robots: robots.to_vec(),
        track: Arc::new(w.track),
        ..Default::default()
    };
    TrafficControl::from_config(&cfg).unwrap()
}

/// A snapshot at `secs` with robots at `(id, x, y, heading in degrees)`.
fn snapshot(secs: u64, robots: &[(u16, f64, f64, f64)]) -> WorldSnapshot {
    robots
        .iter()
        .fold(
            world().arena(1.6, 1.0).at(secs as f64),
            |w, &(id, x, y, deg)| w.robot(id, x, y, deg),
        )
        .build()
}

fn node(t: &TrafficControl, id: &str) -> u32 {
    t.graph.node(id).unwrap().index() as u32
}

fn moves_for(out: &[Intent], robot: u16) -> usize {
    out.iter()
        .filter(|i| matches!(i, Intent::Move { robot: r, .. } if *r == robot))
        .count()
}

#[test]
fn a_robot_on_a_node_stands_there_and_is_planned_from_it() {
    let mut h = Harness::new(junction(&[1]));
    // C is at (0.8, 0.15): 1 cm off it still stands on it.
    let w = snapshot(0, &[(1, 0.81, 0.15, 90.0)]);
    let out = h.start(&w);
    assert!(
        h.behaviour().verdict.is_none(),
        "{:?}",
        h.behaviour().verdict
    );
    assert_eq!(moves_for(&out, 1), 0, "{out:?}");
    assert_eq!(h.behaviour().bots[0].node, node(h.behaviour(), "C"));
    // At the next snapshot the team is planned and the robot drives its first edge.
    let out = h.snapshot(&snapshot(1, &[(1, 0.81, 0.15, 90.0)]));
    assert_eq!(h.behaviour().phase, Phase::Running);
    assert!(moves_for(&out, 1) > 0, "{out:?}");
    assert!(h.behaviour().bots[0]
        .driving
        .is_some_and(|l| l.index.is_some()));
}

#[test]
fn a_robot_on_an_edge_drives_to_the_node_ahead_or_the_free_one_behind() {
    let mut h = Harness::new(junction(&[1, 2]));
    // Robot 1 stands on C; robot 2 on the main line between F and C, heading for C, backs
    // to F.
    let w = snapshot(0, &[(1, 0.8, 0.15, 0.0), (2, 0.7, 0.15, 0.0)]);
    let out = h.start(&w);
    assert!(
        h.behaviour().verdict.is_none(),
        "{:?}",
        h.behaviour().verdict
    );
    assert_eq!(h.behaviour().bots[0].node, node(h.behaviour(), "C"));
    assert_eq!(h.behaviour().bots[1].node, node(h.behaviour(), "F"));
    let leg = h.behaviour().bots[1].driving.unwrap();
    assert!(leg.back && leg.to == node(h.behaviour(), "F"), "{leg:?}");
    match out.as_slice() {
        [Intent::Move {
            robot: 2,
            command: MoveCommand::Straight { distance_m, .. },
            ..
        }] => assert!((*distance_m + 0.25).abs() < 1e-3, "{out:?}"),
        _ => panic!("robot 2 backs to F: {out:?}"),
    }
    // Alone, it drives ahead to C.
    let mut h = Harness::new(junction(&[2]));
    let out = h.start(&snapshot(0, &[(2, 0.7, 0.15, 0.0)]));
    assert_eq!(h.behaviour().bots[0].node, node(h.behaviour(), "C"));
    assert!(!h.behaviour().bots[0].driving.unwrap().back);
    assert!(moves_for(&out, 2) > 0);
}

#[test]
fn two_robots_on_one_edge_take_the_end_on_their_side() {
    let mut h = Harness::new(junction(&[1, 2]));
    // Both head for C; robot 1 is behind robot 2, so it goes back to F instead of passing.
    h.start(&snapshot(0, &[(1, 0.55, 0.15, 0.0), (2, 0.7, 0.15, 0.0)]));
    assert!(
        h.behaviour().verdict.is_none(),
        "{:?}",
        h.behaviour().verdict
    );
    assert_eq!(h.behaviour().bots[0].node, node(h.behaviour(), "F"));
    assert_eq!(h.behaviour().bots[1].node, node(h.behaviour(), "C"));
}

#[test]
fn a_robot_off_the_tape_is_refused_with_where_it_is() {
    let mut h = Harness::new(junction(&[1, 7]));
    let out = h.start(&snapshot(0, &[(1, 0.8, 0.15, 0.0), (7, 0.8, 0.42, 0.0)]));
    let v = h.behaviour().verdict.clone().expect("refused");
    assert!(!v.success);
    assert!(
        v.summary.contains("robot 7")
            && v.summary.contains("(0.800, 0.420)")
            && v.summary.contains("12.0 cm"),
        "{}",
        v.summary
    );
    assert!(out.is_empty(), "nothing moves: {out:?}");
}

#[test]
fn a_robot_with_both_ends_taken_is_refused_naming_who_holds_them() {
    let mut h = Harness::new(junction(&[1, 2, 3]));
    h.start(&snapshot(
        0,
        &[
            (1, 0.45, 0.15, 0.0),
            (2, 0.8, 0.15, 0.0),
            (3, 0.62, 0.15, 0.0),
        ],
    ));
    let v = h.behaviour().verdict.clone().expect("refused");
    assert!(
        v.summary.contains("robot 3") && v.summary.contains("C by robot 2"),
        "{}",
        v.summary
    );
}

#[test]
fn a_lost_robot_keeps_its_leg_and_drives_it_again_when_found() {
    let mut h = Harness::new(junction(&[2]));
    let w = snapshot(0, &[(2, 0.7, 0.15, 0.0)]);
    let out = h.start(&w);
    let sent = moves_for(&out, 2);
    assert!(sent > 0);
    h.localise(
        2,
        LocalisationEvent::Lost {
            why: "tape where none is".into(),
        },
        &w,
    );
    // Its dropped moves end aborted: not a failure, not progress.
    for _ in 0..sent {
        let aborted = Event::MoveFinished {
            tag: 0,
            outcome: MoveOutcome::Stopped,
        };
        assert!(h.event(2, aborted, &w).is_empty());
    }
    // Lost for longer than a stall would take is no deadlock.
    let late = snapshot(120, &[(2, 0.7, 0.15, 0.0)]);
    h.snapshot(&late);
    assert!(
        h.behaviour().verdict.is_none(),
        "{:?}",
        h.behaviour().verdict
    );
    let found = snapshot(121, &[(2, 0.74, 0.16, 10.0)]);
    let out = h.localise(2, LocalisationEvent::Found, &found);
    assert!(moves_for(&out, 2) > 0, "{out:?}");
    assert_eq!(
        h.behaviour().bots[0].driving.unwrap().to,
        node(h.behaviour(), "C")
    );
}

#[test]
fn a_robot_waiting_behind_a_lost_one_backs_away_and_returns_when_it_is_found() {
    let mut h = Harness::new(junction(&[2, 3]));
    let at = |secs, x3| snapshot(secs, &[(2, 0.7, 0.15, 0.0), (3, x3, 0.15, 0.0)]);
    let out = h.start(&at(0, 0.6));
    // Robot 3's moves are held, too near robot 2: it stands idle 10 cm behind it.
    let held: Vec<Intent> = out
        .into_iter()
        .filter(|i| matches!(i, Intent::Move { robot: 3, .. }))
        .collect();
    for i in held {
        h.hold(i, "too near robot 2", &at(0, 0.6));
    }
    assert!(h.team().idle(3));
    // How far robot 3 is sent straight to make room or come back, if it is.
    let room = |out: &[Intent]| {
        out.iter().find_map(|i| match i {
            Intent::Move {
                robot: 3,
                command: MoveCommand::Straight { distance_m, .. },
                tag: MAKE_ROOM_TAG,
            } => Some(*distance_m),
            _ => None,
        })
    };
    let lost = LocalisationEvent::Lost {
        why: "tape where none is".into(),
    };
    h.localise(2, lost, &at(1, 0.6));
    let backing = h.snapshot(&at(1, 0.6));
    assert!(room(&backing).is_some_and(|d| d < 0.0), "{backing:?}");
    // Backed away, it waits while robot 2 is lost.
    assert!(h.finish_move(3, MAKE_ROOM_TAG, &at(2, 0.52)).is_empty());
    assert_eq!(moves_for(&h.snapshot(&at(3, 0.52)), 3), 0);
    // Robot 2 found: robot 3 drives back to where it stood, then on with its leg.
    let back = h.localise(2, LocalisationEvent::Found, &at(4, 0.52));
    assert!(
        room(&back).is_some_and(|d| (d - 0.08).abs() < 1e-3),
        "{back:?}"
    );
    let on = h.finish_move(3, MAKE_ROOM_TAG, &at(5, 0.6));
    assert!(moves_for(&on, 3) > 0, "{on:?}");
    assert!(h.behaviour().bots[1].making_room.is_none());
}

#[test]
fn without_progress_the_team_recovers_then_fails_saying_who_waits_for_what() {
    let mut h = Harness::new(junction(&[1, 2]));
    let poses = [(1, 0.8, 0.15, 0.0), (2, 0.7, 0.15, 0.0)];
    h.start(&snapshot(0, &poses));
    // Robot 2's moves never finish; each stall is a recovery that sends it back and forth.
    let mut secs = 0;
    while h.behaviour().verdict.is_none() && secs < 1000 {
        secs += 1;
        h.snapshot(&snapshot(secs, &poses));
    }
    let v = h.behaviour().verdict.clone().expect("fails");
    assert!(!v.success);
    assert_eq!(h.behaviour().recoveries_total, MAX_RECOVERIES);
    assert!(
        v.summary.contains("deadlock") && v.summary.contains("robot 2 is driving"),
        "{}",
        v.summary
    );
    assert!(
        secs > STALL_LIMIT.as_secs() * u64::from(MAX_RECOVERIES + 1),
        "{secs}"
    );
}

#[test]
fn a_segment_held_for_seconds_sends_the_robot_back_and_replans() {
    let mut h = Harness::new(junction(&[2]));
    let w = snapshot(0, &[(2, 0.7, 0.15, 0.0)]);
    let out = h.start(&w);
    for i in &out {
        h.hold(*i, "another robot in the way", &w);
    }
    assert!(h.behaviour().bots[0].retry);
    // Planned again from the pose at the next snapshot.
    let out = h.snapshot(&snapshot(1, &[(2, 0.7, 0.15, 0.0)]));
    assert!(moves_for(&out, 2) > 0);
    for (n, i) in out.iter().enumerate() {
        let reason = if n == 0 {
            "another robot in the way"
        } else {
            "follows a held move"
        };
        h.hold(*i, reason, &w);
    }
    assert_eq!(h.behaviour().bots[0].held_why, "another robot in the way");
    let out = h.snapshot(&snapshot(5, &[(2, 0.7, 0.15, 0.0)]));
    assert_eq!(h.behaviour().recoveries_total, 1);
    let leg = h.behaviour().bots[0].driving.unwrap();
    assert_eq!(
        leg.to,
        node(h.behaviour(), "F"),
        "it drives back where it came from"
    );
    assert!(moves_for(&out, 2) > 0, "{out:?}");
}

/// Two robots on `junction`, running: robot 1 stands on A, robot 2 left F for C and is at
/// action `index` of the old plan. Returns the behaviour and the nodes A, F and C.
fn one_standing_one_driving_f_to_c(index: usize) -> (TrafficControl, u32, u32, u32) {
    let mut t = junction(&[1, 2]);
    let (a, f, c) = (node(&t, "A"), node(&t, "F"), node(&t, "C"));
    let (edge, forward) = t.edge_between(f, c).unwrap();
    t.phase = Phase::Running;
    t.bots[0].node = a;
    t.bots[1].node = f;
    t.bots[1].driving = Some(EdgeDrive {
        index: Some(index),
        edge,
        forward,
        to: c,
        last: false,
        back: false,
    });
    (t, a, f, c)
}

#[test]
fn a_lifelong_plan_keeps_a_drive_and_lets_no_robot_into_the_node_it_left_before_it_arrives() {
    let (mut t, a, f, c) = one_standing_one_driving_f_to_c(7);
    // Robot 1 has F as its goal; robot 2 drives to C, its goal.
    t.bots[0].goal = f;
    t.bots[1].goal = c;
    assert!(t.replan_lifelong().unwrap());
    assert_eq!(t.bots[1].driving.unwrap().index, Some(0));
    let adg = t.adg.as_mut().unwrap();
    assert_eq!((adg.actions(1)[0].from, adg.actions(1)[0].to), (f, c));
    assert_eq!((adg.actions(0)[0].from, adg.actions(0)[0].to), (a, f));
    assert_eq!(adg.dependency(0, 0), Some((1, 0)));
    assert_eq!(adg.ready(0), None);
    adg.complete(1, 0).unwrap();
    assert_eq!(adg.ready(0).map(|x| x.to), Some(f));
    // Neither goal was reached, so no task was given or counted.
    assert_eq!((t.bots[0].goal, t.bots[1].goal, t.tasks), (f, c, 0));
}

#[test]
fn a_robot_sent_on_from_its_goal_gets_a_new_task_at_the_next_lifelong_plan() {
    let (mut t, _, f, c) = one_standing_one_driving_f_to_c(2);
    t.bots[0].goal = u32::MAX;
    // Robot 2 reached F, its goal, and the old plan sent it on towards C.
    t.bots[1].goal = f;
    t.bots[1].reached = true;
    assert!(t.replan_lifelong().unwrap());
    // A new task from C, where it is committed to: not counted again on reaching F.
    assert!(!t.bots[1].reached);
    assert_ne!(t.bots[1].goal, c);
    assert_eq!(t.tasks, 0);
    assert_ne!(t.bots[0].goal, t.bots[1].goal);
}

#[test]
fn a_last_segment_whose_drive_was_held_does_not_count_as_arrived() {
    let mut h = Harness::new(junction(&[2]));
    // 5 cm before C, facing across the tape: a turn, then a straight onto C.
    let w = snapshot(0, &[(2, 0.75, 0.15, 90.0)]);
    let out = h.start(&w);
    assert_eq!(out.len(), 2, "{out:?}");
    h.hold(out[1], "another robot in the way", &w);
    let turned = snapshot(1, &[(2, 0.75, 0.15, 0.0)]);
    let out = h.finish_move(2, 0, &turned);
    assert!(
        h.behaviour().bots[0]
            .driving
            .is_some_and(|l| l.to == node(h.behaviour(), "C")),
        "still driving to C"
    );
    assert!(
        matches!(
            out.as_slice(),
            [Intent::Move {
                robot: 2,
                command: MoveCommand::Straight { .. },
                ..
            }]
        ),
        "the straight is planned again: {out:?}"
    );
}
