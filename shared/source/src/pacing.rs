//! When each frame is due.

use std::str::FromStr;

/// How fast acquisition publishes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pacing {
    /// The next frame as soon as a consumer has released the last one (how the paper measured maximum rate).
    OnDemand,
    /// Follow the recording's `times.txt` (or the settings' fps when there is none), like a live camera.
    Recorded,
    /// A fixed rate in Hz.
    Fixed(f64),
    /// On demand, but no faster than this rate: a live camera's pace without ever dropping a frame (a slow
    /// consumer delays frames instead). Written `on-demand:30hz`.
    OnDemandAtMost(f64),
}

impl Pacing {
    /// True when a frame waits for a consumer's credit.
    pub fn waits_for_consumer(self) -> bool {
        matches!(self, Self::OnDemand | Self::OnDemandAtMost(_))
    }
}

fn parse_rate(s: &str, whole: &str) -> Result<f64, String> {
    let hz: f64 =
        s.trim_end_matches("hz").trim_end_matches("Hz").parse().map_err(|_| {
            format!("`{whole}`: expected on-demand, on-demand:<rate>, recorded, or a rate such as 30hz")
        })?;
    if hz.is_finite() && hz > 0.0 && hz <= 10_000.0 {
        Ok(hz)
    } else {
        Err(format!("`{whole}`: the rate must be in (0, 10000] Hz"))
    }
}

impl FromStr for Pacing {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "on-demand" => Ok(Self::OnDemand),
            "recorded" => Ok(Self::Recorded),
            _ => match s.strip_prefix("on-demand:") {
                Some(rate) => parse_rate(rate, s).map(Self::OnDemandAtMost),
                None => parse_rate(s, s).map(Self::Fixed),
            },
        }
    }
}

/// The due times of a sequence's frames relative to the moment streaming starts.
#[derive(Debug, Clone)]
pub struct Schedule {
    pacing: Pacing,
    fallback_period_s: f64,
    first_source_s: Option<f64>,
}

impl Schedule {
    /// `fallback_fps` is used by `Recorded` when the sequence has no timestamps.
    pub fn new(pacing: Pacing, first_source_s: Option<f64>, fallback_fps: f64) -> Self {
        Self { pacing, fallback_period_s: 1.0 / fallback_fps, first_source_s }
    }

    /// Offset in ns from the start at which frame `index` (with recording time `t_source_s`) is due; `None`
    /// when frames are not time-driven (on demand).
    pub fn due_offset_ns(&self, index: usize, t_source_s: Option<f64>) -> Option<u64> {
        let seconds = match self.pacing {
            Pacing::OnDemand => return None,
            Pacing::Fixed(hz) | Pacing::OnDemandAtMost(hz) => index as f64 / hz,
            Pacing::Recorded => match (t_source_s, self.first_source_s) {
                (Some(t), Some(t0)) => t - t0,
                _ => index as f64 * self.fallback_period_s,
            },
        };
        Some((seconds.max(0.0) * 1e9) as u64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_schedules() {
        assert_eq!("on-demand".parse::<Pacing>(), Ok(Pacing::OnDemand));
        assert_eq!("25hz".parse::<Pacing>(), Ok(Pacing::Fixed(25.0)));
        assert!("fast".parse::<Pacing>().is_err());
        assert!("0hz".parse::<Pacing>().is_err());
        assert_eq!("on-demand:30hz".parse::<Pacing>(), Ok(Pacing::OnDemandAtMost(30.0)));
        assert!("on-demand:fast".parse::<Pacing>().unwrap_err().contains("on-demand:<rate>"));
        assert!(Pacing::OnDemandAtMost(30.0).waits_for_consumer() && !Pacing::Fixed(30.0).waits_for_consumer());
        assert_eq!(Schedule::new(Pacing::OnDemandAtMost(10.0), None, 30.0).due_offset_ns(2, None), Some(200_000_000));
        let s = Schedule::new(Pacing::Recorded, Some(10.0), 30.0);
        assert_eq!(s.due_offset_ns(3, Some(10.5)), Some(500_000_000));
        let s = Schedule::new(Pacing::Recorded, None, 25.0);
        assert_eq!(s.due_offset_ns(5, None), Some(200_000_000));
        let s = Schedule::new(Pacing::Fixed(10.0), None, 30.0);
        assert_eq!(s.due_offset_ns(2, None), Some(200_000_000));
        assert_eq!(Schedule::new(Pacing::OnDemand, None, 30.0).due_offset_ns(2, None), None);
    }
}
