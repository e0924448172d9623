//! The small enums carried inside packets as `u8` codes: modes, sides, marks, levels, outcomes
//! and reasons.

macro_rules! code_enum {
    ($(#[$meta:meta])* pub enum $name:ident { $($(#[doc = $vdoc:literal])* $var:ident = $val:literal),* $(,)? }) => {
        $(#[$meta])*
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
        #[repr(u8)]
        pub enum $name { $($(#[doc = $vdoc])* $var = $val),* }

        impl $name {
            /// Every variant, in code order.
            pub const ALL: &'static [Self] = &[$(Self::$var),*];

            /// The variant's name.
            pub fn name(self) -> &'static str {
                match self { $(Self::$var => stringify!($var)),* }
            }

            /// The variant's doc comment, lines joined.
            pub fn doc(self) -> &'static str {
                match self { $(Self::$var => concat!($($vdoc),*)),* }
            }
        }

        impl TryFrom<u8> for $name {
            type Error = u8;
            fn try_from(v: u8) -> Result<Self, u8> {
                match v { $($val => Ok(Self::$var),)* other => Err(other) }
            }
        }
    };
}

code_enum! {
    /// What the state reflector sends (thesis 9.7).
    pub enum ReflectorMode {
        /// Nothing.
        None = 0,
        /// The whole [`RobotState`](crate::state::RobotState).
        Full = 1,
        /// The [`ReducedState`](crate::state::ReducedState).
        Reduced = 2,
    }
}

code_enum! {
    /// Who drives the motors right now.
    pub enum DriveMode {
        /// Motors off, nothing queued.
        Idle = 0,
        /// Executing the move queue.
        Moves = 1,
        /// Following the line.
        LineFollow = 2,
        /// Holding teleoperated wheel speeds.
        WheelSpeeds = 3,
        /// Applying teleoperated motor duties directly.
        MotorPower = 4,
    }
}

code_enum! {
    /// Which receiver saw an IR frame.
    pub enum Side {
        /// Front receiver.
        Front = 0,
        /// Rear receiver.
        Rear = 1,
    }
}

code_enum! {
    /// What made the robot report a bump.
    pub enum BumpCause {
        /// The accelerometer felt a jolt the wheel speeds do not explain.
        Jolt = 1,
        /// The wheels turned while the robot stood idle with its motors off.
        WheelsWhileIdle = 2,
    }
}

code_enum! {
    /// Colour mark on the track under the robot.
    pub enum Mark {
        /// White floor or black tape.
        None = 0,
        /// Red segment: slow down.
        Red = 1,
        /// Blue segment: speed up.
        Blue = 2,
    }
}

code_enum! {
    /// Verbosity of a log message (thesis 6.2.3); lower is more severe.
    pub enum LogLevel {
        /// Unrecoverable error.
        Error = 1,
        /// Something the host should know about.
        Warn = 2,
        /// Module start-up and normal operation.
        Info = 3,
        /// Detailed tracing.
        Debug = 4,
    }
}

code_enum! {
    /// Line sensor calibration step.
    pub enum CalibrationAction {
        /// Forget the extremes and start recording them while the robot is swept over the line.
        Start = 1,
        /// Stop recording and adopt the recorded extremes as white and black.
        Finish = 2,
        /// Restore the factory calibration.
        Reset = 3,
    }
}

code_enum! {
    /// How a move ended.
    pub enum MoveOutcome {
        /// Reached its distance or angle.
        Completed = 0,
        /// Removed by a clear-queue command before or while running.
        Cleared = 1,
        /// Aborted by a stop command or the watchdog.
        Stopped = 2,
        /// Stopped by the proximity reflex: something close in the way.
        Blocked = 3,
    }
}

code_enum! {
    /// Why a command was not carried out.
    pub enum NackReason {
        /// The move queue is full.
        QueueFull = 1,
        /// A settings range was out of bounds or split a field.
        BadSettingsRange = 2,
        /// A parameter was not finite or out of its range.
        BadParameter = 3,
        /// Settings storage failed.
        StorageFailed = 4,
        /// The frame's type code is not in the table; the Nack's `packet_type` is that code.
        UnknownType = 5,
        /// The payload length is not one the type allows, or a settings update's `len` disagrees
        /// with the bytes it carries.
        BadLength = 6,
        /// A settings value is outside its documented range; the Nack names the field's offset.
        BadSettingValue = 7,
    }
}
