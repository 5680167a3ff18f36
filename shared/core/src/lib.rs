//! bdis-slam basics shared by every process: calibration and settings, geometry conventions, file formats.
//!
//! Conventions (see DESIGN.md): camera x right, y down, z forward; a pose is `world_from_camera` of the left
//! camera as `Isometry3<f64>`; disparity `d = x_left − x_right`, depth `z = bf / d`; lengths in the calibration's
//! unit (millimetres for endoscopes).
//!
//! Also [`fanout`]: watchers outside the pipeline (browsers, navigation workstations), each fed from a bounded
//! queue by a thread of its own, let go rather than waited for.

pub mod calib;
pub mod fanout;
pub mod formats;
pub mod geometry;
pub mod pixel;
pub mod scale;
pub mod settings;
pub mod stats;

pub use calib::{Distortion, RectifiedCamera, StereoCamera};
pub use geometry::Pose;
pub use settings::{Settings, SettingsError};
