//! The buffer a host's packets wait in until the next step hands them to the link, what it
//! drops when full, and the sink that takes a robot's packets instead of the channel.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

use crate::link::{PacketQueue, LINK_BUFFER_BYTES};

/// What a host's side of one link has dropped for a full buffer, as (packets, bytes) per
/// direction, not yet counted in the simulation.
#[derive(Default)]
pub(super) struct Dropped {
    pub(super) to_robot: (u64, u64),
    pub(super) to_host: (u64, u64),
}

/// Where the stepping task hands a robot's packets when a reader has asked for them directly
/// ([`LinkSender::set_sink`](super::LinkSender::set_sink)): `Some(packet)`, or `None` once the
/// simulation has stopped. It returns `false` once its reader is gone.
pub type Sink = Box<dyn FnMut(Option<Vec<u8>>) -> bool + Send>;

/// Host packets on their way into the simulation, shared by a link end and the stepping task.
pub(super) struct HostBuffer {
    inbox: Mutex<(PacketQueue, Dropped)>,
    pub(super) stopped: AtomicBool,
    /// A reader's sink with its key, which takes the robot's packets instead of the channel.
    sink: Mutex<Option<(u64, Sink)>>,
    /// Every robot's "something to drain" flag, in one allocation, so the stepping task finds the
    /// few buffers to drain each step without touching every robot's lock.
    waiting: Arc<[AtomicBool]>,
    index: usize,
}

impl HostBuffer {
    pub(super) fn new(waiting: Arc<[AtomicBool]>, index: usize) -> Self {
        Self {
            inbox: Mutex::new((PacketQueue::new(LINK_BUFFER_BYTES), Dropped::default())),
            stopped: AtomicBool::new(false),
            sink: Mutex::new(None),
            waiting,
            index,
        }
    }

    /// Flags this buffer for the next step's drain; called after the inbox changed.
    fn mark(&self) {
        self.waiting[self.index].store(true, Ordering::Release);
    }

    pub(super) fn lock(&self) -> std::sync::MutexGuard<'_, (PacketQueue, Dropped)> {
        // The guarded data stays consistent whatever panicked while holding it.
        self.inbox.lock().unwrap_or_else(PoisonError::into_inner)
    }

    pub(super) fn sink(&self) -> std::sync::MutexGuard<'_, Option<(u64, Sink)>> {
        self.sink.lock().unwrap_or_else(PoisonError::into_inner)
    }

    pub(super) fn send(&self, packet: &[u8]) -> bool {
        if self.stopped.load(Ordering::Acquire) {
            return false;
        }
        let mut guard = self.lock();
        let (queue, dropped) = &mut *guard;
        if queue.fits(packet.len()) {
            let _ = queue.push(0, packet.to_vec());
        } else {
            dropped.to_robot.0 += 1;
            dropped.to_robot.1 += packet.len() as u64;
        }
        drop(guard);
        self.mark();
        true
    }

    pub(super) fn dropped_to_host(&self, bytes: usize) {
        let mut guard = self.lock();
        guard.1.to_host.0 += 1;
        guard.1.to_host.1 += bytes as u64;
        drop(guard);
        self.mark();
    }
}

/// Marks the host buffers stopped however the stepping task ends (returned, or dropped with its
/// runtime), so senders learn it.
pub(super) struct StopOnDrop(pub(super) Vec<Arc<HostBuffer>>);

impl Drop for StopOnDrop {
    fn drop(&mut self) {
        for b in &self.0 {
            // Under the sink's lock, so a sink set at the same time hears of the stop either way.
            let mut slot = b.sink();
            b.stopped.store(true, Ordering::Release);
            if let Some((_, mut sink)) = slot.take() {
                sink(None);
            }
        }
    }
}
