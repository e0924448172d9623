//! A connector wrapper that records every packet through its links.

use std::sync::atomic::{AtomicU16, AtomicU32, Ordering};
use std::sync::Arc;

use futures::future::BoxFuture;
use protocol::packets::AnyPacket;
use protocol::Frame;
use robot_actor::link::{Connector, Link, LinkError, LinkEvent, SEND_QUEUE};
use tokio::sync::mpsc;

use super::format::Dir;
use super::writer::Recorder;

/// Wraps a connector so every packet through its links, both ways, is recorded.
pub struct Tap {
    inner: Arc<dyn Connector>,
    index: usize,
    robot: Arc<AtomicU16>,
    links: AtomicU32,
    recorder: Arc<Recorder>,
}

impl Tap {
    /// Taps robot `index`'s connector; `robot` is its id if known already (0 otherwise: the tap
    /// learns it from the robot's hello).
    pub fn new(
        inner: Arc<dyn Connector>,
        index: usize,
        robot: u16,
        recorder: Arc<Recorder>,
    ) -> Self {
        Self {
            inner,
            index,
            robot: Arc::new(AtomicU16::new(robot)),
            links: AtomicU32::new(0),
            recorder,
        }
    }
}

impl Connector for Tap {
    fn peer(&self) -> String {
        self.inner.peer()
    }

    fn connect(&self) -> BoxFuture<'static, Result<Link, LinkError>> {
        let opening = self.inner.connect();
        let (index, robot, recorder) = (self.index, Arc::clone(&self.robot), self.recorder.clone());
        let link_no = self.links.fetch_add(1, Ordering::Relaxed);
        Box::pin(async move {
            let link = opening.await?;
            let (tx, mut from_actor) = mpsc::channel::<Vec<u8>>(SEND_QUEUE);
            let (to_actor, rx) = mpsc::unbounded_channel();
            let (inner_tx, mut inner_rx) = (link.tx, link.rx);
            let rec = recorder.clone();
            let id = Arc::clone(&robot);
            tokio::spawn(async move {
                while let Some(p) = from_actor.recv().await {
                    rec.packet(index, id.load(Ordering::Relaxed), link_no, Dir::Tx, &p);
                    if inner_tx.send(p).await.is_err() {
                        break;
                    }
                }
            });
            tokio::spawn(async move {
                while let Some(event) = inner_rx.recv().await {
                    match &event {
                        LinkEvent::Packet(p) => {
                            if let Ok(frame) = Frame::parse(p) {
                                if let AnyPacket::Hello(h) = frame.packet() {
                                    robot.store(h.robot_id, Ordering::Relaxed);
                                }
                            }
                            recorder.packet(
                                index,
                                robot.load(Ordering::Relaxed),
                                link_no,
                                Dir::Rx,
                                p,
                            );
                        }
                        LinkEvent::Closed(_) => recorder.packet(
                            index,
                            robot.load(Ordering::Relaxed),
                            link_no,
                            Dir::Closed,
                            &[],
                        ),
                    }
                    if to_actor.send(event).is_err() {
                        break;
                    }
                }
            });
            Ok(Link {
                peer: link.peer,
                tx,
                rx,
                counters: link.counters,
            })
        })
    }
}
