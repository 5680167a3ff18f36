//! Interlaced footage from a render: a sequence rendered at twice the frame rate, one rendered frame per field,
//! woven as an SDI camera weaves it — frame `k`'s even rows are the top field (rendered frame `2k`, first in
//! time), its odd rows the bottom field (frame `2k + 1`, half a frame later). Beside it, the progressive
//! sequence a camera without interlacing would have given (frames `2k`), for comparison.

use std::path::Path;

use crate::SynthError;

/// What [`weave`] wrote.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Woven {
    pub frames: usize,
}

/// Weaves the field-rate sequence at `fields` (as `write_scene` writes it) into `interlaced` and writes its
/// progressive twin into `progressive`: `left/`, `right/`, `times.txt`, `settings.yaml` (at half the field
/// rate) and `gt/poses.tum` (the top field's poses, at its times) in each, `gt/mesh.ply` where the render has
/// one. An odd last field is left out.
pub fn weave(fields: &Path, interlaced: &Path, progressive: &Path) -> Result<Woven, SynthError> {
    let fail =
        |path: &Path, e: &dyn std::fmt::Display| SynthError::Write { path: path.to_path_buf(), detail: e.to_string() };
    let read = |path: &Path| std::fs::read_to_string(path).map_err(|e| fail(path, &e));
    let times_text = read(&fields.join("times.txt"))?;
    let times: Vec<&str> = times_text.lines().filter(|l| !l.trim().is_empty()).collect();
    let frames = times.len() / 2;
    for out in [interlaced, progressive] {
        for side in ["left", "right", "gt"] {
            std::fs::create_dir_all(out.join(side)).map_err(|e| fail(&out.join(side), &e))?;
        }
    }
    for k in 0..frames {
        for side in ["left", "right"] {
            let load = |i: usize| {
                let path = fields.join(format!("{side}/{}.png", i + 1));
                image::open(&path).map(|img| img.to_rgb8()).map_err(|e| fail(&path, &e))
            };
            let (top, bottom) = (load(2 * k)?, load(2 * k + 1)?);
            let mut woven = top.clone();
            for (y, row) in woven.rows_mut().enumerate().filter(|(y, _)| y % 2 == 1) {
                for (x, px) in row.enumerate() {
                    *px = *bottom.get_pixel(x as u32, y as u32);
                }
            }
            let name = format!("{side}/{}.png", k + 1);
            woven.save(interlaced.join(&name)).map_err(|e| fail(&interlaced.join(&name), &e))?;
            top.save(progressive.join(&name)).map_err(|e| fail(&progressive.join(&name), &e))?;
        }
    }
    let every_other = |lines: &mut dyn Iterator<Item = &str>| {
        let mut kept = String::new();
        for (i, line) in lines.filter(|l| !l.starts_with('#') && !l.trim().is_empty()).enumerate() {
            if i % 2 == 0 && i / 2 < frames {
                kept.push_str(line);
                kept.push('\n');
            }
        }
        kept
    };
    let times = every_other(&mut times.iter().copied());
    let poses_text = read(&fields.join("gt/poses.tum"))?;
    let header: String = poses_text.lines().filter(|l| l.starts_with('#')).map(|l| format!("{l}\n")).collect();
    let poses = header + &every_other(&mut poses_text.lines());
    let settings_text = read(&fields.join("settings.yaml"))?;
    let settings: String = settings_text
        .lines()
        .map(|line| match line.split_once(':') {
            Some(("Camera.fps", v)) => match v.trim().parse::<f64>() {
                Ok(fps) => format!("Camera.fps: {}\n", fps / 2.0),
                Err(_) => format!("{line}\n"),
            },
            _ => format!("{line}\n"),
        })
        .collect();
    for out in [interlaced, progressive] {
        for (name, text) in [("times.txt", &times), ("gt/poses.tum", &poses), ("settings.yaml", &settings)] {
            std::fs::write(out.join(name), text).map_err(|e| fail(&out.join(name), &e))?;
        }
        let mesh = fields.join("gt/mesh.ply");
        if mesh.is_file() {
            std::fs::copy(&mesh, out.join("gt/mesh.ply")).map_err(|e| fail(&mesh, &e))?;
        }
    }
    Ok(Woven { frames })
}
