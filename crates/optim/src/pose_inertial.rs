//! Visual-inertial motion-only optimisation for tracking (in progress).
