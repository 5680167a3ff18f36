//! When a sample that is catching up may be published. What the sender sends again after a restart or a broken
//! link arrives at once; the consumers on the receiving host have the topics' small buffers (the mosaic's depth
//! buffer is 4), sized for the pace the samples were produced at, so a backlog published at once overwrites
//! some. A catching-up sample is due after the one published before it by their gap at the producer, over
//! [`CATCH_UP`], and never more than [`LONGEST_PAUSE`] after it.

use std::time::{Duration, Instant};

/// A backlog is published this many times as fast as it was produced: fast enough to catch up (an outage of T
/// seconds is made good in T more), slow enough for any consumer that kept up live using less than half its core.
pub const CATCH_UP: u32 = 2;
/// The longest pause kept in a replay (a scope held still is not replayed).
pub const LONGEST_PAUSE: Duration = Duration::from_millis(250);

#[derive(Debug, Default)]
pub struct Pace {
    /// When the last sample was published here, and when its producer's side sent it (its clock).
    last: Option<(Instant, u64)>,
}

impl Pace {
    /// How long a sample its producer's side sent at `t_sent_ns` must still wait at `now` (`None`: it is due).
    pub fn wait(&self, t_sent_ns: u64, now: Instant) -> Option<Duration> {
        let (at, sent) = self.last?;
        let gap = (Duration::from_nanos(t_sent_ns.saturating_sub(sent)) / CATCH_UP).min(LONGEST_PAUSE);
        (at + gap).checked_duration_since(now).filter(|left| !left.is_zero())
    }

    /// A sample sent at `t_sent_ns` was published at `now`.
    pub fn published(&mut self, t_sent_ns: u64, now: Instant) {
        self.last = Some((now, t_sent_ns));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_backlog_goes_out_at_twice_its_pace_with_no_pause_beyond_the_longest() {
        let ms = |n: u64| Duration::from_millis(n);
        let start = Instant::now();
        let mut pace = Pace::default();
        assert_eq!(pace.wait(0, start), None, "the first is due at once");
        pace.published(0, start);
        // Sent 70 ms after the first: due 35 ms after it was published.
        assert_eq!(pace.wait(70_000_000, start + ms(10)), Some(ms(25)));
        assert_eq!(pace.wait(70_000_000, start + ms(35)), None);
        pace.published(70_000_000, start + ms(35));
        // Sent out of order (a redone keyframe): due at once.
        assert_eq!(pace.wait(10_000_000, start + ms(35)), None);
        // Sent 10 s later (a still scope): at most LONGEST_PAUSE.
        assert_eq!(pace.wait(10_070_000_000, start + ms(35)), Some(LONGEST_PAUSE));
    }
}
