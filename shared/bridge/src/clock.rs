//! The sender's clock in the receiver's. Every time in the pipeline's messages is its host's CLOCK_MONOTONIC,
//! which means nothing on another host, so the receiver translates a sample's capture time into its own clock
//! before publishing it (the far host's latency report then measures capture → map). The offset is the least
//! `received here − sent there` seen: the clocks' difference plus the link's shortest delay, so a translated time
//! is late by at most that shortest delay (0.3 ms on loopback here) — on one host, where the clocks are the
//! same, exactly by it.

#[derive(Debug, Default, Clone, Copy)]
pub struct ClockOffset {
    offset_ns: Option<i128>,
}

impl ClockOffset {
    /// A sample sent at `t_sent_there` (the sender's clock) was received at `t_received_here`.
    pub fn observe(&mut self, t_sent_there: u64, t_received_here: u64) {
        let d = i128::from(t_received_here) - i128::from(t_sent_there);
        self.offset_ns = Some(self.offset_ns.map_or(d, |o| o.min(d)));
    }

    /// A time of the sender's clock in this host's; 0 (unset) stays 0.
    pub fn here(&self, t_there: u64) -> u64 {
        match (t_there, self.offset_ns) {
            (0, _) | (_, None) => t_there,
            (t, Some(o)) => u64::try_from(i128::from(t) + o).unwrap_or(0),
        }
    }

    /// The least delay seen, in this host's terms (the offset itself), ns.
    pub fn offset_ns(&self) -> Option<i128> {
        self.offset_ns
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn times_move_by_the_least_offset_seen() {
        let mut clock = ClockOffset::default();
        assert_eq!(clock.here(5), 5, "nothing seen: unchanged");
        // The far clock is 1 s behind; the link takes 200–900 µs.
        clock.observe(10_000_000_000, 11_000_900_000);
        clock.observe(10_100_000_000, 11_100_200_000);
        clock.observe(10_200_000_000, 11_200_500_000);
        assert_eq!(clock.offset_ns(), Some(1_000_200_000));
        assert_eq!(clock.here(10_000_000_000), 11_000_200_000);
        assert_eq!(clock.here(0), 0);
        // A far clock ahead of this one.
        let mut ahead = ClockOffset::default();
        ahead.observe(50_000, 20_000);
        assert_eq!(ahead.here(40_000), 10_000);
        assert_eq!(ahead.here(1), 0, "before this clock's start: clamped, not wrapped");
    }
}
