//! The mapping pipeline: everything that happens to a keyframe after tracking inserted it,
//! in one place, whoever runs it (see [`super`]).
//!
//! Per keyframe, in order: local mapping grows the neighbourhood (culling of recent points,
//! triangulation, fusion; [`LocalMapper::grow`]) and refines it (local BA, visual or inertial,
//! and keyframe culling; [`LocalMapper::refine`]); the keyframe index catches up with the
//! map (new and culled keyframes); loop closing looks for a loop at the keyframe and
//! corrects it. After a merge, a job first welds the seam and bundle-adjusts the whole map.

use std::collections::HashMap;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::{Duration, Instant};

use ferroslam_map::{KeyFrameId, Map, MapPointId};
#[cfg(feature = "bench")]
use ferroslam_optim::BaProblem;
use ferroslam_vocabulary::{BowVector, FeatureVector, Vocabulary};

use crate::context::Context;
use crate::error::SlamError;
use crate::local_ba_problem::adjust_keyframes;
use crate::local_inertial_ba::InertialWindow;
use crate::local_mapping::{Interrupt, LocalMapper, MappingReport};
use crate::loop_closing::{LoopCloser, LoopClosure, LoopStats};
use crate::place_recognition::PlaceRecognition;

/// A keyframe for the pipeline, with the points tracking created since the last one.
#[derive(Clone, Debug)]
pub(crate) struct KeyFrameWork {
    pub kf: KeyFrameId,
    pub new_points: Vec<MapPointId>,
    /// The window of local inertial BA (aligned visual-inertial maps).
    pub inertial: Option<InertialWindow>,
}

/// What tracking hands the pipeline.
pub(crate) enum MappingRequest {
    /// A keyframe tracking inserted.
    KeyFrame(KeyFrameWork),
    /// After a merge, ahead of the keyframes that follow: local BA of the seam's keyframes
    /// (the weld, see `crate::loop_closing`'s merging), then global BA.
    AdjustMerged { seam: Vec<KeyFrameId> },
}

/// Keyframes to process, in insertion order, and what the pipeline must know with them.
pub(crate) struct MappingJob {
    /// The seam of a merge to weld and bundle-adjust before the work
    /// ([`MappingRequest::AdjustMerged`]).
    pub merged_seam: Option<Vec<KeyFrameId>>,
    pub work: Vec<KeyFrameWork>,
    /// Start from a fresh pipeline state (the map was reset or replaced).
    pub fresh: bool,
    /// Renaming of points the previous job created in a map copy (see `MapJournal`), for
    /// the list of recent points.
    pub renamed: HashMap<MapPointId, MapPointId>,
    pub vocabulary: Option<Arc<Vocabulary>>,
    /// Frames come faster than the last keyframe was mapped (see [`Interrupt`]).
    pub hurried: bool,
}

/// What a job did.
#[derive(Default)]
pub(crate) struct Mapped {
    /// Local mapping report per processed keyframe.
    pub reports: Vec<(KeyFrameId, MappingReport)>,
    /// Loops closed.
    pub loops: Vec<LoopClosure>,
    /// Wall time of loop detection, verification and correction, milliseconds.
    pub loop_closing_ms: f64,
    /// Loop-detection counters after the job.
    pub stats: LoopStats,
    /// The first error met (the job stopped there).
    pub error: Option<SlamError>,
    /// The inertial windows with the states local inertial BA found.
    pub inertial: Vec<InertialWindow>,
    /// Keyframes the job indexed for place recognition (those still live at its end), with
    /// their bags of words and feature vectors, for tracking's own index (relocalisation).
    pub indexed: Vec<(KeyFrameId, (BowVector, FeatureVector))>,
}

/// How the one running a job follows it.
pub(crate) struct Progress<'a> {
    /// Set when tracking is about to wait for the job (see [`Interrupt`]).
    pub waiting: Option<&'a AtomicBool>,
    /// Called whenever a keyframe's new points are in the map, ahead of its local BA.
    pub send_ahead: &'a mut dyn FnMut(&mut Map),
    /// Called with the wall time of each keyframe mapped in full (neither hurried nor
    /// interrupted).
    pub mapped_in_full: &'a dyn Fn(Duration),
}

impl Progress<'_> {
    /// Mapping inline: never interrupted, nothing to send ahead, no pacing.
    pub(crate) fn inline(job: impl FnOnce(Progress<'_>) -> Mapped) -> Mapped {
        job(Progress {
            waiting: None,
            send_ahead: &mut |_| {},
            mapped_in_full: &|_| {},
        })
    }
}

/// Local mapping, the keyframe index and loop closing, with the state they keep from one
/// keyframe to the next.
#[derive(Default)]
pub(crate) struct MappingPipeline {
    mapper: LocalMapper,
    closer: LoopCloser,
    place: Option<PlaceRecognition>,
}

impl MappingPipeline {
    /// Forgets the map (it was reset or replaced).
    pub(crate) fn reset(&mut self) {
        self.mapper.reset();
        self.closer.reset_map();
        self.place = None;
    }

    /// Follows the renaming of points created in a map copy and replayed on the original.
    pub(crate) fn rename_points(&mut self, renamed: &HashMap<MapPointId, MapPointId>) {
        self.mapper.rename_recent_points(renamed);
    }

    /// Processes the job's keyframes in order on `map` (see the module doc).
    pub(crate) fn process(
        &mut self,
        job: MappingJob,
        map: &mut Map,
        ctx: &Context,
        progress: Progress<'_>,
    ) -> Mapped {
        if job.fresh {
            self.reset();
        }
        let Self {
            mapper,
            closer,
            place,
        } = self;
        match (&job.vocabulary, &*place) {
            (Some(v), Some(p)) if Arc::ptr_eq(v, p.vocabulary()) => {}
            (Some(v), _) => {
                let config = ctx.config.place_recognition;
                *place = Some(PlaceRecognition::new(Arc::clone(v), config));
            }
            (None, _) => *place = None,
        }
        mapper.rename_recent_points(&job.renamed);
        let Progress {
            waiting,
            send_ahead,
            mapped_in_full,
        } = progress;
        let interrupt = waiting.map_or(Interrupt::NEVER, |w| Interrupt::on(w, job.hurried));
        let mut mapped = Mapped::default();
        let mut indexed = Vec::new();
        let adjusted = match &job.merged_seam {
            Some(seam) => adjust_keyframes(seam, map, ctx, None)
                .and_then(|_| adjust_keyframes(&map.keyframe_ids(), map, ctx, None))
                .map(|_| ()),
            None => Ok(()),
        };
        if let Err(e) = adjusted {
            mapped.error = Some(e);
            mapped.stats = closer.stats();
            return mapped;
        }
        for mut work in job.work {
            for m in work.new_points {
                mapper.add_recent_point(m);
            }
            if map.keyframe(work.kf).is_none() {
                continue;
            }
            let mut report = MappingReport::default();
            let start = Instant::now();
            let step = mapper
                .grow(work.kf, map, ctx, &mut report, interrupt, &mut *send_ahead)
                .and_then(|()| {
                    send_ahead(map);
                    if report.interrupted {
                        return Ok(());
                    }
                    mapper.refine(work.kf, map, ctx, &mut report, work.inertial.as_mut())
                })
                .inspect(|()| {
                    if !job.hurried && !report.interrupted {
                        mapped_in_full(start.elapsed());
                    }
                })
                .and_then(|()| {
                    let Some(place) = place.as_mut() else {
                        return Ok(None);
                    };
                    // Indexed after culling, before loop detection queries it.
                    indexed.extend(place.sync(map));
                    if !ctx.config.loop_closing.loop_closure || map.keyframe(work.kf).is_none() {
                        return Ok(None);
                    }
                    let loops = Instant::now();
                    let closed = closer.process_keyframe(work.kf, map, ctx, place);
                    mapped.loop_closing_ms += loops.elapsed().as_secs_f64() * 1e3;
                    closed
                });
            mapped.reports.push((work.kf, report));
            mapped.inertial.extend(work.inertial);
            match step {
                Ok(Some(loop_closure)) => mapped.loops.push(loop_closure),
                Ok(None) => {}
                Err(e) => {
                    mapped.error = Some(e);
                    break;
                }
            }
        }
        if let Some(place) = place.as_ref() {
            mapped.indexed = indexed
                .into_iter()
                .filter_map(|kf| Some((kf, place.entry(kf)?.clone())))
                .collect();
        }
        mapped.stats = closer.stats();
        mapped
    }

    /// Starts (`true`) or stops recording each local BA problem before it is solved.
    #[cfg(feature = "bench")]
    pub(crate) fn record_local_ba_problems(&mut self, on: bool) {
        self.mapper.record_problems(on);
    }

    /// The local BA problems recorded since the last call.
    #[cfg(feature = "bench")]
    pub(crate) fn take_local_ba_problems(&mut self) -> Vec<BaProblem> {
        self.mapper.take_recorded_problems()
    }

    /// Whether local BA problems are being recorded.
    pub(crate) fn is_recording(&self) -> bool {
        self.mapper.is_recording()
    }
}
