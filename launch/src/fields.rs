//! `run --interlaced`: the settings of the published fields, written from the woven frame's settings.

use std::path::Path;

use anyhow::{Context, Result, bail};
use bdis_source::FieldMode;

/// Writes `out`: the settings at `frame_settings` with the camera of what acquisition publishes in `mode` —
/// for one field, `fy` and `cy` halved (`FieldMode::field_camera`) and `Camera.height` halved where it is
/// given. Everything else is kept as written (ORB-SLAM2 YAML line by line, TOML through its table).
pub fn write_field_settings(frame_settings: &Path, mode: FieldMode, out: &Path) -> Result<()> {
    let settings = bdis_core::Settings::load(frame_settings)?;
    let camera = settings.camera;
    let (fy, cy) = mode.field_camera(camera.fy, camera.cy);
    let height = camera.height.and_then(|h| mode.output_size(camera.width.unwrap_or(1), h)).map(|(_, h)| h);
    if camera.height.is_some() && height.is_none() {
        bail!("{}: Camera.height {:?} cannot be split into fields", frame_settings.display(), camera.height);
    }
    let text = std::fs::read_to_string(frame_settings).with_context(|| format!("read {}", frame_settings.display()))?;
    let written = if frame_settings.extension().is_some_and(|e| e == "toml") {
        let mut table: toml::Table = text.parse().with_context(|| format!("{}", frame_settings.display()))?;
        let camera = table.get_mut("Camera").and_then(|c| c.as_table_mut()).context("no [Camera] table")?;
        camera.insert("fy".into(), toml::Value::Float(fy));
        camera.insert("cy".into(), toml::Value::Float(cy));
        if let Some(h) = height {
            camera.insert("height".into(), toml::Value::Integer(i64::from(h)));
        }
        toml::to_string(&table)?
    } else {
        let mut lines =
            vec![format!("# {} fields of {} (bdis-slam run --interlaced)", mode.name(), frame_settings.display())];
        for line in text.lines() {
            let key = line.split(':').next().unwrap_or_default().trim();
            let value = match key {
                "Camera.fy" => Some(fy.to_string()),
                "Camera.cy" => Some(cy.to_string()),
                "Camera.height" => height.map(|h| h.to_string()),
                _ => None,
            };
            lines.push(value.map_or_else(|| line.to_string(), |v| format!("{key}: {v}")));
        }
        // The YAML header must stay the first line.
        if lines.get(1).is_some_and(|l| l.starts_with("%YAML")) {
            lines.swap(0, 1);
        }
        lines.join("\n") + "\n"
    };
    std::fs::write(out, written).with_context(|| format!("write {}", out.display()))?;
    // Read back: the rewrite must have taken (a key written in a form the line rewrite missed would not).
    let check = bdis_core::Settings::load(out)?;
    if (check.camera.fy - fy).abs() > 1e-9 || (check.camera.cy - cy).abs() > 1e-9 || check.camera.height != height {
        bail!("{}: could not rewrite Camera.fy / Camera.cy / Camera.height for the fields", frame_settings.display());
    }
    Ok(())
}
