//! What a behaviour may ask for: an [`Intent`] per robot, each passing the supervisor's safety
//! check before it reaches the robot.

use protocol::MoveCommand;

/// What a behaviour asks the supervisor to do; every intent passes its safety check first.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Intent {
    /// Queue a move.
    Move {
        /// Robot id.
        robot: u16,
        /// The move.
        command: MoveCommand,
        /// The behaviour's word for the move, returned in its `Event::MoveFinished`.
        tag: u32,
    },
    /// Follow the line at a speed, or stop following (`None`).
    FollowLine {
        /// Robot id.
        robot: u16,
        /// Speed, m/s.
        speed: Option<f32>,
    },
    /// Hold wheel speeds, m/s.
    WheelSpeeds {
        /// Robot id.
        robot: u16,
        /// Left wheel.
        left: f32,
        /// Right wheel.
        right: f32,
    },
    /// Drop the robot's queued moves.
    ClearQueue {
        /// Robot id.
        robot: u16,
    },
    /// Stop one robot.
    Stop {
        /// Robot id.
        robot: u16,
    },
    /// Set a robot's LED.
    Led {
        /// Robot id.
        robot: u16,
        /// Colour.
        rgb: [u8; 3],
    },
    /// Attach a message word to a robot's IR frames.
    IrMessage {
        /// Robot id.
        robot: u16,
        /// Message.
        message: u16,
    },
    /// Set the robot's proximity reflex: it stops any drive towards a surface that returns its
    /// own light at this power level or weaker (1, the default: within about 15 mm); 0 turns it
    /// off, for a behaviour that must close in (pushing a box).
    Reflex {
        /// Robot id.
        robot: u16,
        /// Power level, 0 off.
        power_level: u8,
    },
}

impl Intent {
    /// The robot the intent is for.
    pub fn robot(&self) -> u16 {
        match *self {
            Intent::Move { robot, .. }
            | Intent::FollowLine { robot, .. }
            | Intent::WheelSpeeds { robot, .. }
            | Intent::ClearQueue { robot }
            | Intent::Stop { robot }
            | Intent::Led { robot, .. }
            | Intent::IrMessage { robot, .. }
            | Intent::Reflex { robot, .. } => robot,
        }
    }
}

impl Intent {
    /// `commands` for `robot`, in order, each tagged `tag`.
    pub fn moves(
        robot: u16,
        commands: impl IntoIterator<Item = MoveCommand>,
        tag: u32,
    ) -> Vec<Intent> {
        commands
            .into_iter()
            .map(|command| Intent::Move {
                robot,
                command,
                tag,
            })
            .collect()
    }
}
