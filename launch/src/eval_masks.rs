//! `bdis-slam eval masks`: our instrument-mask estimate on a sequence's left images, scored against true masks.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use bdis_track::instruments::{InstrumentMasker, InstrumentParams, MaskScore};

#[derive(Debug, clap::Args)]
pub struct MasksArgs {
    /// Sequence folder (any image layout `bdis-slam run` reads).
    #[arg(long)]
    sequence: PathBuf,
    /// True masks, named like the left images with `.png` (default: SEQUENCE/gt/masks, as `synth --instruments`
    /// writes them). Without any, only the estimate's share of the image is reported.
    #[arg(long)]
    truth: Option<PathBuf>,
    /// Write each estimated mask here (`<name>.png`, 255 = instrument).
    #[arg(long)]
    write: Option<PathBuf>,
    /// Write a picture to look at: the frame where the estimate masks or weighs most, beside it with the
    /// estimate laid over it (green: instrument found; red: tissue masked; blue: instrument missed, when true
    /// masks exist; yellow: a grey region weighed and left as a veil, smoke or a membrane).
    #[arg(long, value_name = "PNG")]
    preview: Option<PathBuf>,
    /// Print JSON instead of a sentence.
    #[arg(long)]
    json: bool,
}

/// The frame shown by `--preview`.
struct Preview {
    /// Share of the image masked or weighed and left.
    share: f32,
    left: image::RgbImage,
    mask: Vec<u8>,
    veils: Vec<u8>,
    truth: Option<Vec<u8>>,
}

pub fn eval_masks(args: MasksArgs) -> Result<()> {
    let sequence = bdis_source::Sequence::open(&args.sequence)?;
    let truth_dir = args.truth.clone().unwrap_or_else(|| args.sequence.join("gt/masks"));
    let scored = truth_dir.is_dir();
    if args.truth.is_some() && !scored {
        bail!("--truth {}: not a folder", truth_dir.display());
    }
    if let Some(dir) = &args.write {
        std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create", dir.display()))?;
    }
    let mut masker = InstrumentMasker::new(InstrumentParams::default());
    let mut score = MaskScore::default();
    let (mut masked_share, mut frames_with_regions) = (0.0f64, 0usize);
    // Every candidate region's opacity, kept and refused: how far each side is from the thresholds on this
    // footage.
    let (mut instruments, mut veils) = (Opacity::default(), Opacity::default());
    let mut frames_with_veils = 0usize;
    let mut preview: Option<Preview> = None;
    let bar = bdis_slam::progress::bar(sequence.frames.len() as u64, "masks {bar:40} {pos}/{len} frames ({eta} left)");
    for entry in &sequence.frames {
        let left =
            image::open(&entry.left).with_context(|| format!("{}: cannot decode", entry.left.display()))?.into_rgb8();
        let (w, h) = (left.width() as usize, left.height() as usize);
        let found = masker.estimate(left.as_raw(), w, h);
        masked_share += f64::from(found.masked_share);
        frames_with_regions += usize::from(found.regions > 0);
        frames_with_veils += usize::from(found.veils > 0);
        for c in masker.candidates() {
            let side = if c.instrument { &mut instruments } else { &mut veils };
            side.edge_contrast.push(c.edge_contrast);
            side.colour_return.push(c.colour_return);
        }
        let name = entry.left.file_stem().map(|s| PathBuf::from(s).with_extension("png")).context("an image name")?;
        let truth = if scored {
            let path = truth_dir.join(&name);
            let truth = image::open(&path).with_context(|| format!("{}: cannot read the true mask", path.display()))?;
            let truth = truth.into_luma8();
            if truth.dimensions() != left.dimensions() {
                bail!("{}: mask is {:?}, the image {:?}", path.display(), truth.dimensions(), left.dimensions());
            }
            score.add(masker.mask(), truth.as_raw());
            Some(truth.into_raw())
        } else {
            None
        };
        if let Some(dir) = &args.write {
            let path = dir.join(&name);
            image::GrayImage::from_raw(w as u32, h as u32, masker.mask().to_vec())
                .context("mask size")?
                .save(&path)
                .with_context(|| format!("{}: cannot write", path.display()))?;
        }
        let weighed =
            found.masked_share + masker.candidates().iter().filter(|c| !c.instrument).map(|c| c.share).sum::<f32>();
        if args.preview.is_some() && weighed >= preview.as_ref().map_or(0.0, |p: &Preview| p.share) {
            let mut veils = Vec::new();
            masker.veils(&mut veils);
            preview = Some(Preview { share: weighed, left, mask: masker.mask().to_vec(), veils, truth });
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    if let (Some(path), Some(p)) = (&args.preview, &preview) {
        let (w, h) = p.left.dimensions();
        let mut picture = image::RgbImage::new(2 * w, h);
        for (x, y, px) in p.left.enumerate_pixels() {
            picture.put_pixel(x, y, *px);
            let i = (y * w + x) as usize;
            let (found, truth) = (p.mask[i] != 0, p.truth.as_ref().map(|t| t.get(i).is_some_and(|&v| v != 0)));
            let veil = p.veils.get(i).is_some_and(|&v| v != 0);
            let tint = match (found, truth) {
                (true, Some(false)) => Some([255u8, 0, 0]),
                (true, _) => Some([0, 255, 0]),
                (false, Some(true)) => Some([0, 0, 255]),
                _ if veil => Some([255, 255, 0]),
                _ => None,
            };
            let out =
                tint.map_or(*px, |t| image::Rgb([0, 1, 2].map(|c| ((u16::from(px[c]) + u16::from(t[c])) / 2) as u8)));
            picture.put_pixel(w + x, y, out);
        }
        picture.save(path).with_context(|| format!("{}: cannot write", path.display()))?;
    }
    let frames = sequence.frames.len().max(1);
    let mean_share = masked_share / frames as f64;
    if args.json {
        let mut report = serde_json::json!({
            "frames": sequence.frames.len(),
            "frames_with_instruments": frames_with_regions,
            "masked_share": mean_share,
            "frames_with_veils": frames_with_veils,
            "opacity": {
                "instruments": instruments.json(),
                "veils": veils.json(),
                "min_edge_contrast": masker.params.min_edge_contrast,
                "min_colour_return": masker.params.min_colour_return,
            },
        });
        if scored {
            report["precision"] = score.precision().into();
            report["recall"] = score.recall().into();
        }
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    print!(
        "masks: {} frames, instruments found in {frames_with_regions}, {:.1} % of the image masked on average",
        sequence.frames.len(),
        100.0 * mean_share
    );
    if scored {
        println!("; against {}: precision {:.3}, recall {:.3}", truth_dir.display(), score.precision(), score.recall());
    } else {
        println!();
    }
    if let Some(text) = instruments.text() {
        println!("  instruments: {text}");
    }
    if let Some(text) = veils.text() {
        println!("  not opaque (smoke, a membrane: not masked), in {frames_with_veils} frames: {text}");
    }
    if let Some(path) = &args.preview {
        println!("preview: {}", path.display());
    }
    Ok(())
}

/// The opacity figures of a set of candidate regions.
#[derive(Debug, Default)]
struct Opacity {
    edge_contrast: Vec<f32>,
    colour_return: Vec<f32>,
}

impl Opacity {
    fn json(&mut self) -> serde_json::Value {
        serde_json::json!({
            "regions": self.edge_contrast.len(),
            "edge_contrast": spread(&mut self.edge_contrast).map(|s| s.json()),
            "colour_return": spread(&mut self.colour_return).map(|s| s.json()),
        })
    }

    fn text(&mut self) -> Option<String> {
        let regions = self.edge_contrast.len();
        let edge = spread(&mut self.edge_contrast)?;
        let colour = spread(&mut self.colour_return)?;
        Some(format!("{regions} regions, edge contrast {edge}, colour return {colour}"))
    }
}

/// Least, median and greatest of a set of opacity figures.
#[derive(Debug, Clone, Copy)]
struct Spread {
    least: f32,
    median: f32,
    greatest: f32,
}

impl Spread {
    fn json(&self) -> serde_json::Value {
        // An infinite figure (nothing to compare with) is not a JSON number.
        let finite = |v: f32| if v.is_finite() { serde_json::json!(v) } else { serde_json::Value::Null };
        serde_json::json!({ "min": finite(self.least), "median": finite(self.median), "max": finite(self.greatest) })
    }
}

impl std::fmt::Display for Spread {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:.2} … {:.2} (median {:.2})", self.least, self.greatest, self.median)
    }
}

fn spread(values: &mut [f32]) -> Option<Spread> {
    values.sort_by(f32::total_cmp);
    let (&least, &greatest) = (values.first()?, values.last()?);
    Some(Spread { least, median: values[values.len() / 2], greatest })
}
