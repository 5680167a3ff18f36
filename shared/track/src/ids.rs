//! The map's ids: an index into the map's keyframes and into its points. They live here, not in `map`, so that
//! `frame` (which holds a point id per keypoint) and `map` (which is built from frames) do not import each
//! other. Ids are never reused: a culled keyframe or point stays in place, flagged `bad`.

/// A keyframe: its index in `Map::keyframes`.
pub type KfId = usize;
/// A map point: its index in `Map::points`.
pub type PointId = usize;
