//! What a navigation workstation holds of the dense map: one block per keyframe (3D Slicer shows each as a model
//! node), in world coordinates. A new picture of the map — a snapshot from the mosaic, or the map it wrote at the
//! end — is compared with what was sent, keyframe by keyframe, so only the keyframes that are new, were moved by
//! a pose correction or lost points to a later view go out again, and a keyframe that left the map is emptied.

use std::collections::BTreeMap;

/// One keyframe's points in world coordinates, with their colours.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct KeyframeBlock {
    pub xyz: Vec<[f32; 3]>,
    pub rgb: Vec<[u8; 3]>,
}

/// What changed between the map as sent and a new picture of it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Change {
    /// The keyframe is new or its points differ: send its block.
    Block(u64),
    /// The keyframe is no longer in the map (or has no points left): send it empty.
    Gone(u64),
}

/// The blocks as sent, and the next picture being taken in.
#[derive(Debug, Default)]
pub struct MapMirror {
    sent: BTreeMap<u64, KeyframeBlock>,
    incoming: BTreeMap<u64, KeyframeBlock>,
}

impl MapMirror {
    /// The blocks as the workstation holds them, in keyframe order.
    pub fn blocks(&self) -> impl Iterator<Item = (u64, &KeyframeBlock)> {
        self.sent.iter().map(|(&id, b)| (id, b))
    }

    pub fn block(&self, kf_id: u64) -> Option<&KeyframeBlock> {
        self.sent.get(&kf_id)
    }

    /// Points of the map as sent.
    pub fn points(&self) -> usize {
        self.sent.values().map(|b| b.xyz.len()).sum()
    }

    /// Takes one point of the new picture.
    pub fn point(&mut self, kf_id: u64, xyz: [f32; 3], rgb: [u8; 3]) {
        let block = self.incoming.entry(kf_id).or_default();
        block.xyz.push(xyz);
        block.rgb.push(rgb);
    }

    /// Makes the new picture the one sent and says what changed, in keyframe order.
    pub fn commit(&mut self, changes: &mut Vec<Change>) {
        changes.clear();
        let incoming = std::mem::take(&mut self.incoming);
        for (&id, _) in self.sent.iter().filter(|(id, _)| !incoming.contains_key(id)) {
            changes.push(Change::Gone(id));
        }
        for (id, block) in &incoming {
            if self.sent.get(id) != Some(block) {
                changes.push(Change::Block(*id));
            }
        }
        self.sent = incoming;
        changes.sort_by_key(|c| match c {
            Change::Block(id) | Change::Gone(id) => *id,
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_what_changed_goes_out_again() {
        let mut mirror = MapMirror::default();
        let mut changes = Vec::new();
        mirror.point(1, [0.0, 0.0, 1.0], [1, 2, 3]);
        mirror.point(2, [0.0, 0.0, 2.0], [1, 2, 3]);
        mirror.commit(&mut changes);
        assert_eq!(changes, vec![Change::Block(1), Change::Block(2)]);
        // The same picture: nothing to send.
        mirror.point(1, [0.0, 0.0, 1.0], [1, 2, 3]);
        mirror.point(2, [0.0, 0.0, 2.0], [1, 2, 3]);
        mirror.commit(&mut changes);
        assert!(changes.is_empty());
        // Keyframe 2 moved, 1 left the map, 3 is new.
        mirror.point(2, [0.0, 0.1, 2.0], [1, 2, 3]);
        mirror.point(3, [0.0, 0.0, 3.0], [1, 2, 3]);
        mirror.commit(&mut changes);
        assert_eq!(changes, vec![Change::Gone(1), Change::Block(2), Change::Block(3)]);
        assert_eq!(mirror.points(), 2);
        assert_eq!(mirror.block(2).unwrap().xyz, vec![[0.0, 0.1, 2.0]]);
    }
}
