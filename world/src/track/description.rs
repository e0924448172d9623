//! A track as a user describes it: named nodes, edges naming their end nodes, and why a
//! description is refused.

use nalgebra::Point2;

use super::{Mark, DEFAULT_TAPE_WIDTH_M, MAX_TAPE_WIDTH_M};

/// A named point of the track where edges start or end.
#[derive(Clone, Debug, PartialEq)]
pub struct Node {
    /// Name used by edges, world files and the coordinator.
    pub id: String,
    /// Position on the floor in metres.
    pub position: Point2<f64>,
}

impl Node {
    /// A node called `id` at (`x`, `y`) metres.
    pub fn new(id: impl Into<String>, x: f64, y: f64) -> Self {
        Node {
            id: id.into(),
            position: Point2::new(x, y),
        }
    }
}

/// An edge as described by a user, naming its end nodes; [`Track::new`](super::Track::new)
/// resolves and checks it.
#[derive(Clone, Debug, PartialEq)]
pub struct EdgeSpec {
    /// Id of the start node.
    pub from: String,
    /// Id of the end node.
    pub to: String,
    /// Signed sweep of the arc from `from` to `to` in degrees, positive = turning left
    /// (counter-clockwise); 0 is a straight line. Must lie strictly between -360 and 360.
    pub turn_deg: f64,
    /// Tape width in metres.
    pub width_m: f64,
    /// Colour of the whole edge; `None` is black tape.
    pub mark: Option<Mark>,
}

impl EdgeSpec {
    /// A straight black edge of the default width.
    pub fn straight(from: impl Into<String>, to: impl Into<String>) -> Self {
        Self::arc(from, to, 0.0)
    }

    /// A black arc of the default width sweeping `turn_deg` (positive = left) from `from` to `to`.
    pub fn arc(from: impl Into<String>, to: impl Into<String>, turn_deg: f64) -> Self {
        EdgeSpec {
            from: from.into(),
            to: to.into(),
            turn_deg,
            width_m: DEFAULT_TAPE_WIDTH_M,
            mark: None,
        }
    }

    /// The same edge with a colour mark.
    pub fn with_mark(mut self, mark: Mark) -> Self {
        self.mark = Some(mark);
        self
    }
}

/// Which end of an edge a problem concerns.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EdgeEnd {
    /// The `from` end.
    From,
    /// The `to` end.
    To,
}

/// Why a track description was refused.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum TrackError {
    /// Two nodes share an id.
    #[error("node {node} repeats the id \"{id}\" of an earlier node")]
    DuplicateNode {
        /// Index of the later node.
        node: usize,
        /// The repeated id.
        id: String,
    },
    /// A node position is NaN or infinite.
    #[error("node {node} (\"{id}\") has a position that is not a finite number")]
    NonFiniteNode {
        /// Index of the node.
        node: usize,
        /// Its id.
        id: String,
    },
    /// An edge names a node that does not exist.
    #[error("edge {edge} refers to unknown node \"{id}\"")]
    UnknownNode {
        /// Index of the edge.
        edge: usize,
        /// Which end names the node.
        end: EdgeEnd,
        /// The unknown id.
        id: String,
    },
    /// An edge's ends coincide, so it has no length and no direction.
    #[error("edge {edge} has zero length: its end nodes \"{from}\" and \"{to}\" coincide")]
    ZeroLength {
        /// Index of the edge.
        edge: usize,
        /// Id of its start node.
        from: String,
        /// Id of its end node.
        to: String,
    },
    /// An arc sweep outside (-360, 360) or not a number.
    #[error("edge {edge} has turn_deg = {turn_deg}; it must lie strictly between -360 and 360")]
    BadTurn {
        /// Index of the edge.
        edge: usize,
        /// The refused sweep.
        turn_deg: f64,
    },
    /// A tape width that is not positive, or wider than [`MAX_TAPE_WIDTH_M`].
    #[error("edge {edge} has width_m = {width_m}; it must be above 0 and at most {MAX_TAPE_WIDTH_M} (metres)")]
    BadWidth {
        /// Index of the edge.
        edge: usize,
        /// The refused width.
        width_m: f64,
    },
}
