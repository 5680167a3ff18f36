//! `eval traj --plot FILE.svg`: where along the run the error is, to look at beside the numbers. One panel
//! draws each pose's position error after the ATE's alignment over time, with what the tracker reported behind
//! it (from the run's quality log: `Uncertain`, `Lost` and not-yet-initialised frames shaded, keyframes
//! ticked); with `--quality`, a second panel draws the honesty bar: each judged `Ok` frame's error relative to
//! its keyframe over the travel since, against the bar.

use std::fmt::Write as _;

use bdis_core::formats::quality::{QualityLog, ReportedState};
use bdis_eval::status::StatusHonesty;
use bdis_eval::traj::PositionError;

const WIDTH: f64 = 840.0;
const LEFT: f64 = 70.0;
const RIGHT: f64 = 20.0;
const PANEL: f64 = 200.0;

/// What a plot shows.
pub struct TrajPlot<'a> {
    pub title: &'a str,
    /// After each time tick: ` s`, or nothing where times are pose numbers (KITTI).
    pub time_unit: &'a str,
    pub errors: &'a [PositionError],
    pub ate_rmse: f64,
    pub log: Option<&'a QualityLog>,
    pub status: Option<&'a StatusHonesty>,
}

fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
}

/// Ticks at 1, 2 or 5 × a power of ten, about five over `0..=hi`.
fn ticks(hi: f64) -> Vec<f64> {
    if !(hi.is_finite() && hi > 0.0) {
        return vec![0.0];
    }
    let raw = hi / 5.0;
    let decade = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0].into_iter().map(|m| m * decade).find(|s| *s >= raw).unwrap_or(10.0 * decade);
    (0..).map(|i| i as f64 * step).take_while(|v| *v <= hi * (1.0 + 1e-9)).collect()
}

/// Shortest form of a tick value (no float noise such as 0.30000000000000004).
fn tick_label(v: f64) -> String {
    let s = format!("{v:.6}");
    s.trim_end_matches('0').trim_end_matches('.').to_owned()
}

/// One panel's axes: time on x, `0..=y_max` on y, the panel's top at `top`.
struct Axes {
    t0: f64,
    t1: f64,
    y_max: f64,
    top: f64,
}

impl Axes {
    fn x(&self, t: f64) -> f64 {
        LEFT + (WIDTH - LEFT - RIGHT) * ((t - self.t0) / (self.t1 - self.t0)).clamp(0.0, 1.0)
    }
    fn y(&self, v: f64) -> f64 {
        self.top + PANEL * (1.0 - (v / self.y_max).clamp(0.0, 1.0))
    }
    fn bottom(&self) -> f64 {
        self.top + PANEL
    }

    /// Title, grid, tick labels.
    fn draw(&self, out: &mut String, title: &str, y_label: &str, y_scale: f64, time_unit: &str) {
        let _ = writeln!(out, r#"<text x="10" y="{:.0}" class="title">{}</text>"#, self.top - 12.0, xml_escape(title));
        for v in ticks(self.y_max) {
            let y = self.y(v);
            let _ = writeln!(
                out,
                r#"<line x1="{LEFT}" y1="{y:.1}" x2="{:.0}" y2="{y:.1}" class="grid"/><text x="{:.0}" y="{:.1}" class="ylabel">{}</text>"#,
                WIDTH - RIGHT,
                LEFT - 6.0,
                y + 4.0,
                tick_label(v * y_scale)
            );
        }
        for t in ticks(self.t1 - self.t0) {
            let x = self.x(self.t0 + t);
            let _ = writeln!(
                out,
                r#"<line x1="{x:.1}" y1="{:.0}" x2="{x:.1}" y2="{:.0}" class="grid"/><text x="{x:.1}" y="{:.0}" class="axis">{}{time_unit}</text>"#,
                self.top,
                self.bottom(),
                self.bottom() + 14.0,
                tick_label(self.t0 + t)
            );
        }
        let _ = writeln!(
            out,
            r#"<text x="12" y="{:.0}" class="axis" transform="rotate(-90 12 {:.0})">{}</text>"#,
            self.top + PANEL / 2.0,
            self.top + PANEL / 2.0,
            xml_escape(y_label)
        );
    }
}

fn state_class(state: ReportedState) -> Option<&'static str> {
    match state {
        ReportedState::Ok => None,
        ReportedState::Uncertain => Some("uncertain"),
        ReportedState::Lost => Some("lost"),
        ReportedState::NotInitialised => Some("uninit"),
    }
}

/// The frames the tracker did not report `Ok`, as shaded spans (each frame to the next one's time), and its
/// keyframes as ticks under the axis.
fn draw_states(out: &mut String, axes: &Axes, log: &QualityLog) {
    let lines = &log.lines;
    for (i, line) in lines.iter().enumerate() {
        let Some(class) = state_class(line.state) else { continue };
        let next = lines.get(i + 1).map_or(line.t_source_s, |n| n.t_source_s);
        let (x0, x1) = (axes.x(line.t_source_s), axes.x(next.max(line.t_source_s)));
        let _ = writeln!(
            out,
            r#"<rect x="{x0:.1}" y="{:.0}" width="{:.1}" height="{PANEL}" class="{class}"><title>{:.3} s: {}{}</title></rect>"#,
            axes.top,
            (x1 - x0).max(1.0),
            line.t_source_s,
            line.state.name(),
            line.doubt.as_deref().map(|d| format!(" ({d})")).unwrap_or_default()
        );
    }
    for line in lines.iter().filter(|l| l.keyframe.is_some()) {
        let x = axes.x(line.t_source_s);
        let _ = writeln!(
            out,
            r#"<line x1="{x:.1}" y1="{:.0}" x2="{x:.1}" y2="{:.0}" class="keyframe"/>"#,
            axes.bottom() - 5.0,
            axes.bottom()
        );
    }
}

impl TrajPlot<'_> {
    pub fn svg(&self) -> String {
        let mut body = String::new();
        let times = self.errors.iter().map(|e| e.t_s);
        let (mut t0, mut t1) = times.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), t| (a.min(t), b.max(t)));
        if !(t0.is_finite() && t1 > t0) {
            (t0, t1) = if t0.is_finite() { (t0, t0 + 1.0) } else { (0.0, 1.0) };
        }
        let worst = self.errors.iter().map(|e| e.error).fold(0.0, f64::max);
        let axes = Axes { t0, t1, y_max: if worst > 0.0 { worst * 1.05 } else { 1.0 }, top: 40.0 };
        if let Some(log) = self.log {
            draw_states(&mut body, &axes, log);
        }
        axes.draw(
            &mut body,
            &format!("{}: position error after alignment (ATE RMSE {:.6})", self.title, self.ate_rmse),
            "error (the trajectory's unit)",
            1.0,
            self.time_unit,
        );
        let points: Vec<String> =
            self.errors.iter().map(|e| format!("{:.1},{:.1}", axes.x(e.t_s), axes.y(e.error))).collect();
        let _ = writeln!(body, r#"<polyline points="{}" class="error"/>"#, points.join(" "));
        let _ = writeln!(
            body,
            r#"<line x1="{LEFT}" y1="{0:.1}" x2="{1:.0}" y2="{0:.1}" class="rmse"/><text x="{1:.0}" y="{2:.1}" class="note">RMSE</text>"#,
            axes.y(self.ate_rmse),
            WIDTH - RIGHT,
            axes.y(self.ate_rmse) - 4.0
        );
        let mut height = axes.bottom() + 24.0;
        if self.log.is_some() {
            let _ = writeln!(
                body,
                r#"<rect x="{LEFT}" y="{0:.0}" width="10" height="10" class="uncertain"/><text x="{1:.0}" y="{2:.0}">Uncertain</text><rect x="{3:.0}" y="{0:.0}" width="10" height="10" class="lost"/><text x="{4:.0}" y="{2:.0}">Lost</text><rect x="{5:.0}" y="{0:.0}" width="10" height="10" class="uninit"/><text x="{6:.0}" y="{2:.0}">not initialised</text><line x1="{7:.0}" y1="{0:.0}" x2="{7:.0}" y2="{8:.0}" class="keyframe"/><text x="{9:.0}" y="{2:.0}">keyframe</text>"#,
                height - 2.0,
                LEFT + 14.0,
                height + 7.0,
                LEFT + 100.0,
                LEFT + 114.0,
                LEFT + 170.0,
                LEFT + 184.0,
                LEFT + 300.0,
                height + 8.0,
                LEFT + 306.0
            );
            height += 24.0;
        }
        if let Some(status) = self.status {
            height = self.draw_honesty(&mut body, status, t0, t1, height + 30.0);
        }
        format!(
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="{WIDTH}" height="{height:.0}" viewBox="0 0 {WIDTH} {height:.0}" font-family="sans-serif" font-size="12">
<style>.title{{font-weight:bold;font-size:13px}} .axis{{text-anchor:middle;fill:#666;font-size:10px}} .ylabel{{text-anchor:end;fill:#666;font-size:10px}} .note{{text-anchor:end;fill:#666;font-size:10px}} .grid{{stroke:#e4e4e4}} .error{{fill:none;stroke:#4a7fb5;stroke-width:1.3}} .rmse{{stroke:#4a7fb5;stroke-dasharray:4 3}} .bar{{stroke:#b5524a;stroke-dasharray:4 3}} .uncertain{{fill:#f2c14e;fill-opacity:0.35}} .lost{{fill:#d9534f;fill-opacity:0.35}} .uninit{{fill:#999;fill-opacity:0.25}} .keyframe{{stroke:#333}} .judged{{fill:#4a7fb5}} .over{{fill:#b5524a}}</style>
<rect width="100%" height="100%" fill="white"/>
{body}</svg>
"#
        )
    }

    /// The honesty bar's panel; returns the height used so far.
    fn draw_honesty(&self, out: &mut String, status: &StatusHonesty, t0: f64, t1: f64, top: f64) -> f64 {
        let bar = status.bar.max_error_of_travel;
        let axes = Axes { t0, t1, y_max: status.worst_error_of_travel.max(bar) * 1.1, top };
        axes.draw(
            out,
            &format!(
                "Ok frames: error relative to their keyframe over the travel since it ({} judged, {} over {} %)",
                status.judged,
                status.wrong_ok.len(),
                tick_label(100.0 * bar)
            ),
            "% of the travel",
            100.0,
            self.time_unit,
        );
        for frame in &status.judged_frames {
            let class = if frame.error_of_travel > bar { "over" } else { "judged" };
            let _ = writeln!(
                out,
                r#"<circle cx="{:.1}" cy="{:.1}" r="2.2" class="{class}"><title>{:.3} s: {:.2} %</title></circle>"#,
                axes.x(frame.t_s),
                axes.y(frame.error_of_travel),
                frame.t_s,
                100.0 * frame.error_of_travel
            );
        }
        let _ = writeln!(
            out,
            r#"<line x1="{LEFT}" y1="{0:.1}" x2="{1:.0}" y2="{0:.1}" class="bar"/><text x="{1:.0}" y="{2:.1}" class="note">the bar</text>"#,
            axes.y(bar),
            WIDTH - RIGHT,
            axes.y(bar) - 4.0
        );
        axes.bottom() + 24.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_are_round_and_cover_the_range() {
        let labels: Vec<String> = ticks(1.0).into_iter().map(tick_label).collect();
        assert_eq!(labels, ["0", "0.2", "0.4", "0.6", "0.8", "1"]);
        let t = ticks(0.0137);
        assert_eq!(t.first(), Some(&0.0));
        assert!(t.len() >= 3 && t.len() <= 8 && *t.last().unwrap_or(&0.0) <= 0.0137, "{t:?}");
        assert_eq!(tick_label(0.1 + 0.2), "0.3");
        assert_eq!(ticks(0.0), [0.0]);
    }
}
