//! Spreading the corners over the level with a quadtree (§1.4): the strongest corner of each node survives.

use super::*;

/// A quadtree node: a rectangle and the range of its corners in the member list.
#[derive(Debug, Clone, Copy)]
pub(super) struct Node {
    x0: f32,
    y0: f32,
    x1: f32,
    y1: f32,
    start: u32,
    count: u32,
}

impl OrbExtractor {
    /// Quadtree distribution keeping the strongest corner of each node (§1.4); result in `self.kept`.
    #[inline(never)] // a stage of its own in profiles
    pub(super) fn distribute(&mut self, l: usize) {
        let want = self.per_level[l];
        self.kept.clear();
        if self.corners.is_empty() || want == 0 {
            return;
        }
        let level = &self.levels[l];
        let (x0, y0, x1, y1) =
            (FAST_MARGIN as f32, FAST_MARGIN as f32, (level.w - FAST_MARGIN) as f32, (level.h - FAST_MARGIN) as f32);
        let n_ini = (((x1 - x0) / (y1 - y0)).round() as usize).max(1);
        let strip = (x1 - x0) / n_ini as f32;
        self.nodes.clear();
        self.members.clear();
        for k in 0..n_ini {
            let (nx0, nx1) = (x0 + k as f32 * strip, x0 + (k + 1) as f32 * strip);
            let start = self.members.len() as u32;
            for (i, c) in self.corners.iter().enumerate() {
                let cx = f32::from(c.x);
                let inside = cx >= nx0 && (cx < nx1 || k == n_ini - 1);
                if inside {
                    self.members.push(i as u32);
                }
            }
            let count = self.members.len() as u32 - start;
            if count > 0 {
                self.nodes.push(Node { x0: nx0, y0, x1: nx1, y1, start, count });
            }
        }
        // Split nodes until there are enough; nodes with one corner are final.
        loop {
            let before = self.nodes.len();
            let expandable = self.nodes.iter().filter(|n| n.count > 1).count();
            if before >= want || expandable == 0 {
                break;
            }
            // Final phase: split the most populated first, stop as soon as there are enough.
            let final_phase = before + 3 * expandable > want;
            if final_phase {
                self.nodes.sort_unstable_by_key(|n| std::cmp::Reverse(n.count));
            }
            self.next_nodes.clear();
            self.next_members.clear();
            let mut total = self.nodes.len();
            for idx in 0..self.nodes.len() {
                let n = self.nodes[idx];
                if n.count == 1 || (final_phase && total >= want) {
                    let start = self.next_members.len() as u32;
                    self.next_members.extend_from_slice(&self.members[n.start as usize..(n.start + n.count) as usize]);
                    self.next_nodes.push(Node { start, ..n });
                    continue;
                }
                let (mx, my) = ((n.x0 + (n.x1 - n.x0) / 2.0).ceil(), (n.y0 + (n.y1 - n.y0) / 2.0).ceil());
                let mut children = 0;
                for q in 0..4 {
                    let (cx0, cx1) = if q % 2 == 0 { (n.x0, mx) } else { (mx, n.x1) };
                    let (cy0, cy1) = if q < 2 { (n.y0, my) } else { (my, n.y1) };
                    let start = self.next_members.len() as u32;
                    for &m in &self.members[n.start as usize..(n.start + n.count) as usize] {
                        let c = self.corners[m as usize];
                        let (cx, cy) = (f32::from(c.x), f32::from(c.y));
                        let left = cx < mx;
                        let up = cy < my;
                        if left == (q % 2 == 0) && up == (q < 2) {
                            self.next_members.push(m);
                        }
                    }
                    let count = self.next_members.len() as u32 - start;
                    if count > 0 {
                        self.next_nodes.push(Node { x0: cx0, y0: cy0, x1: cx1, y1: cy1, start, count });
                        children += 1;
                    }
                }
                total = total - 1 + children;
            }
            std::mem::swap(&mut self.nodes, &mut self.next_nodes);
            std::mem::swap(&mut self.members, &mut self.next_members);
            if self.nodes.len() == before {
                break;
            }
        }
        for n in &self.nodes {
            let best = self.members[n.start as usize..(n.start + n.count) as usize]
                .iter()
                .map(|&m| self.corners[m as usize])
                .max_by_key(|c| c.response);
            if let Some(c) = best {
                self.kept.push(c);
            }
        }
    }
}
