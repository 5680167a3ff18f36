//! Draws `map.png` again from a saved `map.bin`: `preview MAP_BIN OUT_PNG [WIDTH]`.

use std::process::ExitCode;

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (Some(map), Some(out)) = (args.first(), args.get(1)) else {
        eprintln!("usage: preview MAP_BIN OUT_PNG [WIDTH]");
        return ExitCode::FAILURE;
    };
    let width = args.get(2).and_then(|w| w.parse().ok()).unwrap_or(1024);
    let mosaic = match bdis_mosaic::load(std::path::Path::new(map)) {
        Ok(m) => m,
        Err(e) => {
            eprintln!("preview: {e}");
            return ExitCode::FAILURE;
        }
    };
    let Some((image, view)) = bdis_mosaic::render_preview(&mosaic, width) else {
        eprintln!("preview: {map}: the map is empty");
        return ExitCode::FAILURE;
    };
    if let Err(e) = image.save(out) {
        eprintln!("preview: {out}: {e}");
        return ExitCode::FAILURE;
    }
    println!(
        "{out}: {} points drawn, looking along {:.2?}, {:.3} mm/px",
        view.points_drawn, view.looking_along, view.mm_per_pixel
    );
    ExitCode::SUCCESS
}
