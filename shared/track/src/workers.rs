//! The tracker's background threads (local bundle adjustment, loop closing) and the owner's say in how they run.

/// Called first on every worker thread the tracker starts: where the process that owns the tracker sets how
/// its background work is scheduled (the tracking service lowers its priority below the frame-rate work). The
/// library itself leaves threads as they are.
pub type WorkerStart = fn();
