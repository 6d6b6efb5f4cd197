//! The mapping pipeline and who runs it: inline, inside the tracking call that inserted the
//! keyframe (deterministic, the default), or in a thread of its own ([`thread`]). Both run
//! the one [`MappingPipeline::process`] and hand tracking the same [`Mapped`] results.

mod pipeline;
mod thread;

use std::collections::HashMap;
use std::sync::atomic::AtomicUsize;
use std::sync::Arc;

use ferroslam_map::Map;
use ferroslam_vocabulary::Vocabulary;

pub(crate) use pipeline::{KeyFrameWork, Mapped, MappingPipeline, MappingRequest};
use pipeline::{MappingJob, Progress};
use thread::MappingThread;

use crate::context::Context;
use crate::error::SlamError;

/// Where the mapping pipeline runs.
pub(crate) enum Mapping {
    /// In the tracking call that inserts the keyframe.
    Inline(MappingPipeline),
    /// In the mapping thread, on copies of the map.
    Thread(MappingThread),
}

impl Default for Mapping {
    fn default() -> Self {
        Self::Inline(MappingPipeline::default())
    }
}

impl Mapping {
    /// Whether the pipeline runs in the mapping thread.
    pub(crate) fn is_threaded(&self) -> bool {
        matches!(self, Self::Thread(_))
    }

    /// Moves the pipeline, with its state, into a thread of its own (`true`) or back inline.
    /// Finish the thread's work ([`Self::collect`] with `wait`) before moving it back.
    pub(crate) fn set_threaded(&mut self, on: bool, ctx: &Context) {
        *self = match std::mem::take(self) {
            Self::Inline(pipeline) if on => {
                Self::Thread(MappingThread::spawn(ctx.clone(), pipeline))
            }
            Self::Thread(thread) if !on => Self::Inline(thread.stop_thread()),
            same => same,
        };
    }

    /// Hands a request over: inline it is processed at once and its result returned; the
    /// thread queues it (its result comes with a later [`Self::collect`], or is waited for
    /// and returned with `SlamConfig::deterministic`).
    pub(crate) fn submit(
        &mut self,
        request: MappingRequest,
        map: &mut Map,
        ctx: &Context,
        vocabulary: Option<&Arc<Vocabulary>>,
    ) -> Option<Mapped> {
        match self {
            Self::Inline(pipeline) => {
                let (merged_seam, work) = match request {
                    MappingRequest::KeyFrame(work) => (None, vec![work]),
                    MappingRequest::AdjustMerged { seam } => (Some(seam), Vec::new()),
                };
                let job = MappingJob {
                    merged_seam,
                    work,
                    fresh: false,
                    renamed: HashMap::new(),
                    vocabulary: vocabulary.cloned(),
                    hurried: false,
                };
                Some(Progress::inline(|progress| {
                    pipeline.process(job, map, ctx, progress)
                }))
            }
            Self::Thread(thread) => {
                thread.push(request, map, vocabulary);
                // Deterministic: mapped before the call returns, in the inline order of
                // events (the queue was empty: every keyframe before was waited for too).
                ctx.config
                    .deterministic
                    .then(|| thread.collect(map, vocabulary, true).pop())
                    .flatten()
            }
        }
    }

    /// The thread's finished jobs, their edits replayed on `map` (all of them, waiting, if
    /// `wait`); nothing inline.
    ///
    /// # Errors
    /// Why the mapping thread stopped, at every call once it has.
    pub(crate) fn collect(
        &mut self,
        map: &mut Map,
        vocabulary: Option<&Arc<Vocabulary>>,
        wait: bool,
    ) -> Result<Vec<Mapped>, SlamError> {
        let Self::Thread(thread) = self else {
            return Ok(Vec::new());
        };
        let finished = thread.collect(map, vocabulary, wait);
        match thread.failure() {
            Some(failure) => Err(failure.clone()),
            None => Ok(finished),
        }
    }

    /// Forgets the map (reset or replaced): inline at once, in the thread with its next job.
    pub(crate) fn reset(&mut self) {
        match self {
            Self::Inline(pipeline) => pipeline.reset(),
            Self::Thread(thread) => thread.reset(),
        }
    }

    /// Tracking starts a frame (the thread paces itself on the frame rate).
    pub(crate) fn frame_started(&mut self) {
        if let Self::Thread(thread) = self {
            thread.frame_started();
        }
    }

    /// Keyframes queued or in progress (0 inline: a keyframe is mapped within its call).
    pub(crate) fn backlog(&self) -> usize {
        match self {
            Self::Inline(_) => 0,
            Self::Thread(thread) => thread.backlog(),
        }
    }

    /// The thread's backlog counter, shared so another thread can poll it.
    pub(crate) fn backlog_handle(&self) -> Option<Arc<AtomicUsize>> {
        match self {
            Self::Inline(_) => None,
            Self::Thread(thread) => Some(thread.backlog_handle()),
        }
    }

    /// Asks the thread's job in flight to skip its optional work: tracking will wait for it.
    pub(crate) fn interrupt(&self) {
        if let Self::Thread(thread) = self {
            thread.interrupt();
        }
    }

    /// The pipeline, when it runs inline.
    pub(crate) fn inline_pipeline(&mut self) -> Option<&mut MappingPipeline> {
        match self {
            Self::Inline(pipeline) => Some(pipeline),
            Self::Thread(_) => None,
        }
    }
}
