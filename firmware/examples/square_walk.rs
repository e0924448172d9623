//! The thesis's "hello robot" square walk (Appendix A.1) against the firmware on the kinematic mock
//! board: the host side speaks only protocol packets, the robot side is the unmodified firmware.
//!
//! Prints the reflected encoder totals and the board's true pose as the robot walks, then how far
//! from its start the square closed.

use firmware::mock::{MockBoard, MockRobot};
use firmware::protocol::packets::{
    Ping, ReflectorConfig, ReflectorMode, RotationMovement, StraightMovement,
};
use firmware::protocol::AnyPacket;
use firmware::Duration;

fn main() {
    let mut robot = MockRobot::new(MockBoard::default());
    robot.fw.on_link_connected(robot.now);
    robot.send(ReflectorConfig {
        mode: ReflectorMode::Full as u8,
        period_ms: 250,
    });
    for i in 0..4u16 {
        robot.send(StraightMovement {
            distance_m: 0.1,
            speed_mps: 0.2,
            move_id: 2 * i,
        });
        robot.send(RotationMovement {
            angle_deg: 90.0,
            speed_mps: 0.2,
            move_id: 2 * i + 1,
        });
    }
    println!("  t [s]   left  right   true x [mm]  true y [mm]  heading [deg]");
    let mut done = false;
    while !done && robot.now.as_millis() < 20_000 {
        // The host pings every 100 ms; without it the robot's watchdog would stop it.
        robot.send(Ping {
            seq: 0,
            host_time_us: robot.now.as_micros(),
        });
        let mut latest = None;
        robot.run(Duration::from_millis(100), |t, p| match p {
            AnyPacket::Hello(h) => println!(
                "hello from robot {} (protocol {}, settings layout {:016x})",
                { h.robot_id },
                { h.protocol_version },
                { h.settings_hash }
            ),
            AnyPacket::State(s) => latest = Some((t, s)),
            AnyPacket::MoveFinished(m) => println!("move {} finished", { m.move_id }),
            AnyPacket::QueueEmpty(_) => done = true,
            _ => {}
        });
        if let Some((t, s)) = latest {
            let p = robot.fw.board().pose;
            println!(
                "{:7.2} {:6} {:6} {:13.1} {:12.1} {:14.1}",
                t.as_millis() as f64 / 1e3,
                { s.encoders.left_ticks },
                { s.encoders.right_ticks },
                p.x * 1e3,
                p.y * 1e3,
                p.theta.to_degrees()
            );
        }
    }
    robot.run(Duration::from_millis(200), |_, _| {});
    let p = robot.fw.board().pose;
    println!(
        "square closed {:.1} mm from its start, heading error {:.1} deg, after {:.2} s",
        p.x.hypot(p.y) * 1e3,
        (p.theta.to_degrees() - 360.0),
        robot.now.as_millis() as f64 / 1e3
    );
}
