//! Interlaced video (1080i from SDI, recordings of it): each frame holds two fields captured 1/50 or 1/60 s
//! apart, woven line by line (the top field on the even rows). Woven as it is, anything moving shows combs —
//! an edge at two places a field apart — which the tracker's corners and the dense matcher take for texture.
//!
//! Two ways out, chosen per run:
//! - `top-field` / `bottom-field`: one field only, half the rows (the usual choice for tracking): a camera of
//!   the same fx and half the fy; every pixel is one instant.
//! - `bob`: the top field, the missing rows interpolated (mean of the rows above and below): the frame keeps
//!   its size and calibration, at half the vertical detail.
//!
//! Applied to the full woven frame as read (a staging buffer the reader owns), written once into the loaned
//! sample.

use std::mem::MaybeUninit;

use bdis_ipc::FrameLayout;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FieldMode {
    TopField,
    BottomField,
    Bob,
}

impl std::str::FromStr for FieldMode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "top-field" => Ok(Self::TopField),
            "bottom-field" => Ok(Self::BottomField),
            "bob" => Ok(Self::Bob),
            _ => Err(format!("`{s}`: expected top-field, bottom-field or bob")),
        }
    }
}

impl FieldMode {
    pub fn name(self) -> &'static str {
        match self {
            Self::TopField => "top-field",
            Self::BottomField => "bottom-field",
            Self::Bob => "bob",
        }
    }

    /// The size of the frames published from woven frames of `width × height` (`None` for an odd height).
    pub fn output_size(self, width: u32, height: u32) -> Option<(u32, u32)> {
        if !height.is_multiple_of(2) || height < 4 {
            return None;
        }
        Some(match self {
            Self::TopField | Self::BottomField => (width, height / 2),
            Self::Bob => (width, height),
        })
    }

    /// The rectified camera of the published frames, from the woven frame's: a field's row `r` is the frame's
    /// row `2r` (top) or `2r + 1` (bottom), so `fy` and `cy` scale by one half (the bottom field's rows sit
    /// half a field row lower). Bob keeps the frame's camera.
    pub fn field_camera(self, fy: f64, cy: f64) -> (f64, f64) {
        match self {
            Self::TopField => (fy / 2.0, cy / 2.0),
            Self::BottomField => (fy / 2.0, (cy - 1.0) / 2.0),
            Self::Bob => (fy, cy),
        }
    }

    /// Writes the published frame (`out` layout) from a woven packed frame (`woven` layout) into `payload`.
    pub fn apply(self, woven: &[u8], woven_layout: &FrameLayout, out: &FrameLayout, payload: &mut [MaybeUninit<u8>]) {
        let (w, h) = (woven_layout.width as usize, woven_layout.height as usize);
        let (n_in, n_out) = (w * h, out.width as usize * out.height as usize);
        let planes_in = [(0, 1), (n_in, 1), (2 * n_in, 3)];
        let planes_out = [0, n_out, 2 * n_out];
        for ((start_in, channels), start_out) in planes_in.into_iter().zip(planes_out) {
            let row = w * channels;
            let src = &woven[start_in..start_in + row * h];
            let dst = &mut payload[start_out..start_out + channels * n_out];
            match self {
                Self::TopField | Self::BottomField => {
                    let first = usize::from(self == Self::BottomField);
                    for (r, out_row) in dst.chunks_exact_mut(row).enumerate() {
                        let y = 2 * r + first;
                        for (o, &v) in out_row.iter_mut().zip(&src[y * row..(y + 1) * row]) {
                            o.write(v);
                        }
                    }
                }
                Self::Bob => {
                    for (y, out_row) in dst.chunks_exact_mut(row).enumerate() {
                        let above = &src[(y & !1) * row..((y & !1) + 1) * row];
                        if y % 2 == 0 {
                            for (o, &v) in out_row.iter_mut().zip(above) {
                                o.write(v);
                            }
                        } else {
                            // The last odd row has no top-field row below it: it repeats the one above.
                            let below_y = if y + 1 < h { y + 1 } else { y - 1 };
                            let below = &src[below_y * row..(below_y + 1) * row];
                            for ((o, &a), &b) in out_row.iter_mut().zip(above).zip(below) {
                                o.write((u16::from(a) + u16::from(b)).div_ceil(2) as u8);
                            }
                        }
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    #[allow(clippy::unwrap_used)]
    fn fields_take_their_rows_and_bob_interpolates_the_others() {
        let (w, h) = (3u32, 4u32);
        let layout = FrameLayout::packed(w, h).unwrap();
        // Every byte says its plane and row: plane·100 + row.
        let mut woven = Vec::new();
        for (plane, channels) in [(0u8, 1usize), (1, 1), (2, 3)] {
            for y in 0..h as u8 {
                woven.extend(std::iter::repeat_n(plane * 100 + y * 10, w as usize * channels));
            }
        }
        let run = |mode: FieldMode| {
            let (ow, oh) = mode.output_size(w, h).unwrap();
            let out = FrameLayout::packed(ow, oh).unwrap();
            let mut payload = vec![MaybeUninit::new(0u8); out.payload_len()];
            mode.apply(&woven, &layout, &out, &mut payload);
            payload.into_iter().map(|b| unsafe { b.assume_init() }).collect::<Vec<u8>>()
        };
        let top = run(FieldMode::TopField);
        assert_eq!(&top[..6], &[0, 0, 0, 20, 20, 20], "left grey: rows 0 and 2");
        assert_eq!(&top[6..12], &[100, 100, 100, 120, 120, 120], "right grey");
        assert_eq!(&top[12..], &[[200u8; 9], [220; 9]].concat()[..], "RGB");
        let bottom = run(FieldMode::BottomField);
        assert_eq!(&bottom[..6], &[10, 10, 10, 30, 30, 30]);
        let bob = run(FieldMode::Bob);
        assert_eq!(&bob[..12], &[0, 0, 0, 10, 10, 10, 20, 20, 20, 20, 20, 20], "rows 0, (0+20)/2, 20, 20");
        assert_eq!(FieldMode::TopField.field_camera(800.0, 540.0), (400.0, 270.0));
        assert_eq!(FieldMode::BottomField.field_camera(800.0, 541.0), (400.0, 270.0));
        assert_eq!(FieldMode::Bob.output_size(8, 5), None);
        assert!("weave".parse::<FieldMode>().is_err());
    }
}
