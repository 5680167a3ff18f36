//! The ORB front end of the tracker, as pure compute: extraction (ORB-SLAM2-STEREO.md §1) and stereo matching
//! of features (§2), written from the specification. Buffers are owned by the extractor and matcher and reused.

pub mod extract;
pub mod matching;
pub mod nearest;
pub mod pattern;
mod simd;
pub mod stereo;

pub use extract::{
    Features, KeyPoint, Level, OrbError, OrbExtractor, OrbParams, hamming, image_to_level, level_to_image,
};
pub use matching::{FeatureGrid, RotationBins, RotationHistogram};
pub use nearest::{hamming_distances, nearest_two};
pub use stereo::{StereoFeatures, StereoMatcher, close_depth};
