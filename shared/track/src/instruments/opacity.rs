//! The instrument estimate's opacity test (step 4 of the parent module): a candidate region's edge contrast
//! and colour return, against what the frame's tissue looks like. Methods of `InstrumentMasker` on its own
//! buffers, so a warmed-up frame allocates nothing.

use super::{EDGE_PERCENTILE, InstrumentMasker, MAX_GRADIENT, TISSUE, rgb_offset};

impl InstrumentMasker {
    /// The edge contrast of the region whose members are in `stack`: the 90th-percentile gradient at its
    /// members that border tissue, over `tissue_edge`. Those members are left in `ring_front`, where
    /// `colour_return` grows its ring from.
    pub(super) fn edge_contrast(&mut self, width: usize, height: usize, tissue_edge: u16) -> f32 {
        self.edge_gradients.clear();
        self.ring_front.clear();
        for &i in &self.stack {
            let i = i as usize;
            let (x, y) = (i % width, i / width);
            let borders_tissue = (x > 0 && self.class[i - 1] == TISSUE)
                || (x + 1 < width && self.class[i + 1] == TISSUE)
                || (y > 0 && self.class[i - width] == TISSUE)
                || (y + 1 < height && self.class[i + width] == TISSUE);
            if borders_tissue {
                self.edge_gradients.push(sobel(&self.luma, width, height, x, y));
                self.ring_front.push(i as u32);
            }
        }
        if self.edge_gradients.is_empty() || tissue_edge == 0 {
            return f32::INFINITY;
        }
        let k = ((EDGE_PERCENTILE * self.edge_gradients.len() as f32) as usize).min(self.edge_gradients.len() - 1);
        let (_, &mut edge, _) = self.edge_gradients.select_nth_unstable(k);
        f32::from(edge) / f32::from(tissue_edge)
    }

    /// The colour return of the region labelled `label` (its members bordering tissue in `ring_front`, as
    /// `edge_contrast` leaves them): the median saturation of the tissue within `ring` cells of it (8-connected
    /// steps through tissue), over the tissue's 90th percentile. The ring's cells are marked with the region's
    /// label: tissue cells carry no label of their own.
    pub(super) fn colour_return(&mut self, rgb: &[u8], ring: usize, label: u32, levels: TissueLevels) -> f32 {
        let (width, height) = self.grid_size;
        self.ring_saturations.clear();
        let (w, h) = (width as isize, height as isize);
        let mut layer_start = 0;
        for _ in 0..ring {
            let layer_end = self.ring_front.len();
            for k in layer_start..layer_end {
                let i = self.ring_front[k] as usize;
                let (x, y) = ((i % width) as isize, (i / width) as isize);
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let (nx, ny) = (x + dx, y + dy);
                        if nx < 0 || ny < 0 || nx >= w || ny >= h {
                            continue;
                        }
                        let j = (ny * w + nx) as usize;
                        if self.class[j] == TISSUE && self.labels[j] != label {
                            self.labels[j] = label;
                            self.ring_front.push(j as u32);
                            self.ring_saturations.push(self.saturation_at(rgb, j));
                        }
                    }
                }
            }
            layer_start = layer_end;
        }
        if self.ring_saturations.is_empty() || levels.saturation == 0 {
            return f32::INFINITY;
        }
        let k = self.ring_saturations.len() / 2;
        let (_, &mut ring_saturation, _) = self.ring_saturations.select_nth_unstable(k);
        f32::from(ring_saturation) / f32::from(levels.saturation)
    }

    /// The tissue's 90th-percentile gradient (over tissue cells whose 3×3 neighbourhood is all tissue: not the
    /// rim of a region, not a highlight's) and its 90th-percentile saturation (over tissue cells); 0 where there
    /// is none. `rgb` is the image `estimate` was given.
    pub(super) fn tissue_levels(&mut self, rgb: &[u8]) -> TissueLevels {
        let (width, height) = self.grid_size;
        let (step, full_width) = (self.grid_step, self.image_size.0);
        let (class, luma) = (&self.class, &self.luma);
        let gradients = &mut self.tissue_gradients;
        gradients.clear();
        gradients.resize(MAX_GRADIENT + 1, 0);
        let saturations = &mut self.tissue_saturations;
        saturations.clear();
        saturations.resize(256, 0);
        // Every second cell of every second row: a percentile needs no more.
        for y in (1..height.saturating_sub(1)).step_by(2) {
            let (above, row, below) = (&class[(y - 1) * width..], &class[y * width..], &class[(y + 1) * width..]);
            for x in (1..width - 1).step_by(2) {
                if row[x] != TISSUE {
                    continue;
                }
                saturations[usize::from(saturation_at(rgb, rgb_offset(x, y, step, full_width)))] += 1;
                let around = [
                    above[x - 1],
                    above[x],
                    above[x + 1],
                    row[x - 1],
                    row[x + 1],
                    below[x - 1],
                    below[x],
                    below[x + 1],
                ];
                if around.iter().all(|&c| c == TISSUE) {
                    gradients[usize::from(sobel(luma, width, height, x, y))] += 1;
                }
            }
        }
        TissueLevels {
            edge: percentile(gradients, EDGE_PERCENTILE) as u16,
            saturation: percentile(saturations, EDGE_PERCENTILE) as u8,
        }
    }

    /// Saturation of grid cell `cell`'s pixel.
    fn saturation_at(&self, rgb: &[u8], cell: usize) -> u8 {
        let width = self.grid_size.0;
        saturation_at(rgb, rgb_offset(cell % width, cell / width, self.grid_step, self.image_size.0))
    }
}

/// What the tissue of a frame looks like, to judge a region against.
#[derive(Debug, Clone, Copy)]
pub(super) struct TissueLevels {
    /// 90th-percentile gradient magnitude.
    pub(super) edge: u16,
    /// 90th-percentile saturation (of 255): the tissue's own colour where no veil covers it (under smoke the
    /// median tissue is veiled too).
    saturation: u8,
}

/// Saturation `(max − min) / max`, of 255, of the pixel at byte `at` of an RGB image.
fn saturation_at(rgb: &[u8], at: usize) -> u8 {
    let (r, g, b) = (rgb[at], rgb[at + 1], rgb[at + 2]);
    let (hi, lo) = (r.max(g).max(b), r.min(g).min(b));
    if hi == 0 { 0 } else { ((255 * u32::from(hi - lo)) / u32::from(hi)) as u8 }
}

/// The value below which `share` of a histogram's counts lie (0 for an empty histogram).
fn percentile(histogram: &[u32], share: f32) -> usize {
    let count: u64 = histogram.iter().map(|&c| u64::from(c)).sum();
    if count == 0 {
        return 0;
    }
    let wanted = (f64::from(share) * count as f64).ceil().max(1.0) as u64;
    let mut seen = 0u64;
    for (value, &c) in histogram.iter().enumerate() {
        seen += u64::from(c);
        if seen >= wanted {
            return value;
        }
    }
    histogram.len() - 1
}

/// Sobel gradient magnitude `|gx| + |gy|` of `luma` at `(x, y)`, the image's edge replicated.
fn sobel(luma: &[u8], width: usize, height: usize, x: usize, y: usize) -> u16 {
    let (x0, x1) = (x.saturating_sub(1), (x + 1).min(width - 1));
    let (y0, y1) = (y.saturating_sub(1), (y + 1).min(height - 1));
    let at = |x: usize, y: usize| i32::from(luma[y * width + x]);
    let gx = at(x1, y0) + 2 * at(x1, y) + at(x1, y1) - at(x0, y0) - 2 * at(x0, y) - at(x0, y1);
    let gy = at(x0, y1) + 2 * at(x, y1) + at(x1, y1) - at(x0, y0) - 2 * at(x, y0) - at(x1, y0);
    (gx.abs() + gy.abs()) as u16
}
