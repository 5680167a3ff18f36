//! `latency.svg`: the report drawn, bars to p50, whiskers to p99, a dot at max, on a log scale.

use super::*;

/// One row of a latency chart: a label and percentiles in µs.
struct ChartRow<'a> {
    label: String,
    p: &'a Percentiles,
}

fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
}

/// A horizontal log-scale chart: per row a bar to p50, a whisker to p99 and a mark at max.
fn chart(out: &mut String, title: &str, rows: &[ChartRow], y0: f64) -> f64 {
    const LEFT: f64 = 250.0;
    const WIDTH: f64 = 560.0;
    const ROW: f64 = 22.0;
    let _ = writeln!(out, r#"<text x="10" y="{:.0}" class="title">{}</text>"#, y0 + 16.0, xml_escape(title));
    if rows.is_empty() {
        return y0 + 30.0;
    }
    // Decades from below the smallest p50 to above the largest max.
    let lo = rows.iter().map(|r| r.p.p50.max(0.1)).fold(f64::INFINITY, f64::min).log10().floor();
    let hi = rows.iter().map(|r| r.p.max.max(r.p.p99).max(1.0)).fold(0.0, f64::max).log10().ceil().max(lo + 1.0);
    let x = |us: f64| LEFT + WIDTH * ((us.max(10f64.powf(lo)).log10() - lo) / (hi - lo)).clamp(0.0, 1.0);
    let top = y0 + 26.0;
    let bottom = top + ROW * rows.len() as f64;
    for d in lo as i32..=hi as i32 {
        let us = 10f64.powi(d);
        let label = if us >= 1000.0 { format!("{} ms", us / 1000.0) } else { format!("{us} µs") };
        let _ = writeln!(
            out,
            r#"<line x1="{0:.1}" y1="{top:.0}" x2="{0:.1}" y2="{bottom:.0}" class="grid"/><text x="{0:.1}" y="{1:.0}" class="axis">{label}</text>"#,
            x(us),
            bottom + 14.0
        );
    }
    for (i, r) in rows.iter().enumerate() {
        let y = top + ROW * i as f64;
        let _ = writeln!(
            out,
            r#"<text x="{:.0}" y="{:.0}" class="label">{}</text><rect x="{LEFT}" y="{:.0}" width="{:.1}" height="12" class="p50"><title>p50 {:.1} µs, p90 {:.1} µs, p99 {:.1} µs, max {:.1} µs</title></rect><line x1="{:.1}" y1="{:.0}" x2="{:.1}" y2="{:.0}" class="p99"/><line x1="{:.1}" y1="{:.0}" x2="{:.1}" y2="{:.0}" class="p99"/><circle cx="{:.1}" cy="{:.0}" r="2.5" class="max"/>"#,
            LEFT - 8.0,
            y + 11.0,
            xml_escape(&r.label),
            y + 2.0,
            (x(r.p.p50) - LEFT).max(1.0),
            r.p.p50,
            r.p.p90,
            r.p.p99,
            r.p.max,
            x(r.p.p50),
            y + 8.0,
            x(r.p.p99),
            y + 8.0,
            x(r.p.p99),
            y + 3.0,
            x(r.p.p99),
            y + 13.0,
            x(r.p.max),
            y + 8.0
        );
    }
    bottom + 24.0
}

impl LatencyReport {
    /// `latency.svg`: the table's figures to look at — per process the time spent on a message and the age of
    /// its output since capture, per hop the transport latency; bars to p50, whiskers to p99, dots at max, on a
    /// log scale (hover a bar for the numbers).
    pub fn svg(&self) -> String {
        let mut body = String::new();
        let processing: Vec<ChartRow> = self
            .processes
            .iter()
            .filter_map(|p| {
                p.processing_us.as_ref().map(|q| ChartRow { label: format!("{} ({} msgs)", p.name, p.messages), p: q })
            })
            .collect();
        let age: Vec<ChartRow> = self
            .processes
            .iter()
            .filter_map(|p| p.age_us.as_ref().map(|q| ChartRow { label: format!("{} output", p.name), p: q }))
            .collect();
        let hops: Vec<ChartRow> = self
            .hops
            .iter()
            .map(|h| ChartRow { label: format!("{}→{} ({})", h.from, h.to, h.topic), p: &h.latency_us })
            .collect();
        let end_to_end: Vec<ChartRow> = self
            .end_to_end
            .iter()
            .map(|e| ChartRow { label: format!("{} ({})", e.path, e.process), p: &e.latency_us })
            .collect();
        let mut y = 0.0;
        if !end_to_end.is_empty() {
            y = chart(&mut body, "End to end: from a frame's capture to its pose and to the map", &end_to_end, y);
        }
        y = chart(&mut body, "Processing per message (p50 bar, p99 whisker, max dot)", &processing, y);
        y = chart(&mut body, "Age of each process's output since capture", &age, y);
        y = chart(&mut body, "Transport latency per hop (publish → receive, zero copy)", &hops, y);
        format!(
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="840" height="{:.0}" viewBox="0 0 840 {:.0}" font-family="sans-serif" font-size="12">
<style>.title{{font-weight:bold;font-size:13px}} .label{{text-anchor:end}} .axis{{text-anchor:middle;fill:#666;font-size:10px}} .grid{{stroke:#ddd}} .p50{{fill:#4a7fb5}} .p99{{stroke:#b5524a;stroke-width:1.5}} .max{{fill:#b5524a}}</style>
<rect width="100%" height="100%" fill="white"/>
{body}</svg>
"#,
            y, y
        )
    }
}
