//! TOML world files: the serde form ([`WorldFile`], with source spans kept so every refusal names
//! its line) and its checked conversion into a [`World`].
//!
//! A world file looks like this (all keys shown; `worlds/*.toml` are complete examples):
//!
//! ```toml
//! name = "demo"
//! description = "one straight"
//! seed = 7                       # optional
//! [arena]                        # walls around [0, width_m] × [0, height_m]
//! width_m = 1.0
//! height_m = 0.6
//! [[track.nodes]]
//! id = "a"
//! x = 0.2
//! y = 0.3
//! [[track.nodes]]
//! id = "b"
//! x = 0.8
//! y = 0.3
//! [[track.edges]]
//! from = "a"
//! to = "b"
//! turn_deg = 0                   # signed arc sweep, + = left; default 0 (straight)
//! width_m = 0.006                # default 0.006
//! mark = "blue"                  # optional: "red" or "blue"
//! [[obstacles]]
//! x = 0.5
//! y = 0.45
//! width_m = 0.04
//! height_m = 0.04
//! heading_deg = 0                # default 0
//! mass_kg = 0.06
//! friction = 0.5                 # floor Coulomb coefficient, default 0.5
//! [[robots]]
//! id = 1
//! x = 0.3
//! y = 0.3
//! heading_deg = 0                # default 0
//! [link]                         # every key optional; defaults shown
//! profile = "l2cap"              # ideal, l2cap, bluetooth or poor; the keys below override it
//! latency_ms = 10
//! jitter_ms = 2
//! loss = 0
//! loss_burst_ms = 0              # mean fade; 0: each packet's loss on its own
//! bandwidth_kbps = 700
//! robots_per_piconet = 7
//! [light]
//! ambient = 0.2
//! noise = 0.01
//! ```

use std::ops::Range;
use std::path::Path;

use nalgebra::Point2;
use serde::Deserialize;
use toml::Spanned;

use super::track::{EdgeSpec, Mark, Node, Track, TrackError, DEFAULT_TAPE_WIDTH_M};
use super::{Arena, Light, Obstacle, Place, Problem, RadioModel, RobotStart, World};

/// Default floor friction coefficient of an obstacle.
pub const DEFAULT_OBSTACLE_FRICTION: f64 = 0.5;

/// Why a world file was refused. Its `Display` reads `FILE:LINE: what is wrong`.
#[derive(Debug, thiserror::Error)]
pub enum WorldError {
    /// The file could not be read.
    #[error("{origin}: cannot read the world file: {source}")]
    Io {
        /// The file's name.
        origin: String,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// Not valid TOML, or a value of the wrong type, a missing or an unknown key.
    #[error("{origin}:{line}: {message}")]
    Syntax {
        /// The file's name.
        origin: String,
        /// 1-based line of the offending text.
        line: usize,
        /// The TOML parser's description.
        message: String,
    },
    /// Valid TOML describing an impossible world.
    #[error("{origin}:{line}: {problem}")]
    Invalid {
        /// The file's name.
        origin: String,
        /// 1-based line of the offending value.
        line: usize,
        /// What is wrong.
        problem: Problem,
    },
}

impl WorldError {
    /// The 1-based line the error points at, if it concerns the file's content.
    pub fn line(&self) -> Option<usize> {
        match self {
            WorldError::Io { .. } => None,
            WorldError::Syntax { line, .. } | WorldError::Invalid { line, .. } => Some(*line),
        }
    }
}

/// A world file as written, with the span of every value kept for error messages.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorldFile {
    /// Short name.
    pub name: String,
    /// What the world is for.
    #[serde(default)]
    pub description: String,
    /// The walled floor.
    pub arena: ArenaFile,
    /// The tape.
    #[serde(default)]
    pub track: TrackFile,
    /// Movable boxes.
    #[serde(default)]
    pub obstacles: Vec<Spanned<ObstacleFile>>,
    /// Robot start poses.
    #[serde(default)]
    pub robots: Vec<Spanned<RobotFile>>,
    /// Radio link model.
    #[serde(default)]
    pub link: LinkFile,
    /// Ambient light and sensor noise.
    #[serde(default)]
    pub light: LightFile,
    /// Seed for every random choice of a run.
    #[serde(default)]
    pub seed: Option<u64>,
    /// Faults the experiment injects.
    #[serde(default)]
    pub faults: Vec<Spanned<FaultFile>>,
}

/// One `[[faults]]` entry: what goes wrong with which robot, when and for how long.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FaultFile {
    /// `cut`, `loss`, `latency`, `corrupt`, `duplicate`, `reorder` or `reboot`.
    pub kind: Spanned<String>,
    /// The robot's id.
    pub robot: Spanned<u16>,
    /// When it begins, seconds after the robots are connected.
    pub at_s: Spanned<f64>,
    /// How long it lasts, seconds (not for a reboot).
    #[serde(default)]
    pub for_s: Option<Spanned<f64>>,
    /// The share of packets hit (default 1), or a latency spike's seconds (default 1).
    #[serde(default)]
    pub amount: Option<Spanned<f64>>,
}

impl FaultFile {
    /// The fault, checked; `i` its index for the problem's place.
    fn to_spec(&self, i: usize) -> Result<crate::faults::FaultSpec, Problem> {
        let bad = |key: &'static str, why: String| Problem::BadFault { fault: i, key, why };
        let kind = crate::faults::FaultKind::new(
            self.kind.get_ref(),
            self.amount.as_ref().map(|a| *a.get_ref()),
        )
        .map_err(|why| {
            let key = if self.amount.is_some() && !why.starts_with("unknown") {
                "amount"
            } else {
                "kind"
            };
            bad(key, why)
        })?;
        let seconds = |v: f64, key: &'static str| {
            crate::cli::parse_duration(&v.to_string()).map_err(|why| bad(key, why))
        };
        let at = if *self.at_s.get_ref() == 0.0 {
            std::time::Duration::ZERO
        } else {
            seconds(*self.at_s.get_ref(), "at_s")?
        };
        let lasting = match (&self.for_s, kind.lasts()) {
            (Some(_), false) => return Err(bad("for_s", "a reboot happens at an instant".into())),
            (None, false) => std::time::Duration::ZERO,
            (Some(d), true) => seconds(*d.get_ref(), "for_s")?,
            (None, true) => return Err(bad("for_s", "how long it lasts is missing".into())),
        };
        Ok(crate::faults::FaultSpec {
            kind,
            robot: *self.robot.get_ref(),
            at,
            lasting,
        })
    }
}

/// `[arena]`: walls around the rectangle 0 ≤ x ≤ `width_m`, 0 ≤ y ≤ `height_m`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArenaFile {
    /// Extent along x in metres.
    pub width_m: Spanned<f64>,
    /// Extent along y in metres.
    pub height_m: Spanned<f64>,
}

/// `[track]`: the tape as nodes and edges.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrackFile {
    /// `[[track.nodes]]`.
    #[serde(default)]
    pub nodes: Vec<Spanned<NodeFile>>,
    /// `[[track.edges]]`.
    #[serde(default)]
    pub edges: Vec<Spanned<EdgeFile>>,
}

/// One `[[track.nodes]]` entry.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NodeFile {
    /// Unique name.
    pub id: Spanned<String>,
    /// x in metres.
    pub x: Spanned<f64>,
    /// y in metres.
    pub y: Spanned<f64>,
}

/// One `[[track.edges]]` entry.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EdgeFile {
    /// Start node id.
    pub from: Spanned<String>,
    /// End node id.
    pub to: Spanned<String>,
    /// Signed arc sweep in degrees, positive = left; absent or 0 = straight.
    #[serde(default)]
    pub turn_deg: Option<Spanned<f64>>,
    /// Tape width in metres; absent = 0.006.
    #[serde(default)]
    pub width_m: Option<Spanned<f64>>,
    /// `"red"` or `"blue"`; absent = black tape.
    #[serde(default)]
    pub mark: Option<Spanned<Mark>>,
}

/// One `[[obstacles]]` entry: a box on the floor.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObstacleFile {
    /// Centre x in metres.
    pub x: Spanned<f64>,
    /// Centre y in metres.
    pub y: Spanned<f64>,
    /// Extent along the box's x axis in metres.
    pub width_m: Spanned<f64>,
    /// Extent along the box's y axis in metres.
    pub height_m: Spanned<f64>,
    /// Rotation in degrees, counter-clockwise; absent = 0.
    #[serde(default)]
    pub heading_deg: Option<Spanned<f64>>,
    /// Mass in kilograms.
    pub mass_kg: Spanned<f64>,
    /// Coulomb friction coefficient against the floor; absent = 0.5.
    #[serde(default)]
    pub friction: Option<Spanned<f64>>,
}

/// One `[[robots]]` entry: where a robot starts.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotFile {
    /// Robot id.
    pub id: Spanned<u16>,
    /// Centre x in metres.
    pub x: Spanned<f64>,
    /// Centre y in metres.
    pub y: Spanned<f64>,
    /// Heading in degrees counter-clockwise from +x; absent = 0.
    #[serde(default)]
    pub heading_deg: Option<Spanned<f64>>,
}

/// `[link]`: the radio model; every key is optional.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LinkFile {
    /// A named profile the other keys start from; default `l2cap`.
    #[serde(default)]
    pub profile: Option<Spanned<String>>,
    /// One-way latency in ms; default 10.
    #[serde(default)]
    pub latency_ms: Option<Spanned<f64>>,
    /// Latency standard deviation in ms; default 2.
    #[serde(default)]
    pub jitter_ms: Option<Spanned<f64>>,
    /// Packet loss probability; default 0.
    #[serde(default)]
    pub loss: Option<Spanned<f64>>,
    /// Mean length of a fade in ms; default 0 (each packet's loss on its own).
    #[serde(default)]
    pub loss_burst_ms: Option<Spanned<f64>>,
    /// Bandwidth per piconet in kbit/s; default 700.
    #[serde(default)]
    pub bandwidth_kbps: Option<Spanned<f64>>,
    /// Robots per radio; default 7.
    #[serde(default)]
    pub robots_per_piconet: Option<Spanned<u32>>,
}

impl LinkFile {
    /// The model: the named profile (or the default), with every key given replacing its value.
    pub fn to_model(&self) -> Result<RadioModel, Problem> {
        let d = match &self.profile {
            None => RadioModel::default(),
            Some(name) => {
                RadioModel::profile(name.get_ref()).ok_or_else(|| Problem::UnknownLinkProfile {
                    name: name.get_ref().clone(),
                    known: RadioModel::profile_names(),
                })?
            }
        };
        Ok(RadioModel {
            latency_ms: value(&self.latency_ms, d.latency_ms),
            jitter_ms: value(&self.jitter_ms, d.jitter_ms),
            loss: value(&self.loss, d.loss),
            loss_burst_ms: value(&self.loss_burst_ms, d.loss_burst_ms),
            bandwidth_kbps: value(&self.bandwidth_kbps, d.bandwidth_kbps),
            robots_per_piconet: value(&self.robots_per_piconet, d.robots_per_piconet),
        })
    }
}

/// A link profile file: a `[link]` table as a world file has it, and nothing else.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct LinkProfileFile {
    link: LinkFile,
}

/// Parses and checks a link profile file's text (a `[link]` table); `origin` heads every message.
pub fn parse_link(text: &str, origin: &str) -> Result<RadioModel, WorldError> {
    let file: LinkProfileFile = toml::from_str(text).map_err(|e| WorldError::Syntax {
        origin: origin.to_owned(),
        line: e.span().map_or(1, |s| line_of(text, s.start)),
        message: syntax_message(&e, text),
    })?;
    let invalid = |problem: Problem| {
        let span = match problem.place() {
            Place::Link(key) => file.link.span_of(key),
            _ => None,
        };
        WorldError::Invalid {
            origin: origin.to_owned(),
            line: span.map_or(1, |s| line_of(text, s.start)),
            problem,
        }
    };
    let model = file.link.to_model().map_err(invalid)?;
    model.validate().map_err(invalid)?;
    Ok(model)
}

impl LinkFile {
    /// Where `key`'s value is written, when it is.
    fn span_of(&self, key: &str) -> Option<Range<usize>> {
        let l = self;
        Some(match key {
            "profile" => l.profile.as_ref()?.span(),
            "latency_ms" => l.latency_ms.as_ref()?.span(),
            "jitter_ms" => l.jitter_ms.as_ref()?.span(),
            "loss" => l.loss.as_ref()?.span(),
            "loss_burst_ms" => l.loss_burst_ms.as_ref()?.span(),
            "bandwidth_kbps" => l.bandwidth_kbps.as_ref()?.span(),
            "robots_per_piconet" => l.robots_per_piconet.as_ref()?.span(),
            _ => return None,
        })
    }
}

/// `[light]`: ambient light; every key is optional.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightFile {
    /// Ambient IR level 0..=1; default 0.2.
    #[serde(default)]
    pub ambient: Option<Spanned<f64>>,
    /// Sensor noise standard deviation; default 0.01.
    #[serde(default)]
    pub noise: Option<Spanned<f64>>,
}

fn value<T: Copy>(s: &Option<Spanned<T>>, default: T) -> T {
    s.as_ref().map_or(default, |s| *s.get_ref())
}

fn span_or<T>(field: &Option<Spanned<T>>, whole: Range<usize>) -> Range<usize> {
    field.as_ref().map_or(whole, Spanned::span)
}

impl WorldFile {
    /// The span of the value a problem is about; the entry or section when that key is absent.
    fn span_of(&self, place: Place) -> Option<Range<usize>> {
        Some(match place {
            Place::Arena("height_m") => self.arena.height_m.span(),
            Place::Arena(_) => self.arena.width_m.span(),
            Place::Node(i, key) => {
                let n = self.track.nodes.get(i)?;
                let v = n.get_ref();
                match key {
                    "id" => v.id.span(),
                    "y" => v.y.span(),
                    "x" => v.x.span(),
                    _ => n.span(),
                }
            }
            Place::Edge(i, key) => {
                let e = self.track.edges.get(i)?;
                let v = e.get_ref();
                match key {
                    "from" => v.from.span(),
                    "to" => v.to.span(),
                    "turn_deg" => span_or(&v.turn_deg, e.span()),
                    "width_m" => span_or(&v.width_m, e.span()),
                    _ => e.span(),
                }
            }
            Place::Obstacle(i, key) => {
                let o = self.obstacles.get(i)?;
                let v = o.get_ref();
                match key {
                    "x" => v.x.span(),
                    "y" => v.y.span(),
                    "heading_deg" => span_or(&v.heading_deg, o.span()),
                    "width_m" => v.width_m.span(),
                    "height_m" => v.height_m.span(),
                    "mass_kg" => v.mass_kg.span(),
                    "friction" => span_or(&v.friction, o.span()),
                    _ => o.span(),
                }
            }
            Place::Robot(i, key) => {
                let r = self.robots.get(i)?;
                let v = r.get_ref();
                match key {
                    "id" => v.id.span(),
                    "x" => v.x.span(),
                    "y" => v.y.span(),
                    "heading_deg" => span_or(&v.heading_deg, r.span()),
                    _ => r.span(),
                }
            }
            Place::Link(key) => self.link.span_of(key)?,
            Place::Light(key) => match key {
                "ambient" => self.light.ambient.as_ref()?.span(),
                "noise" => self.light.noise.as_ref()?.span(),
                _ => return None,
            },
            Place::Fault(i, key) => {
                let f = self.faults.get(i)?;
                let v = f.get_ref();
                match key {
                    "kind" => v.kind.span(),
                    "robot" => v.robot.span(),
                    "at_s" => v.at_s.span(),
                    "for_s" => span_or(&v.for_s, f.span()),
                    "amount" => span_or(&v.amount, f.span()),
                    _ => f.span(),
                }
            }
        })
    }

    /// The track the file describes, checked.
    fn build_track(&self) -> Result<Track, TrackError> {
        let nodes = self
            .track
            .nodes
            .iter()
            .map(|n| {
                let n = n.get_ref();
                Node::new(n.id.get_ref().clone(), *n.x.get_ref(), *n.y.get_ref())
            })
            .collect();
        let edges = self
            .track
            .edges
            .iter()
            .map(|e| {
                let e = e.get_ref();
                EdgeSpec {
                    from: e.from.get_ref().clone(),
                    to: e.to.get_ref().clone(),
                    turn_deg: value(&e.turn_deg, 0.0),
                    width_m: value(&e.width_m, DEFAULT_TAPE_WIDTH_M),
                    mark: e.mark.as_ref().map(|m| *m.get_ref()),
                }
            })
            .collect();
        Track::new(nodes, edges)
    }

    /// Builds the track and the world, then checks it.
    fn to_world(&self, origin: &str) -> Result<World, Problem> {
        let track = self.build_track()?;
        let obstacles = self
            .obstacles
            .iter()
            .map(|o| {
                let o = o.get_ref();
                Obstacle {
                    position: Point2::new(*o.x.get_ref(), *o.y.get_ref()),
                    width_m: *o.width_m.get_ref(),
                    height_m: *o.height_m.get_ref(),
                    heading_rad: value(&o.heading_deg, 0.0).to_radians(),
                    mass_kg: *o.mass_kg.get_ref(),
                    friction: value(&o.friction, DEFAULT_OBSTACLE_FRICTION),
                }
            })
            .collect();
        let robots = self
            .robots
            .iter()
            .map(|r| {
                let r = r.get_ref();
                RobotStart {
                    id: *r.id.get_ref(),
                    position: Point2::new(*r.x.get_ref(), *r.y.get_ref()),
                    heading_rad: value(&r.heading_deg, 0.0).to_radians(),
                }
            })
            .collect();
        let link = self.link.to_model()?;
        let d = Light::default();
        let light = Light {
            ambient: value(&self.light.ambient, d.ambient),
            noise: value(&self.light.noise, d.noise),
        };
        let world = World {
            name: self.name.clone(),
            description: self.description.clone(),
            origin: origin.to_owned(),
            arena: Arena {
                width_m: *self.arena.width_m.get_ref(),
                height_m: *self.arena.height_m.get_ref(),
            },
            track,
            obstacles,
            robots,
            link,
            light,
            seed: self.seed,
            faults: self
                .faults
                .iter()
                .enumerate()
                .map(|(i, f)| f.get_ref().to_spec(i))
                .collect::<Result<_, _>>()?,
        };
        world.validate()?;
        Ok(world)
    }
}

/// 1-based line holding byte `offset` of `text`.
fn line_of(text: &str, offset: usize) -> usize {
    // Bytes, not a str slice: an offset inside a multi-byte character must not panic.
    let end = offset.min(text.len());
    text.as_bytes()[..end]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1
}

/// The parser's description of a syntax error, or one made from where it stopped: some parse
/// errors (a file cut short, a stray character) come without a description.
fn syntax_message(e: &toml::de::Error, text: &str) -> String {
    let message = e.message().trim();
    if !message.is_empty() {
        return message.to_owned();
    }
    let at = e.span().map_or(text.len(), |s| s.start.min(text.len()));
    // The rest of the line from where the parser stopped, cut at a character boundary.
    let rest: String = text.as_bytes()[at..]
        .utf8_chunks()
        .flat_map(|c| c.valid().chars())
        .take_while(|&c| c != '\n')
        .take(40)
        .collect();
    if rest.trim().is_empty() {
        "invalid TOML: the line ends before its value or closing bracket (is the file cut short?)"
            .to_owned()
    } else {
        format!("invalid TOML at {:?}", rest.trim())
    }
}

/// Parses and checks a world file's text; `origin` (usually the file name) heads every message.
pub fn parse(text: &str, origin: &str) -> Result<World, WorldError> {
    let file: WorldFile = toml::from_str(text).map_err(|e| WorldError::Syntax {
        origin: origin.to_owned(),
        line: e.span().map_or(1, |s| line_of(text, s.start)),
        message: syntax_message(&e, text),
    })?;
    file.to_world(origin)
        .map_err(|problem| WorldError::Invalid {
            origin: origin.to_owned(),
            line: file
                .span_of(problem.place())
                .map_or(1, |s| line_of(text, s.start)),
            problem,
        })
}

/// Reads and checks the world file at `path`.
pub fn load(path: impl AsRef<Path>) -> Result<World, WorldError> {
    let path = path.as_ref();
    let origin = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|source| WorldError::Io {
        origin: origin.clone(),
        source,
    })?;
    parse(&text, &origin)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::track::Surface;

    const GOOD: &str = r#"name = "t"
description = "two nodes"

[arena]
width_m = 1.0
height_m = 1

[[track.nodes]]
id = "a"
x = 0.2
y = 0.5

[[track.nodes]]
id = "b"
x = 0.8
y = 0.5

[[track.edges]]
from = "a"
to = "b"
mark = "red"

[[robots]]
id = 3
x = 0.3
y = 0.5
"#;

    /// Replaces the first occurrence of `from` in the good file.
    fn edited(from: &str, to: &str) -> String {
        assert!(GOOD.contains(from), "{from:?} not in the test file");
        GOOD.replacen(from, to, 1)
    }

    fn line_of_text(text: &str, needle: &str) -> usize {
        let at = text.find(needle).expect("needle in text");
        line_of(text, at)
    }

    #[test]
    fn good_file_parses_with_defaults() {
        let w = parse(GOOD, "good.toml").expect("valid");
        assert_eq!(w.name, "t");
        assert_eq!(w.arena.height_m, 1.0, "an integer is accepted for a float");
        assert_eq!(w.track.edges()[0].width_m, DEFAULT_TAPE_WIDTH_M);
        assert_eq!(w.track.floor_at(Point2::new(0.5, 0.5)), Surface::RED);
        assert_eq!(w.robots[0].id, 3);
        assert_eq!(w.robots[0].heading_rad, 0.0);
        assert_eq!(w.link, RadioModel::default());
        assert_eq!(w.light, Light::default());
        assert_eq!(w.seed, None);
    }

    #[test]
    fn syntax_error_reports_its_line() {
        let text = edited("y = 0.5\n\n[[track.edges]]", "y = 0.5\n\n[[track.edges]\n");
        let err = parse(&text, "bad.toml").unwrap_err();
        let expected = line_of_text(&text, "[[track.edges]\n");
        assert!(matches!(err, WorldError::Syntax { .. }), "{err}");
        assert_eq!(err.line(), Some(expected), "{err}");
        assert!(
            err.to_string()
                .starts_with(&format!("bad.toml:{expected}: ")),
            "{err}"
        );
    }

    #[test]
    fn type_error_reports_its_line() {
        let text = edited("x = 0.8", "x = \"far\"");
        let err = parse(&text, "bad.toml").unwrap_err();
        assert!(matches!(err, WorldError::Syntax { .. }), "{err}");
        assert_eq!(
            err.line(),
            Some(line_of_text(&text, "x = \"far\"")),
            "{err}"
        );
    }

    #[test]
    fn unknown_key_and_bad_mark_report_their_lines() {
        let text = edited("mark = \"red\"", "mark = \"green\"");
        let err = parse(&text, "bad.toml").unwrap_err();
        assert_eq!(err.line(), Some(line_of_text(&text, "mark =")), "{err}");
        let text = edited("id = 3", "id = 3\nspeed = 2");
        let err = parse(&text, "bad.toml").unwrap_err();
        assert!(err.to_string().contains("speed"), "{err}");
    }

    #[test]
    fn typo_in_node_id_reports_the_edge_line() {
        let text = edited("to = \"b\"", "to = \"c\"");
        let err = parse(&text, "worlds/x.toml").unwrap_err();
        let line = line_of_text(&text, "to = \"c\"");
        assert_eq!(
            err.to_string(),
            format!("worlds/x.toml:{line}: edge 0 refers to unknown node \"c\"")
        );
    }

    #[test]
    fn semantic_errors_point_at_the_value() {
        // (edit from, edit to, text on the expected line (last occurrence), message part)
        let cases: &[(&str, &str, &str, &str)] = &[
            ("id = \"b\"", "id = \"a\"", "id = \"a\"", "repeats the id"),
            ("x = 0.8", "x = 0.2", "to = \"b\"", "zero length"),
            (
                "x = 0.3",
                "x = 1.2",
                "x = 1.2",
                "does not fit inside the arena",
            ),
            (
                "x = 0.3\ny = 0.5\n",
                "x = 0.3\ny = 0.5\n\n[[robots]]\nid = 3\nx = 0.7\ny = 0.6\n",
                "id = 3",
                "used twice",
            ),
            (
                "mark = \"red\"",
                "width_m = -0.006",
                "width_m = -0.006",
                "width_m = -0.006",
            ),
            (
                "mark = \"red\"",
                "turn_deg = 360",
                "turn_deg = 360",
                "turn_deg = 360",
            ),
            (
                "width_m = 1.0",
                "width_m = 0",
                "width_m = 0",
                "arena.width_m = 0",
            ),
            ("x = 0.2", "x = -0.1", "x = -0.1", "outside the arena"),
        ];
        for (from, to, needle, message) in cases {
            let text = edited(from, to);
            let err = parse(&text, "bad.toml").unwrap_err();
            assert!(matches!(err, WorldError::Invalid { .. }), "{to}: {err}");
            assert!(err.to_string().contains(message), "{to}: {err}");
            let at = text.rfind(needle).expect("needle in text");
            assert_eq!(err.line(), Some(line_of(&text, at)), "{to}: {err}");
        }
    }

    #[test]
    fn obstacle_errors_point_at_the_value() {
        let obstacle =
            "\n[[obstacles]]\nx = 0.5\ny = 0.2\nwidth_m = 0.04\nheight_m = 0.04\nmass_kg = -0.1\n";
        let text = format!("{GOOD}{obstacle}");
        let err = parse(&text, "bad.toml").unwrap_err();
        assert_eq!(err.line(), Some(line_of_text(&text, "mass_kg")), "{err}");
        assert!(
            err.to_string().contains("obstacles[0].mass_kg = -0.1"),
            "{err}"
        );
        let text = format!(
            "{GOOD}{}",
            obstacle
                .replace("-0.1", "0.1")
                .replace("y = 0.2", "y = 0.99")
        );
        let err = parse(&text, "bad.toml").unwrap_err();
        assert!(err.to_string().contains("obstacle 0 does not fit"), "{err}");
        let text = format!(
            "{GOOD}{}",
            obstacle
                .replace("-0.1", "0.1")
                .replace("x = 0.5\ny = 0.2", "x = 0.3\ny = 0.5")
        );
        let err = parse(&text, "bad.toml").unwrap_err();
        assert!(
            err.to_string()
                .contains("robot 3 starts on top of obstacle 0"),
            "{err}"
        );
    }

    #[test]
    fn a_link_profile_is_the_base_its_keys_override() {
        let text = format!("{GOOD}\n[link]\nprofile = \"bluetooth\"\nlatency_ms = 20\n");
        let w = parse(&text, "t.toml").unwrap();
        let b = RadioModel::profile("bluetooth").unwrap();
        assert_eq!(
            w.link,
            RadioModel {
                latency_ms: 20.0,
                ..b
            }
        );
        let text = format!("{GOOD}\n[link]\nprofile = \"fast\"\n");
        let e = parse(&text, "t.toml").unwrap_err();
        let line = GOOD.lines().count() + 3;
        assert_eq!(e.line(), Some(line), "{e}");
        assert!(
            e.to_string().contains("\"fast\" is not one of ideal"),
            "{e}"
        );
        assert_eq!(RadioModel::profile("l2cap"), Some(RadioModel::default()));
    }

    #[test]
    fn link_and_light_are_range_checked() {
        let text = format!("{GOOD}\n[link]\nloss = 1.5\n");
        let err = parse(&text, "bad.toml").unwrap_err();
        assert_eq!(err.line(), Some(line_of_text(&text, "loss")), "{err}");
        let text = format!("{GOOD}\n[light]\nambient = 0.5\nnoise = -1\n");
        let err = parse(&text, "bad.toml").unwrap_err();
        assert_eq!(err.line(), Some(line_of_text(&text, "noise")), "{err}");
        let text = format!("{GOOD}\n[link]\nlatency_ms = 3\nrobots_per_piconet = 1\n");
        let w = parse(&text, "ok.toml").expect("valid");
        assert_eq!(w.link.latency_ms, 3.0);
        assert_eq!(w.link.jitter_ms, 2.0);
    }

    #[test]
    fn robot_id_out_of_range_is_a_type_error() {
        let text = edited("id = 3", "id = 70000");
        let err = parse(&text, "bad.toml").unwrap_err();
        assert_eq!(err.line(), Some(line_of_text(&text, "id = 70000")), "{err}");
    }

    #[test]
    fn missing_file_names_the_file() {
        let err = load("/nonexistent/world.toml").unwrap_err();
        assert!(
            err.to_string().starts_with("/nonexistent/world.toml: "),
            "{err}"
        );
        assert_eq!(err.line(), None);
    }

    #[test]
    fn a_truncated_file_always_says_what_is_wrong() {
        // Every cut of a good file, including cuts inside a value, a key or a table header.
        let mut refused = 0;
        for end in 0..GOOD.len() {
            let text = &GOOD[..end];
            let Err(err) = parse(text, "cut.toml") else {
                continue;
            };
            refused += 1;
            let shown = err.to_string();
            let line = err.line().expect("a content error has a line");
            let head = format!("cut.toml:{line}: ");
            assert!(shown.starts_with(&head), "cut at {end}: {shown}");
            assert!(
                !shown[head.len()..].trim().is_empty(),
                "cut at {end}: empty message {shown:?}"
            );
        }
        assert!(refused > GOOD.len() / 2, "{refused} cuts refused");
        let err = parse("name = \"t\"\n[arena]\nwidth_m = ", "cut.toml").unwrap_err();
        assert!(
            err.to_string().starts_with("cut.toml:3: ")
                && err.to_string().len() > "cut.toml:3: ".len(),
            "{err}"
        );
    }

    /// Worlds the simulator cannot hold are refused at the line that makes them so: an arena
    /// wider than [`crate::MAX_ARENA_M`] (1e30 m once panicked in the IR index; 1e4 m aborted
    /// on a 94 GB allocation), more than [`crate::MAX_ROBOTS`] robots, and a robot heading that
    /// is no number, named as the heading rather than the x.
    #[test]
    fn worlds_too_big_to_hold_or_with_no_heading_are_refused_at_their_line() {
        for width in ["1e30", "1e4", "1000.0"] {
            let text = format!("name = \"t\"\n[arena]\nwidth_m = {width}\nheight_m = 1.0\n");
            let err = parse(&text, "big.toml").unwrap_err().to_string();
            assert!(err.starts_with("big.toml:3: arena.width_m"), "{err}");
        }
        let mut text = String::from("name = \"t\"\n[arena]\nwidth_m = 60.0\nheight_m = 60.0\n");
        for i in 0..=crate::MAX_ROBOTS {
            let (x, y) = (0.1 + (i % 500) as f64 * 0.1, 0.1 + (i / 500) as f64 * 0.1);
            text += &format!("[[robots]]\nid = {}\nx = {x:.1}\ny = {y:.1}\n", i + 1);
        }
        let err = parse(&text, "many.toml").unwrap_err().to_string();
        assert!(err.contains("2001 robots: at most 2000"), "{err}");
        let last = 4 + 4 * crate::MAX_ROBOTS + 2;
        assert!(err.starts_with(&format!("many.toml:{last}: ")), "{err}");
        let text = "name = \"t\"\n[arena]\nwidth_m = 1.0\nheight_m = 1.0\n[[robots]]\nid = 1\n\
                    x = 0.5\ny = 0.5\nheading_deg = nan\n";
        let err = parse(text, "nan.toml").unwrap_err().to_string();
        assert!(
            err.starts_with("nan.toml:9: robots[0].heading_deg"),
            "{err}"
        );
    }

    #[test]
    fn faults_in_a_world_file_are_read_and_a_bad_one_is_named_at_its_line() {
        let with = |fault: &str| format!("{GOOD}\n[[faults]]\n{fault}\n");
        let w = parse(
            &with("kind = \"loss\"\nrobot = 3\nat_s = 5\nfor_s = 2\namount = 0.5"),
            "t",
        )
        .unwrap();
        assert_eq!(w.faults.len(), 1);
        assert_eq!(w.faults[0].kind, crate::faults::FaultKind::Loss(0.5));
        assert_eq!(w.faults[0].lasting, std::time::Duration::from_secs(2));
        assert_eq!(
            parse(&with("kind = \"reboot\"\nrobot = 3\nat_s = 4"), "t")
                .unwrap()
                .faults[0]
                .kind,
            crate::faults::FaultKind::Reboot
        );
        let lines = GOOD.lines().count() + 2;
        for (fault, key, line) in [
            (
                "kind = \"jam\"\nrobot = 3\nat_s = 5\nfor_s = 2",
                "kind",
                lines + 1,
            ),
            (
                "kind = \"loss\"\nrobot = 9\nat_s = 5\nfor_s = 2",
                "robot",
                lines + 2,
            ),
            (
                "kind = \"latency\"\nrobot = 3\nat_s = 5\nfor_s = 2\namount = 5",
                "amount",
                lines + 5,
            ),
            (
                "kind = \"cut\"\nrobot = 3\nat_s = -1\nfor_s = 2",
                "at_s",
                lines + 3,
            ),
            (
                "kind = \"cut\"\nrobot = 3\nat_s = 1\nfor_s = inf",
                "for_s",
                lines + 4,
            ),
        ] {
            let e = parse(&with(fault), "t").unwrap_err();
            assert_eq!(e.line(), Some(line), "{fault}: {e}");
            assert!(
                e.to_string().contains(&format!("faults[0].{key}"))
                    || e.to_string().contains("fault 0"),
                "{fault}: {e}"
            );
        }
    }

    #[test]
    fn line_of_is_safe_inside_multibyte_text() {
        let text = "a = \"é\"\nb";
        assert_eq!(line_of(text, 6), 1);
        assert_eq!(line_of(text, 100), 2);
    }
}
