//! On-demand pacing's ledger: how many frames the consumers have asked for, which sent frames no consumer has
//! released yet, and when to send those again (a consumer that replaces one that died mid-frame). No I/O: the
//! node feeds it the events it received and asks it what to do.

use std::collections::VecDeque;

/// What the consumers' events (released, joined, died) allow.
#[derive(Debug)]
pub struct Credits {
    on_demand: bool,
    /// Frames asked for and not yet sent. A consumer that subscribed before acquisition existed sent its first
    /// credit into the void, so an existing subscriber counts as one.
    credits: u64,
    /// On demand, frames sent but not yet released by a consumer, oldest first. When a consumer (re)joins after
    /// one died, these are sent again: the instance that held them may have died with them.
    unacked: VecDeque<usize>,
    /// Set when iceoryx2 reports a consumer's notifier dead; the next consumer to join gets the frames the dead
    /// one held. A consumer joining while all others live gets none.
    consumer_died: bool,
}

/// The events of one wake-up, counted by id.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ConsumerEvents {
    pub released: u64,
    pub joined: u64,
    pub died: u64,
}

impl Credits {
    pub fn new(on_demand: bool, existing_subscriber: bool) -> Self {
        Self {
            on_demand,
            credits: u64::from(existing_subscriber),
            unacked: VecDeque::with_capacity(8),
            consumer_died: false,
        }
    }

    /// Takes in one wake-up's events. Returns the frame to continue from when a consumer replaced one that
    /// died holding frames (on demand only): those frames go out again, one credit per joined consumer.
    pub fn on_events(&mut self, events: ConsumerEvents) -> Option<usize> {
        self.credits += events.released + events.joined;
        for _ in 0..events.released {
            self.unacked.pop_front();
        }
        self.consumer_died |= events.died > 0;
        if self.on_demand && events.joined > 0 && self.consumer_died {
            self.consumer_died = false;
            if let Some(&first) = self.unacked.front() {
                self.unacked.clear();
                self.credits = events.joined;
                return Some(first);
            }
        }
        None
    }

    /// On demand with no frame asked for: the next frame waits for a consumer.
    pub fn waiting_for_consumer(&self) -> bool {
        self.on_demand && self.credits == 0
    }

    /// A frame goes out: it spends a credit (on demand).
    pub fn spend(&mut self) {
        if self.on_demand {
            self.credits = self.credits.saturating_sub(1);
        }
    }

    /// The frame a credit was spent on could not be sent (a video frame its decoder lost): the credit goes to
    /// the next frame.
    pub fn refund(&mut self) {
        if self.on_demand {
            self.credits += 1;
        }
    }

    /// Frame `index` was sent; on demand it is held until a consumer releases it.
    pub fn sent(&mut self, index: usize) {
        if self.on_demand {
            self.unacked.push_back(index);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn released(n: u64) -> ConsumerEvents {
        ConsumerEvents { released: n, ..Default::default() }
    }

    #[test]
    fn a_subscriber_that_existed_before_acquisition_counts_as_one_credit() {
        assert!(!Credits::new(true, true).waiting_for_consumer());
        assert!(Credits::new(true, false).waiting_for_consumer());
        // Paced by time, nobody is waited for.
        assert!(!Credits::new(false, false).waiting_for_consumer());
    }

    #[test]
    fn each_release_allows_one_more_frame() {
        let mut c = Credits::new(true, false);
        assert_eq!(c.on_events(ConsumerEvents { joined: 1, ..Default::default() }), None);
        assert!(!c.waiting_for_consumer());
        c.spend();
        c.sent(0);
        assert!(c.waiting_for_consumer());
        assert_eq!(c.on_events(released(1)), None);
        assert!(!c.waiting_for_consumer());
    }

    #[test]
    fn a_consumer_that_replaces_a_dead_one_gets_the_frames_it_held() {
        let mut c = Credits::new(true, true);
        for i in 0..3 {
            c.spend();
            c.sent(i);
            c.on_events(ConsumerEvents { released: u64::from(i == 0), ..Default::default() });
        }
        // Frame 0 released; 1 and 2 held when the consumer died.
        assert_eq!(c.on_events(ConsumerEvents { died: 1, ..Default::default() }), None);
        assert_eq!(c.on_events(ConsumerEvents { joined: 1, ..Default::default() }), Some(1));
        // One credit for the one consumer that joined; the replay is not repeated for the next joiner.
        assert!(!c.waiting_for_consumer());
        c.spend();
        assert!(c.waiting_for_consumer());
        assert_eq!(c.on_events(ConsumerEvents { joined: 1, ..Default::default() }), None);
    }

    #[test]
    fn a_consumer_joining_while_all_others_live_gets_no_replay() {
        let mut c = Credits::new(true, true);
        c.spend();
        c.sent(0);
        assert_eq!(c.on_events(ConsumerEvents { joined: 1, ..Default::default() }), None);
    }

    #[test]
    fn a_frame_that_could_not_be_sent_gives_its_credit_to_the_next() {
        let mut c = Credits::new(true, true);
        c.spend();
        assert!(c.waiting_for_consumer());
        // The video's decoder lost that frame: nothing went out, the consumer still waits for one.
        c.refund();
        assert!(!c.waiting_for_consumer());
        c.spend();
        c.sent(1);
        assert!(c.waiting_for_consumer());
    }

    #[test]
    fn paced_by_time_nothing_is_replayed() {
        let mut c = Credits::new(false, false);
        c.sent(0);
        c.on_events(ConsumerEvents { died: 1, ..Default::default() });
        assert_eq!(c.on_events(ConsumerEvents { joined: 1, ..Default::default() }), None);
    }
}
