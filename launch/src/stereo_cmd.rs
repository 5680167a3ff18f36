//! `bdis-slam stereo`: BDIS (or plain DIS) on one rectified pair or on every pair of a sequence, writing
//! disparity (PFM), optionally confidence (PFM) and a colour preview (PNG).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use bdis_stereo::{DisparityMap, GrayImage, Matcher, Params};

#[derive(Debug, clap::Args)]
pub struct StereoArgs {
    /// Left image of one pair.
    #[arg(long, requires = "right", conflicts_with = "sequence")]
    left: Option<PathBuf>,
    /// Right image of one pair.
    #[arg(long, requires = "left")]
    right: Option<PathBuf>,
    /// A sequence folder (any layout `bdis-slam run` reads): every pair is matched.
    #[arg(long, required_unless_present = "left")]
    sequence: Option<PathBuf>,
    /// Output: a .pfm file for one pair, a folder for a sequence (`<name>.pfm` per pair).
    #[arg(long)]
    out: PathBuf,
    /// Also write the confidence in [0, 1] (one pair: this .pfm file; sequence: `<name>.conf.pfm`).
    #[arg(long)]
    confidence: Option<Option<PathBuf>>,
    /// Also write a preview PNG: the left image beside the colour-mapped disparity (sequence: `<name>.png`).
    #[arg(long)]
    preview: Option<Option<PathBuf>>,
    /// Settings file whose `BDISparam.*` to use (ORB-SLAM2 YAML or bdis-slam TOML).
    #[arg(long)]
    settings: Option<PathBuf>,
    /// Start from a named parameter set: `slam` (BDIS-SLAM: patch 10, overlap 0.60) or `colon` (the synthetic
    /// colon sets: patch 8, overlap 0.40, unit_disturb 1).
    #[arg(long, conflicts_with = "settings", default_value = "slam")]
    preset: String,
    /// Override one parameter by its settings name, e.g. `--param patchsz=8` (repeatable).
    #[arg(long = "param", value_name = "NAME=VALUE")]
    params: Vec<String>,
    /// `bdis` (Bayesian) or `dis` (plain DIS, the baseline).
    #[arg(long, default_value = "bdis")]
    algorithm: String,
}

fn params_of(args: &StereoArgs) -> Result<Params> {
    let mut params = match (&args.settings, args.preset.as_str()) {
        (Some(path), _) => Params::from_settings(&bdis_core::Settings::load(path)?.bdis),
        (None, "slam") => Params::default(),
        (None, "colon") => Params::colon(),
        (None, other) => bail!("--preset: `{other}` is not a parameter set (slam, colon)"),
    };
    params.apply_overrides(&args.params, &args.algorithm)?;
    Ok(params)
}

pub(crate) fn view(g: &image::GrayImage) -> GrayImage<'_> {
    GrayImage { width: g.width() as usize, height: g.height() as usize, data: g.as_raw() }
}

/// Decodes an image to grey (BT.601, as acquisition does) and RGB.
pub(crate) fn load(path: &Path) -> Result<(image::GrayImage, image::RgbImage)> {
    let rgb = image::open(path).with_context(|| format!("{}: cannot read the image", path.display()))?.to_rgb8();
    let gray = image::GrayImage::from_fn(rgb.width(), rgb.height(), |x, y| {
        let p = rgb.get_pixel(x, y);
        image::Luma([bdis_core::pixel::gray_of(p[0], p[1], p[2])])
    });
    Ok((gray, rgb))
}

struct Outputs {
    disparity: PathBuf,
    confidence: Option<PathBuf>,
    preview: Option<PathBuf>,
}

fn match_pair(
    matcher: &mut Matcher,
    left: &Path,
    right: &Path,
    out: &mut DisparityMap,
    outputs: &Outputs,
) -> Result<()> {
    let (lg, lrgb) = load(left)?;
    let (rg, _) = load(right)?;
    matcher
        .compute_into(view(&lg), view(&rg), out)
        .with_context(|| format!("{} + {}", left.display(), right.display()))?;
    bdis_core::formats::pfm::write_disparity(&outputs.disparity, out.width, out.height, &out.disparity)?;
    if let Some(path) = &outputs.confidence {
        bdis_core::formats::pfm::write(path, out.width, out.height, 1, &out.confidence)?;
    }
    if let Some(path) = &outputs.preview {
        bdis_slam::preview::disparity_beside_image(lrgb.as_raw(), &out.disparity, out.width as u32, out.height as u32)
            .save(path)
            .with_context(|| format!("{}: cannot write the preview", path.display()))?;
    }
    Ok(())
}

pub fn stereo(args: StereoArgs) -> Result<()> {
    let params = params_of(&args)?;
    let mut matcher = Matcher::new(params)?;
    let mut out = DisparityMap::default();
    if let (Some(left), Some(right)) = (&args.left, &args.right) {
        let with_ext = |ext: &str| args.out.with_extension(ext);
        let outputs = Outputs {
            disparity: args.out.clone(),
            confidence: args.confidence.clone().map(|p| p.unwrap_or_else(|| with_ext("conf.pfm"))),
            preview: args.preview.clone().map(|p| p.unwrap_or_else(|| with_ext("png"))),
        };
        let start = std::time::Instant::now();
        match_pair(&mut matcher, left, right, &mut out, &outputs)?;
        println!(
            "{}: {}×{}, density {:.1} %, {:.0} ms (including reading and writing)",
            outputs.disparity.display(),
            out.width,
            out.height,
            100.0 * out.density(),
            start.elapsed().as_secs_f64() * 1000.0
        );
        if let Some(p) = &outputs.preview {
            println!("preview: {}", p.display());
        }
        return Ok(());
    }
    let Some(sequence) = &args.sequence else { bail!("give --left and --right, or --sequence") };
    let sequence = bdis_source::Sequence::open(sequence)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("{}: cannot create the output folder", args.out.display()))?;
    let bar = bdis_slam::progress::bar(sequence.len() as u64, "matching {bar:40} {pos}/{len} pairs ({eta} left)");
    let start = std::time::Instant::now();
    let mut density_sum = 0.0;
    for entry in &sequence.frames {
        let stem = entry.left.file_stem().map_or_else(|| "pair".into(), |s| s.to_string_lossy().into_owned());
        let outputs = Outputs {
            disparity: args.out.join(format!("{stem}.pfm")),
            confidence: args.confidence.as_ref().map(|_| args.out.join(format!("{stem}.conf.pfm"))),
            preview: args.preview.as_ref().map(|_| args.out.join(format!("{stem}.png"))),
        };
        match_pair(&mut matcher, &entry.left, &entry.right, &mut out, &outputs)?;
        density_sum += out.density();
        bar.inc(1);
    }
    bar.finish_and_clear();
    println!(
        "{} pairs → {}: mean density {:.1} %, {:.0} ms per pair (including reading and writing)",
        sequence.len(),
        args.out.display(),
        100.0 * density_sum / sequence.len() as f64,
        start.elapsed().as_secs_f64() * 1000.0 / sequence.len() as f64
    );
    Ok(())
}
