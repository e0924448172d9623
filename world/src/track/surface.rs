//! What the floor looks like to a downward-looking sensor: bare floor, black tape, coloured marks.

use serde::{Deserialize, Serialize};

/// Colour mark of a whole edge. The firmware's colour sensor treats red as "slow down" and blue as
/// "speed up" (`protocol::packets::Mark`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Mark {
    /// Red tape.
    Red,
    /// Blue tape.
    Blue,
}

/// What a downward-looking sensor sees at one point of the floor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Surface {
    /// Fraction of infrared light reflected: white floor 1.0, black tape 0.08, coloured marks 0.35
    /// (darker than the floor, so the IR line sensor still sees them as line).
    pub ir_reflectance: f32,
    /// Visible colour as linear RGB in 0..=1, for the colour sensor and for drawing.
    pub rgb: [f32; 3],
}

impl Surface {
    /// Bare white floor.
    pub const WHITE: Surface = Surface {
        ir_reflectance: 1.0,
        rgb: [1.0, 1.0, 1.0],
    };
    /// Plain black tape.
    pub const BLACK: Surface = Surface {
        ir_reflectance: 0.08,
        rgb: [0.05, 0.05, 0.05],
    };
    /// Red mark.
    pub const RED: Surface = Surface {
        ir_reflectance: 0.35,
        rgb: [0.8, 0.1, 0.1],
    };
    /// Blue mark.
    pub const BLUE: Surface = Surface {
        ir_reflectance: 0.35,
        rgb: [0.1, 0.2, 0.8],
    };

    /// The tape surface of an edge with this mark.
    pub const fn of_tape(mark: Option<Mark>) -> Surface {
        match mark {
            None => Surface::BLACK,
            Some(Mark::Red) => Surface::RED,
            Some(Mark::Blue) => Surface::BLUE,
        }
    }
}
