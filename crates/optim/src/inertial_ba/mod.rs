//! Visual-inertial local bundle adjustment (in progress).
