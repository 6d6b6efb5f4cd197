//! Id newtypes of the map's entities. Ids are allocated in increasing order and never reused.

use std::fmt;

/// Identifier of a [`crate::KeyFrame`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct KeyFrameId(pub u32);

/// Identifier of a [`crate::MapPoint`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct MapPointId(pub u32);

impl fmt::Display for KeyFrameId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "KF{}", self.0)
    }
}

impl fmt::Display for MapPointId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "MP{}", self.0)
    }
}
