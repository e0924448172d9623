//! State updates in batches: robots on a shard arbiter hand their states to a per-thread buffer
//! that goes out as one [`StateBatch`] per subscriber once the arbiter has run every robot that
//! was ready. A subscriber on another thread then takes one message (one allocation, one wake)
//! for many frames instead of one each, which is what capped the world model's intake.

use std::cell::RefCell;

use actix::prelude::*;

use super::StateUpdated;

/// State updates from the robots of one arbiter, in the order they were published (so in order
/// per robot).
#[derive(Clone, Debug, Message)]
#[rtype(result = "()")]
pub struct StateBatch(pub Vec<StateUpdated>);

/// Registers a subscriber taking states in batches.
#[derive(Message)]
#[rtype(result = "()")]
pub struct SubscribeBatches(pub Recipient<StateBatch>);

/// States waiting on this thread for the flush, per subscriber.
#[derive(Default)]
struct Pending {
    batches: Vec<(Recipient<StateBatch>, Vec<StateUpdated>)>,
    flush_spawned: bool,
}

thread_local! {
    static PENDING: RefCell<Pending> = RefCell::new(Pending::default());
}

/// Queues `u` for `to`; the first state queued since the last flush spawns the flush, which runs
/// after the tasks already woken on this arbiter (the other robots with frames waiting).
///
/// The flush first yields: a task spawned here is queued locally and would run before robots
/// woken from other threads (the links' I/O), which wait in the arbiter's shared queue, so
/// batches were of one or two states. A yield defers it to the end of the scheduler's pass (up to
/// 61 tasks): 10,000 links went from 1.06 to about 46 states per batch at 500,000 frames/s.
pub(super) fn push(to: &Recipient<StateBatch>, u: StateUpdated) {
    let spawn = PENDING.with_borrow_mut(|p| {
        match p.batches.iter_mut().find(|(r, _)| r == to) {
            Some((_, states)) => states.push(u),
            None => p.batches.push((to.clone(), vec![u])),
        }
        !std::mem::replace(&mut p.flush_spawned, true)
    });
    if spawn {
        actix::spawn(async {
            tokio::task::yield_now().await;
            flush()
        });
    }
}

/// Sends every state queued on this thread. A robot calls it before it sends an event, so a
/// subscriber still hears of a robot's states and events in the order they happened.
pub(super) fn flush() {
    PENDING.with_borrow_mut(|p| {
        p.flush_spawned = false;
        // The subscribers stay listed, so a flush clones no address (an atomic count each, and
        // a wake-up check on drop); the ones gone are dropped. Sending only queues the batch and
        // wakes the subscriber's task: it cannot come back here.
        p.batches.retain(|(to, _)| to.connected());
        for (to, states) in &mut p.batches {
            if !states.is_empty() {
                to.do_send(StateBatch(std::mem::take(states)));
            }
        }
    });
}
