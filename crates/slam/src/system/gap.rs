//! Poses for the frames of a tracking gap: frames that end without a pose (lost, or before
//! a map starts) are kept, and once a later frame is tracked they are tracked backwards
//! from it, newest first (the constant-velocity model and the local map, as forward
//! tracking, from the last frame posed; no keyframes are made). Each frame posed joins the
//! current map's trajectory, so the trajectory fills in behind the live results: a frame's
//! own result still says it was lost. The frames of a young map that is dropped (ORB-SLAM's
//! rule for a map lost with few keyframes) become frames without a pose again. The map is
//! not changed. Visual maps only: an inertial state integrates in time order.

use super::SlamSystem;
use crate::error::SlamError;
use crate::frame::Frame;

impl SlamSystem {
    /// Whether frames without a pose are kept for [`Self::fill_gap`].
    pub(super) fn keeps_untracked(&self) -> bool {
        self.ctx.config.tracking.gap_frames > 0 && self.inertial.is_none()
    }

    /// Keeps `frame` (no pose) for [`Self::fill_gap`]; beyond `tracking.gap_frames` the
    /// oldest is dropped, as tracking would not reach it.
    pub(super) fn keep_untracked(&mut self, frame: Frame) {
        push_newest(
            &mut self.untracked,
            frame,
            self.ctx.config.tracking.gap_frames,
        );
    }

    /// Keeps a frame just posed in the current map while the map is young: a young map lost
    /// is dropped, and its frames become frames without a pose again.
    pub(super) fn keep_young(&mut self, frame: &Frame) {
        let young = self.map.num_keyframes() <= self.ctx.config.tracking.min_keyframes_to_keep;
        if !young || !self.keeps_untracked() {
            self.young_frames.clear();
            return;
        }
        let keep = self.ctx.config.tracking.gap_frames;
        push_newest(&mut self.young_frames, frame.clone(), keep);
    }

    /// The frames of the young map being dropped join those without a pose, in time order
    /// (the newest `tracking.gap_frames`).
    pub(super) fn unpose_young_frames(&mut self) {
        let mut frames = std::mem::take(&mut self.young_frames);
        frames.append(&mut self.untracked);
        frames.sort_by(|a, b| a.timestamp.total_cmp(&b.timestamp));
        let keep = self.ctx.config.tracking.gap_frames;
        self.untracked = frames.split_off(frames.len().saturating_sub(keep));
    }

    /// Tracks the kept frames backwards from the tracker's last frame (just tracked in the
    /// current map); those it cannot pose are dropped.
    pub(super) fn fill_gap(&mut self) -> Result<(), SlamError> {
        if self.untracked.is_empty() {
            return Ok(());
        }
        let untracked = std::mem::take(&mut self.untracked);
        let Some(mut tracker) = self.tracker.backwards() else {
            return Ok(());
        };
        // On a copy (sharing its entries): the points' visible / found counters stay those
        // of forward tracking, so a run's map is the same with or without its gaps filled.
        let mut map = self.map.clone();
        for mut frame in untracked.into_iter().rev() {
            if !tracker.track(&mut frame, &mut map, &self.ctx, None)? {
                // A blurred frame need not end the gap: the older ones are tried from the
                // last frame posed.
                tracker = tracker.backwards().expect("the last frame posed");
                continue;
            }
            // A monocular map's first keyframe was kept too, before it made the map.
            let posed = tracker.reference_kf.is_some_and(|reference| {
                self.trajectory
                    .insert(frame.timestamp, &frame.T_c_w, reference, &self.map)
            });
            if posed {
                self.keep_young(&frame);
            }
            tracker.set_last_frame(frame, &map, &self.ctx, false);
        }
        Ok(())
    }
}

/// Appends `frame`, dropping the oldest beyond `keep` frames.
fn push_newest(frames: &mut Vec<Frame>, frame: Frame, keep: usize) {
    if frames.len() >= keep {
        frames.remove(0);
    }
    frames.push(frame);
}
