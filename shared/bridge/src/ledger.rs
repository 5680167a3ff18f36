//! What each side of a bridge remembers. The sender keeps every sample until the receiver says it has published
//! it ([`Outbox`]); in each new conversation (a receiver's HELLO: it started, or the sender did, or the link came
//! back) it sends again what is left, less what that HELLO says the receiver already has. The receiver publishes a sample only if it is newer than the last of its topic ([`Inbox`]), so a
//! sample sent twice is published once. Ids are the samples' own: a depth keyframe's id, the end of a stream
//! `u64::MAX`, a correction its generation and its place in it ([`CorrectionIds`]).

use std::collections::VecDeque;

use crate::Carried;

/// A sample on its way: its topic, its id and its whole SAMPLE frame.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Entry {
    pub topic: Carried,
    pub id: u64,
    pub frame: Vec<u8>,
}

/// The sender's samples not yet acknowledged, oldest first, within a byte budget.
#[derive(Debug)]
pub struct Outbox {
    entries: VecDeque<Entry>,
    bytes: usize,
    budget: usize,
    /// Entries written in the current conversation (the first `sent` of `entries`, less those acknowledged).
    sent: usize,
    /// Acknowledged in the current conversation so far.
    acked: u64,
    /// Samples given up because the budget was exceeded (the link was down too long).
    pub overflowed: u64,
}

impl Outbox {
    pub fn new(budget_bytes: usize) -> Self {
        Self { entries: VecDeque::new(), bytes: 0, budget: budget_bytes, sent: 0, acked: 0, overflowed: 0 }
    }

    pub fn len(&self) -> usize {
        self.entries.len()
    }

    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    pub fn bytes(&self) -> usize {
        self.bytes
    }

    /// Queues a sample; the oldest unsent ones go when the budget is exceeded (never the newest).
    pub fn push(&mut self, entry: Entry) {
        self.bytes += entry.frame.len();
        self.entries.push_back(entry);
        while self.bytes > self.budget && self.entries.len() > self.sent + 1 {
            if let Some(gone) = self.entries.remove(self.sent) {
                self.bytes -= gone.frame.len();
                self.overflowed += 1;
            }
        }
    }

    /// A new conversation: nothing is sent in it yet, and what the receiver already published (its HELLO) is
    /// dropped.
    pub fn connected(&mut self, receiver_has: &[(Carried, Option<u64>)]) {
        self.sent = 0;
        self.acked = 0;
        let has = |topic: Carried| receiver_has.iter().find(|(t, _)| *t == topic).and_then(|(_, id)| *id);
        let before = self.entries.len();
        self.entries.retain(|e| has(e.topic).is_none_or(|last| e.id > last));
        if self.entries.len() != before {
            self.bytes = self.entries.iter().map(|e| e.frame.len()).sum();
        }
    }

    /// The entries still to send in this conversation.
    pub fn unsent(&self) -> impl Iterator<Item = &Entry> {
        self.entries.iter().skip(self.sent)
    }

    pub fn mark_sent(&mut self, n: usize) {
        self.sent = (self.sent + n).min(self.entries.len());
    }

    /// The receiver has published `published` samples of this conversation: those are dropped.
    pub fn acknowledged(&mut self, published: u64) {
        let newly = published.saturating_sub(self.acked) as usize;
        let newly = newly.min(self.sent);
        for _ in 0..newly {
            if let Some(gone) = self.entries.pop_front() {
                self.bytes -= gone.frame.len();
            }
        }
        self.sent -= newly;
        self.acked += newly as u64;
    }
}

/// What the receiver has published, per topic. Samples may come out of order — a stereo service that was
/// replaced redoes keyframes while its predecessor's last ones are still arriving — so each id is remembered:
/// the unbroken run from the first id published ([`Inbox::resume_after`]), and the ids published beyond it.
#[derive(Debug, Default)]
pub struct Inbox {
    topics: Vec<(Carried, Seen)>,
}

#[derive(Debug, Default)]
struct Seen {
    /// Every id from the first published up to this one was published.
    run_end: Option<u64>,
    /// Ids published beyond the run (a gap before them).
    beyond: std::collections::BTreeSet<u64>,
}

impl Inbox {
    fn seen(&self, topic: Carried) -> Option<&Seen> {
        self.topics.iter().find(|(t, _)| *t == topic).map(|(_, s)| s)
    }

    /// Whether a sample with this id is new (to be published).
    pub fn fresh(&self, topic: Carried, id: u64) -> bool {
        self.seen(topic).is_none_or(|s| s.run_end.is_none_or(|end| id > end) && !s.beyond.contains(&id))
    }

    pub fn published(&mut self, topic: Carried, id: u64) {
        let i = match self.topics.iter().position(|(t, _)| *t == topic) {
            Some(i) => i,
            None => {
                self.topics.push((topic, Seen::default()));
                self.topics.len() - 1
            }
        };
        let seen = &mut self.topics[i].1;
        match seen.run_end {
            None => seen.run_end = Some(id),
            Some(end) if id == end.saturating_add(1) => seen.run_end = Some(id),
            Some(end) if id > end => {
                seen.beyond.insert(id);
            }
            Some(_) => {}
        }
        // The run grows over ids that arrived early.
        while let Some(next) = seen.run_end.and_then(|end| end.checked_add(1)).filter(|n| seen.beyond.contains(n)) {
            seen.beyond.remove(&next);
            seen.run_end = Some(next);
        }
    }

    /// The last id of the unbroken run published so far: a sender that restarted resumes after it (anything
    /// beyond that it sends again is recognised and not published twice).
    pub fn resume_after(&self, topic: Carried) -> Option<u64> {
        self.seen(topic).and_then(|s| s.run_end)
    }

    /// What a HELLO says: per topic, where a sender resumes.
    pub fn hello(&self, topics: &[Carried]) -> Vec<(Carried, Option<u64>)> {
        topics.iter().map(|&t| (t, self.resume_after(t))).collect()
    }
}

/// Corrections come in generations, several keyframes each: the id is the generation in the upper 44 bits and
/// the record's place in its generation in the lower 20 (a million keyframes a generation).
#[derive(Debug, Default)]
pub struct CorrectionIds {
    generation: u64,
    index: u64,
}

impl CorrectionIds {
    pub fn next(&mut self, generation: u64) -> u64 {
        if generation != self.generation {
            self.generation = generation;
            self.index = 0;
        }
        let id = (generation << 20) | self.index.min((1 << 20) - 1);
        self.index += 1;
        id
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn entry(topic: Carried, id: u64, bytes: usize) -> Entry {
        Entry { topic, id, frame: vec![0; bytes] }
    }

    #[test]
    fn a_new_conversation_resends_what_was_not_acknowledged_less_what_the_receiver_has() {
        let mut out = Outbox::new(1 << 20);
        for id in 1..=5 {
            out.push(entry(Carried::Depth, id, 10));
        }
        out.connected(&[]);
        assert_eq!(out.unsent().count(), 5);
        out.mark_sent(5);
        out.acknowledged(2);
        assert_eq!(out.len(), 3);
        // A new conversation (the link broke); the receiver had published 3 (its ack was lost).
        out.connected(&[(Carried::Depth, Some(3))]);
        let ids: Vec<u64> = out.unsent().map(|e| e.id).collect();
        assert_eq!(ids, vec![4, 5]);
        out.mark_sent(2);
        out.acknowledged(2);
        assert!(out.is_empty());
        assert_eq!(out.bytes(), 0);
    }

    #[test]
    fn over_budget_the_oldest_unsent_go_and_are_counted() {
        let mut out = Outbox::new(25);
        out.connected(&[]);
        out.push(entry(Carried::Depth, 1, 10));
        out.mark_sent(1);
        for id in 2..=4 {
            out.push(entry(Carried::Depth, id, 10));
        }
        let ids: Vec<u64> = out.unsent().map(|e| e.id).collect();
        assert_eq!(ids, vec![4], "the sent one stays until acknowledged; the newest is kept");
        assert_eq!(out.overflowed, 2);
    }

    #[test]
    fn the_receiver_publishes_each_id_once_in_whatever_order_they_come() {
        let mut inbox = Inbox::default();
        assert!(inbox.fresh(Carried::Depth, 0));
        for id in [0, 1, 2, 4, 5] {
            inbox.published(Carried::Depth, id);
        }
        // 3 comes late (a replaced stereo service redoing it): still new; 4 again is not.
        assert!(inbox.fresh(Carried::Depth, 3) && !inbox.fresh(Carried::Depth, 4) && !inbox.fresh(Carried::Depth, 1));
        assert_eq!(inbox.resume_after(Carried::Depth), Some(2), "a restarted sender resumes before the gap");
        inbox.published(Carried::Depth, 3);
        assert_eq!(inbox.resume_after(Carried::Depth), Some(5));
        assert!(inbox.fresh(Carried::Depth, 6) && inbox.fresh(Carried::Corrections, 1));
        assert_eq!(
            inbox.hello(&[Carried::Depth, Carried::Corrections]),
            vec![(Carried::Depth, Some(5)), (Carried::Corrections, None)]
        );
        let mut ids = CorrectionIds::default();
        let a = [ids.next(3), ids.next(3), ids.next(4)];
        assert!(a[0] < a[1] && a[1] < a[2]);
    }
}
