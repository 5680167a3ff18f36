//! YUV4MPEG2 (`.y4m`): a one-line header, then per frame a `FRAME` line and the raw planes (Y, then U and V
//! at the header's chroma subsampling). Read here, without ffmpeg, for 8-bit 4:2:0, 4:2:2, 4:4:4 and mono;
//! other colour spaces (10-bit, alpha) are left to ffmpeg.

use std::io::SeekFrom;
use std::path::Path;

use super::VideoError;
use super::native::{Container, FrameSpan, MAX_SIDE, NativeIndex, ReadSeek};

/// How the chroma planes are subsampled (horizontal, vertical), or no chroma at all.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Chroma {
    Sub { x: u32, y: u32 },
    Mono,
}

/// What a Y4M frame's planes are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct PlaneLayout {
    pub width: u32,
    pub height: u32,
    pub chroma: Chroma,
    /// `XCOLORRANGE=FULL`: luma and chroma use 0..255 (JPEG); otherwise the studio range of BT.601.
    pub full_range: bool,
}

impl PlaneLayout {
    fn chroma_size(&self) -> (usize, usize) {
        match self.chroma {
            Chroma::Sub { x, y } => (self.width.div_ceil(x) as usize, self.height.div_ceil(y) as usize),
            Chroma::Mono => (0, 0),
        }
    }

    /// Bytes of one frame's planes.
    pub fn frame_bytes(&self) -> u64 {
        let (cw, ch) = self.chroma_size();
        u64::from(self.width) * u64::from(self.height) + 2 * (cw * ch) as u64
    }

    /// Converts one frame's planes to packed RGB (`width × height × 3` bytes in `rgb`). BT.601, as ffmpeg
    /// assumes for an untagged Y4M; each chroma sample is used for the pixels it covers.
    pub fn convert_into_rgb(&self, planes: &[u8], rgb: &mut [u8]) {
        let tables = self.tables();
        let (w, h) = (self.width as usize, self.height as usize);
        for (y, out) in rgb.chunks_exact_mut(3 * w).take(h).enumerate() {
            self.rgb_row(&tables, planes, (0, y, w), |i, c| out[3 * i..3 * i + 3].copy_from_slice(&c));
        }
    }

    /// Whether a view starting at (`x0`, `y0`) of the frame has its own chroma samples (the offset is a
    /// multiple of the subsampling), so that [`PlaneLayout::view_into`] can read it.
    pub fn view_aligned(&self, x0: u32, y0: u32) -> bool {
        match self.chroma {
            Chroma::Sub { x, y } => x0.is_multiple_of(x) && y0.is_multiple_of(y),
            Chroma::Mono => true,
        }
    }

    /// Writes the `w`×`h` view at (`x0`, `y0`) of one frame's `planes` as grey into `gray` and, when asked, as
    /// RGB into `rgb` — straight from the planes, as a capture device's frames are: grey is the luma expanded
    /// to full range (what BT.601's grey weights give back from the RGB, to rounding), colour only where it is
    /// wanted. The view must be [`PlaneLayout::view_aligned`] and inside the frame.
    pub fn view_into(
        &self,
        planes: &[u8],
        (x0, y0, w, h): (usize, usize, usize, usize),
        gray: &mut [std::mem::MaybeUninit<u8>],
        mut rgb: Option<&mut [std::mem::MaybeUninit<u8>]>,
    ) {
        let tables = self.tables();
        let grey_of_luma: [u8; 256] = std::array::from_fn(|y| tables.rgb(y as u8, 128, 128)[1]);
        let frame_w = self.width as usize;
        for row in 0..h {
            let y = y0 + row;
            let luma_row = &planes[y * frame_w + x0..y * frame_w + x0 + w];
            for (g, &l) in gray[row * w..(row + 1) * w].iter_mut().zip(luma_row) {
                g.write(grey_of_luma[usize::from(l)]);
            }
            let Some(rgb) = rgb.as_deref_mut() else { continue };
            let out = &mut rgb[3 * row * w..3 * (row + 1) * w];
            self.rgb_row(&tables, planes, (x0, y, w), |i, c| {
                for (o, c) in out[3 * i..3 * i + 3].iter_mut().zip(c) {
                    o.write(c);
                }
            });
        }
    }

    fn tables(&self) -> YuvTables {
        if self.full_range { YuvTables::full() } else { YuvTables::studio() }
    }

    /// The RGB of the `w` pixels from (`x0`, `y`) of one frame's `planes`, pixel by pixel into `put(i, rgb)`:
    /// each chroma sample's terms once, then the (up to) subsampling's pixels it covers. `x0` is a multiple of
    /// the horizontal subsampling.
    #[inline(always)]
    fn rgb_row(
        &self,
        tables: &YuvTables,
        planes: &[u8],
        (x0, y, w): (usize, usize, usize),
        mut put: impl FnMut(usize, [u8; 3]),
    ) {
        let frame_w = self.width as usize;
        let (luma, chroma) = planes.split_at(frame_w * self.height as usize);
        let luma_row = &luma[y * frame_w + x0..y * frame_w + x0 + w];
        match self.chroma {
            Chroma::Mono => {
                for (i, &l) in luma_row.iter().enumerate() {
                    put(i, tables.rgb(l, 128, 128));
                }
            }
            Chroma::Sub { x: sx, y: sy } => {
                let (cw, ch) = self.chroma_size();
                let (u_plane, v_plane) = chroma.split_at(cw * ch);
                let sx = sx as usize;
                let (c0, n) = ((y / sy as usize) * cw + x0 / sx, w.div_ceil(sx));
                let chroma_row = u_plane[c0..c0 + n].iter().zip(&v_plane[c0..c0 + n]);
                for (k, (pixels, (&u, &v))) in luma_row.chunks(sx).zip(chroma_row).enumerate() {
                    let terms = tables.chroma_terms(u, v);
                    for (j, &l) in pixels.iter().enumerate() {
                        put(k * sx + j, tables.rgb_with(l, terms));
                    }
                }
            }
        }
    }
}

/// One range's YUV → RGB conversion as tables of its terms: `rgb = clamp((luma[y] + chroma terms) >> 8)`, the
/// fixed-point arithmetic of [`crate::decode::rgb_of_yuv`] (studio range) or [`rgb_of_full_yuv`] split so that
/// a chroma sample's terms are added to every pixel it covers instead of being computed again for each (the
/// conversion was 70 % of a 1080p Y4M frame's acquisition). The same numbers: checked against the per-pixel
/// functions for every Y, U and V.
struct YuvTables {
    luma: [i32; 256],
    /// Per U: its blue term and its green term; per V: its red term and its green term.
    u_terms: [(i32, i32); 256],
    v_terms: [(i32, i32); 256],
}

impl YuvTables {
    /// BT.601 studio range ([`crate::decode::rgb_of_yuv`]).
    fn studio() -> Self {
        Self::with(|y| 298 * (y - 16) + 128, [409, 100, 208, 516])
    }

    /// Full range ([`rgb_of_full_yuv`]).
    fn full() -> Self {
        Self::with(|y| (y << 8) + 128, [359, 88, 183, 454])
    }

    /// `[c + r·e, c − g_u·d − g_v·e, c + b·d]` with d = U − 128, e = V − 128 and `[r, g_u, g_v, b]`.
    fn with(luma_of: fn(i32) -> i32, [r, g_u, g_v, b]: [i32; 4]) -> Self {
        let mut luma = [0; 256];
        let mut u_terms = [(0, 0); 256];
        let mut v_terms = [(0, 0); 256];
        for k in 0..256 {
            let centred = k as i32 - 128;
            luma[k] = luma_of(k as i32);
            u_terms[k] = (b * centred, -g_u * centred);
            v_terms[k] = (r * centred, -g_v * centred);
        }
        Self { luma, u_terms, v_terms }
    }

    #[inline(always)]
    fn chroma_terms(&self, u: u8, v: u8) -> [i32; 3] {
        let ((b, gu), (r, gv)) = (self.u_terms[usize::from(u)], self.v_terms[usize::from(v)]);
        [r, gu + gv, b]
    }

    #[inline(always)]
    fn rgb_with(&self, y: u8, terms: [i32; 3]) -> [u8; 3] {
        let c = self.luma[usize::from(y)];
        let clamp = |x: i32| (x >> 8).clamp(0, 255) as u8;
        [clamp(c + terms[0]), clamp(c + terms[1]), clamp(c + terms[2])]
    }

    fn rgb(&self, y: u8, u: u8, v: u8) -> [u8; 3] {
        self.rgb_with(y, self.chroma_terms(u, v))
    }
}

/// Full-range (JPEG) YUV to RGB, in the same 8-bit fixed point as the studio-range conversion: the
/// definition [`YuvTables::full`] is checked against.
#[cfg(test)]
fn rgb_of_full_yuv(y: u8, u: u8, v: u8) -> [u8; 3] {
    let c = (i32::from(y) << 8) + 128;
    let (d, e) = (i32::from(u) - 128, i32::from(v) - 128);
    let clamp = |x: i32| (x >> 8).clamp(0, 255) as u8;
    [clamp(c + 359 * e), clamp(c - 88 * d - 183 * e), clamp(c + 454 * d)]
}

/// The header's fields this reader needs.
struct Header {
    planes: PlaneLayout,
    /// Frames per second as a fraction.
    rate: (u64, u64),
}

/// Parses the header line (without its newline). `Ok(None)`: a valid colour space this reader leaves to
/// ffmpeg.
fn parse_header(path: &Path, line: &str) -> Result<Option<Header>, VideoError> {
    let bad = |detail: String| VideoError::Probe { path: path.to_path_buf(), detail };
    let mut tokens = line.split(' ').filter(|t| !t.is_empty());
    if tokens.next() != Some("YUV4MPEG2") {
        return Err(bad("not a YUV4MPEG2 header".into()));
    }
    let (mut width, mut height, mut rate, mut colour, mut full_range) = (None, None, None, "420jpeg", false);
    for token in tokens {
        // The tag is one character (a header is ASCII, but a damaged one need not be).
        let Some(tag) = token.chars().next() else { continue };
        let value = &token[tag.len_utf8()..];
        match tag {
            'W' => width = value.parse::<u32>().ok().filter(|v| (1..=MAX_SIDE).contains(v)),
            'H' => height = value.parse::<u32>().ok().filter(|v| (1..=MAX_SIDE).contains(v)),
            'F' => {
                let fraction = value.split_once(':').and_then(|(n, d)| Some((n.parse().ok()?, d.parse().ok()?)));
                rate = fraction.filter(|&(n, d): &(u64, u64)| n > 0 && d > 0);
                if rate.is_none() {
                    return Err(bad(format!("header field F `{value}` is not a frame rate (N:D)")));
                }
            }
            'C' => colour = value,
            'X' => full_range |= value == "COLORRANGE=FULL",
            _ => {}
        }
    }
    let width = width.ok_or_else(|| bad("header field W (width) is missing or not a size (1 to 16384)".into()))?;
    let height = height.ok_or_else(|| bad("header field H (height) is missing or not a size (1 to 16384)".into()))?;
    let rate = rate.ok_or_else(|| bad("header field F (frame rate) is missing".into()))?;
    let chroma = match colour {
        "420jpeg" | "420paldv" | "420mpeg2" | "420" => Chroma::Sub { x: 2, y: 2 },
        "422" => Chroma::Sub { x: 2, y: 1 },
        "411" => Chroma::Sub { x: 4, y: 1 },
        "444" => Chroma::Sub { x: 1, y: 1 },
        "mono" => Chroma::Mono,
        _ => return Ok(None),
    };
    Ok(Some(Header { planes: PlaneLayout { width, height, chroma, full_range }, rate }))
}

/// Reads up to a newline from the file's position (at most about `limit` bytes) and leaves the file after it;
/// `None` at the end of the file.
fn read_line(file: &mut impl ReadSeek, limit: usize, line: &mut Vec<u8>) -> std::io::Result<Option<()>> {
    line.clear();
    let start = file.stream_position()?;
    let mut chunk = [0u8; 128];
    loop {
        let n = file.read(&mut chunk)?;
        if n == 0 {
            return Ok((!line.is_empty()).then_some(()));
        }
        if let Some(i) = chunk[..n].iter().position(|&b| b == b'\n') {
            line.extend_from_slice(&chunk[..i]);
            file.seek(SeekFrom::Start(start + line.len() as u64 + 1))?;
            return Ok(Some(()));
        }
        line.extend_from_slice(&chunk[..n]);
        if line.len() >= limit {
            return Ok(Some(()));
        }
    }
}

/// Indexes a Y4M file: its planes and every whole frame's offset.
pub(super) fn index(path: &Path, file: &mut impl ReadSeek, file_len: u64) -> Result<Option<NativeIndex>, VideoError> {
    let io = |e: std::io::Error| VideoError::Probe { path: path.to_path_buf(), detail: e.to_string() };
    let bad = |detail: String| VideoError::Probe { path: path.to_path_buf(), detail };
    file.seek(SeekFrom::Start(0)).map_err(io)?;
    let mut line = Vec::with_capacity(256);
    read_line(file, 4096, &mut line).map_err(io)?;
    let Some(header) = parse_header(path, &String::from_utf8_lossy(&line))? else {
        return Ok(None);
    };
    let frame_bytes = header.planes.frame_bytes();
    let mut frames = Vec::new();
    let mut offset = file.stream_position().map_err(io)?;
    while offset < file_len {
        let frame = frames.len();
        if read_line(file, 4096, &mut line).map_err(io)?.is_none() {
            break;
        }
        if !line.starts_with(b"FRAME") {
            return Err(bad(format!("frame {frame} at byte {offset}: no FRAME marker")));
        }
        let data = file.stream_position().map_err(io)?;
        if data + frame_bytes > file_len {
            break;
        }
        frames.push(FrameSpan { offset: data, bytes: frame_bytes });
        offset = data + frame_bytes;
        file.seek(SeekFrom::Start(offset)).map_err(io)?;
    }
    if frames.is_empty() {
        return Err(bad("no video frames".into()));
    }
    let (n, d) = header.rate;
    let timestamps_s = (0..frames.len() as u64).map(|i| (i * d) as f64 / n as f64).collect();
    let (width, height) = (header.planes.width, header.planes.height);
    Ok(Some(NativeIndex { container: Container::Y4m(header.planes), width, height, frames, timestamps_s }))
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_tables_convert_every_yuv_as_the_per_pixel_functions_do() {
        let (studio, full) = (YuvTables::studio(), YuvTables::full());
        for y in 0..=255u8 {
            for u in 0..=255u8 {
                for v in 0..=255u8 {
                    assert_eq!(studio.rgb(y, u, v), crate::decode::rgb_of_yuv(y, u, v), "studio {y} {u} {v}");
                    assert_eq!(full.rgb(y, u, v), rgb_of_full_yuv(y, u, v), "full {y} {u} {v}");
                }
            }
        }
    }

    use super::*;

    #[test]
    fn headers_name_the_field_that_is_wrong() {
        let p = Path::new("clip.y4m");
        let ok = parse_header(p, "YUV4MPEG2 W640 H480 F30000:1001 Ip A1:1 C420jpeg XYSCSS=420JPEG").unwrap().unwrap();
        assert_eq!((ok.planes.width, ok.planes.height, ok.rate), (640, 480, (30000, 1001)));
        assert_eq!(ok.planes.frame_bytes(), 640 * 480 * 3 / 2);
        let full = parse_header(p, "YUV4MPEG2 W5 H3 F25:1 C422 XCOLORRANGE=FULL").unwrap().unwrap();
        assert!(full.planes.full_range);
        assert_eq!(full.planes.frame_bytes(), 15 + 2 * 3 * 3);
        assert!(parse_header(p, "YUV4MPEG2 W640 H480 F30:1 C420p10").unwrap().is_none(), "left to ffmpeg");
        for (line, field) in [
            ("YUV4MPEG2 H480 F30:1", "W (width)"),
            ("YUV4MPEG2 W640 H0 F30:1", "H (height)"),
            ("YUV4MPEG2 W640 H480 F30:0", "F `30:0`"),
            ("YUV4MPEG2 W640 H480", "F (frame rate)"),
        ] {
            let e = parse_header(p, line).err().map(|e| e.to_string()).unwrap_or_default();
            assert!(e.contains("clip.y4m") && e.contains(field), "{line}: {e}");
        }
    }

    #[test]
    fn planes_convert_as_bt601() {
        // 2×2, 4:2:0: one chroma sample; studio-range white, black and mid grey, then saturated red.
        let layout = PlaneLayout { width: 2, height: 2, chroma: Chroma::Sub { x: 2, y: 2 }, full_range: false };
        let mut rgb = [0u8; 12];
        layout.convert_into_rgb(&[235, 16, 126, 126, 128, 128], &mut rgb);
        assert_eq!(rgb, [255, 255, 255, 0, 0, 0, 128, 128, 128, 128, 128, 128]);
        layout.convert_into_rgb(&[81, 81, 81, 81, 90, 240], &mut rgb);
        assert!(rgb[0] >= 253 && rgb[1] <= 2 && rgb[2] <= 2, "{rgb:?}");
    }

    #[test]
    fn a_view_read_from_the_planes_is_that_part_of_the_whole_frame_converted() {
        // Side by side and top-bottom, 4:2:0, 4:2:2 and mono, both ranges: a view's colour straight from the
        // planes equals the same pixels of the whole frame converted to RGB, and its grey is the luma expanded.
        let (w, h) = (12usize, 6usize);
        let mut seed = 7u32;
        let mut next = || {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (seed >> 24) as u8
        };
        for chroma in [Chroma::Sub { x: 2, y: 2 }, Chroma::Sub { x: 2, y: 1 }, Chroma::Mono] {
            for full_range in [false, true] {
                for (fw, fh, right_at) in [(2 * w, h, (w, 0)), (w, 2 * h, (0, h))] {
                    let layout = PlaneLayout { width: fw as u32, height: fh as u32, chroma, full_range };
                    let planes: Vec<u8> = (0..layout.frame_bytes()).map(|_| next()).collect();
                    let mut whole = vec![0u8; 3 * fw * fh];
                    layout.convert_into_rgb(&planes, &mut whole);
                    for (x0, y0) in [(0, 0), right_at] {
                        assert!(layout.view_aligned(x0 as u32, y0 as u32));
                        let mut gray = vec![std::mem::MaybeUninit::new(0u8); w * h];
                        let mut rgb = vec![std::mem::MaybeUninit::new(0u8); 3 * w * h];
                        layout.view_into(&planes, (x0, y0, w, h), &mut gray, Some(&mut rgb));
                        for y in 0..h {
                            for x in 0..w {
                                let (i, j) = (y * w + x, (y0 + y) * fw + x0 + x);
                                // SAFETY: every byte was initialised above.
                                let got: Vec<u8> =
                                    rgb[3 * i..3 * i + 3].iter().map(|b| unsafe { b.assume_init() }).collect();
                                assert_eq!(
                                    got,
                                    whole[3 * j..3 * j + 3],
                                    "{chroma:?} {full_range} view ({x0}, {y0}) px ({x}, {y})"
                                );
                                let luma = i32::from(planes[j]);
                                let want =
                                    if full_range { luma } else { ((298 * (luma - 16) + 128) >> 8).clamp(0, 255) };
                                assert_eq!(i32::from(unsafe { gray[i].assume_init() }), want);
                            }
                        }
                    }
                }
            }
        }
        // A view starting between chroma samples cannot be read from the planes.
        let layout = PlaneLayout { width: 8, height: 8, chroma: Chroma::Sub { x: 2, y: 2 }, full_range: false };
        assert!(!layout.view_aligned(3, 0) && !layout.view_aligned(0, 5));
    }
}
