//! The mapping thread: the [`MappingPipeline`] beside tracking (ORB-SLAM's `LocalMapping`
//! and `LoopClosing` threads), without a shared map lock.
//!
//! Tracking owns the map. When it inserts a keyframe, it hands the thread a snapshot (a copy
//! of the map, O(1)) with the keyframes to process; the thread runs the pipeline on the copy,
//! recording its edits in a [`MapJournal`], and sends the journal back. Tracking replays it
//! on its map when it next looks (before each frame, or when asked to finish), so tracking
//! never waits for local BA. Keyframes inserted while a job runs are queued and go with the
//! next snapshot, taken after the journal is replayed. The points a keyframe brings are sent
//! ahead, as each covisible keyframe yields them and again after fusion, so the next frame
//! can track them before local BA is done. When frames come faster than a keyframe takes to
//! map, triangulation searches only the best covisible keyframes (see
//! [`crate::local_mapping::Interrupt`]).
//!
//! Points created in a copy are renamed when replayed; the renaming travels with the next
//! job so the pipeline's list of recent points follows. A map reset bumps the epoch: results
//! of older jobs are dropped and the thread starts its next job afresh.

use std::collections::HashMap;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::mpsc::{channel, Receiver, Sender, TryRecvError};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use ferroslam_map::{KeyFrameId, Map, MapJournal, MapPointId};
use ferroslam_vocabulary::Vocabulary;

use super::pipeline::{
    KeyFrameWork, Mapped, MappingJob, MappingPipeline, MappingRequest, Progress,
};
use crate::context::Context;
use crate::error::SlamError;

/// A snapshot of the map and the job to run on it.
struct Job {
    epoch: u64,
    map: Map,
    job: MappingJob,
    /// Tests: the job panics, as a bug in local mapping would.
    #[cfg(test)]
    panics: bool,
}

/// What the mapping thread sends back.
enum FromMapping {
    /// The edits so far of the job in flight: a keyframe's new points, ahead of its local BA.
    Grown { epoch: u64, journal: MapJournal },
    /// The job is done: its edits and what it did.
    Done {
        epoch: u64,
        journal: MapJournal,
        mapped: Mapped,
    },
    /// The job panicked (a bug): the thread stops.
    Failed(SlamError),
}

/// Handle of the mapping thread, owned by tracking.
pub(crate) struct MappingThread {
    jobs: Option<Sender<Job>>,
    /// Behind a mutex only so the system stays `Sync`; only tracking reads it.
    done: Mutex<Receiver<FromMapping>>,
    /// Hands the pipeline back when the thread ends (`None` after a panic).
    thread: Option<JoinHandle<Option<MappingPipeline>>>,
    epoch: u64,
    fresh: bool,
    in_flight: bool,
    queue: Vec<KeyFrameWork>,
    /// A merge's seam to weld and bundle-adjust, queued ahead of the keyframes.
    merged_seam: Option<Vec<KeyFrameId>>,
    renamed: HashMap<MapPointId, MapPointId>,
    /// Renaming of the points the job in flight sent ahead.
    renamed_in_flight: HashMap<MapPointId, MapPointId>,
    /// Keyframes queued or being processed (shared with callers asking "is it done?").
    backlog: Arc<AtomicUsize>,
    /// Tracking waits for the job in flight (see [`Interrupt`]); cleared with each dispatch.
    interrupt: Arc<AtomicBool>,
    /// `SlamConfig::deterministic`: never hurried (wall time must not decide anything).
    deterministic: bool,
    /// When tracking started the last frame, and the wall time since the frame before.
    last_frame: Option<Instant>,
    frame_interval: Option<Duration>,
    /// Wall time of the last keyframe mapped unhurried, microseconds (0: none yet).
    keyframe_mapping_us: Arc<AtomicU64>,
    /// Why the mapping thread stopped, once it has: every later collect reports it.
    failure: Option<SlamError>,
}

impl MappingThread {
    /// Starts the mapping thread with `pipeline` (the state inline mapping had so far).
    pub(crate) fn spawn(ctx: Context, pipeline: MappingPipeline) -> Self {
        let (jobs, inbox) = channel::<Job>();
        let (report, done) = channel::<FromMapping>();
        let backlog = Arc::new(AtomicUsize::new(0));
        let interrupt = Arc::new(AtomicBool::new(false));
        let keyframe_mapping_us = Arc::new(AtomicU64::new(0));
        let (count, hurry, mapping_us) = (
            Arc::clone(&backlog),
            Arc::clone(&interrupt),
            Arc::clone(&keyframe_mapping_us),
        );
        let deterministic = ctx.config.deterministic;
        let thread = std::thread::Builder::new()
            .name("ferroslam-mapping".into())
            .spawn(move || mapping_loop(pipeline, &ctx, inbox, report, count, &hurry, &mapping_us))
            .expect("the OS refused to start the mapping thread");
        Self {
            jobs: Some(jobs),
            done: Mutex::new(done),
            thread: Some(thread),
            epoch: 0,
            fresh: false,
            in_flight: false,
            queue: Vec::new(),
            merged_seam: None,
            renamed: HashMap::new(),
            renamed_in_flight: HashMap::new(),
            backlog,
            interrupt,
            deterministic,
            last_frame: None,
            frame_interval: None,
            keyframe_mapping_us,
            failure: None,
        }
    }

    /// Why the mapping thread stopped (a panic in local mapping or loop closing), if it did.
    pub(crate) fn failure(&self) -> Option<&SlamError> {
        self.failure.as_ref()
    }

    /// Tracking starts a frame (the pace of frames decides whether mapping is hurried).
    pub(crate) fn frame_started(&mut self) {
        if self.deterministic {
            return;
        }
        let now = Instant::now();
        self.frame_interval = self.last_frame.map(|last| now - last);
        self.last_frame = Some(now);
    }

    /// Whether frames come faster than local mapping processed the last keyframe it mapped
    /// unhurried (a hurried keyframe's time would say nothing of the full work).
    fn hurried(&self) -> bool {
        let mapping_us = self.keyframe_mapping_us.load(Ordering::Relaxed);
        self.frame_interval
            .is_some_and(|interval| interval < Duration::from_micros(mapping_us))
    }

    /// Asks the job in flight to skip its remaining optional work: tracking is about to wait
    /// for it.
    pub(crate) fn interrupt(&self) {
        self.interrupt.store(true, Ordering::Relaxed);
    }

    /// Keyframes waiting or being processed.
    pub(crate) fn backlog(&self) -> usize {
        self.backlog.load(Ordering::SeqCst)
    }

    /// The shared backlog counter.
    pub(crate) fn backlog_handle(&self) -> Arc<AtomicUsize> {
        Arc::clone(&self.backlog)
    }

    /// Queues a request on `map`; sends it at once if the thread is idle. The backlog
    /// counts keyframes only: a merge's BA keeps the thread busy, not keyframes waiting.
    pub(crate) fn push(
        &mut self,
        request: MappingRequest,
        map: &Map,
        vocabulary: Option<&Arc<Vocabulary>>,
    ) {
        match request {
            MappingRequest::KeyFrame(work) => {
                self.backlog.fetch_add(1, Ordering::SeqCst);
                self.queue.push(work);
            }
            MappingRequest::AdjustMerged { seam } => self.merged_seam = Some(seam),
        }
        if !self.in_flight {
            self.dispatch(map, vocabulary);
        }
    }

    /// Takes the finished jobs in (blocking until the thread is idle with nothing queued if
    /// `wait`), replays their journals on `map` and sends the queued keyframes.
    pub(crate) fn collect(
        &mut self,
        map: &mut Map,
        vocabulary: Option<&Arc<Vocabulary>>,
        wait: bool,
    ) -> Vec<Mapped> {
        let mut out = Vec::new();
        loop {
            let next = {
                let done = self.done.lock().unwrap_or_else(PoisonError::into_inner);
                if wait && self.in_flight {
                    done.recv().map_err(|_| TryRecvError::Disconnected)
                } else {
                    done.try_recv()
                }
            };
            let (journal, mapped) = match next {
                Err(TryRecvError::Empty) => break,
                Err(TryRecvError::Disconnected) => {
                    // Gone without a word (it reports its panics): nothing more will come.
                    self.stop(SlamError::StageFailed {
                        stage: "local mapping",
                        message: "the mapping thread has stopped".into(),
                    });
                    break;
                }
                Ok(FromMapping::Failed(error)) => {
                    self.stop(error);
                    break;
                }
                Ok(FromMapping::Grown { epoch, journal }) => {
                    if epoch == self.epoch {
                        map.apply_journal_part(&journal, &mut self.renamed_in_flight);
                    }
                    continue;
                }
                Ok(FromMapping::Done {
                    epoch,
                    journal,
                    mapped,
                }) if epoch == self.epoch => (journal, mapped),
                Ok(FromMapping::Done { .. }) => {
                    // A job of the map before a reset: its edits are dropped, but the thread
                    // is free only now (waiting for it keeps `wait` honest: afterwards the
                    // backlog is empty).
                    self.in_flight = false;
                    if self.has_work() {
                        self.dispatch(map, vocabulary);
                    }
                    continue;
                }
            };
            self.in_flight = false;
            map.apply_journal_part(&journal, &mut self.renamed_in_flight);
            self.renamed.extend(self.renamed_in_flight.drain());
            out.push(mapped);
            if self.has_work() {
                self.dispatch(map, vocabulary);
            }
        }
        out
    }

    /// Whether anything is queued.
    fn has_work(&self) -> bool {
        self.merged_seam.is_some() || !self.queue.is_empty()
    }

    /// Records that the mapping thread stopped: nothing is in flight or queued any more.
    fn stop(&mut self, error: SlamError) {
        self.failure.get_or_insert(error);
        self.in_flight = false;
        self.backlog.fetch_sub(self.queue.len(), Ordering::SeqCst);
        self.queue.clear();
        self.merged_seam = None;
    }

    /// Forgets the queue and the result of any job in flight (the map was reset or
    /// replaced); a job in flight still occupies the thread until it reports.
    pub(crate) fn reset(&mut self) {
        self.epoch += 1;
        self.fresh = true;
        self.backlog.fetch_sub(self.queue.len(), Ordering::SeqCst);
        self.queue.clear();
        self.merged_seam = None;
        self.renamed.clear();
        self.renamed_in_flight.clear();
    }

    /// Sends the queued keyframes with a copy of `map` (O(1): copies share their entries
    /// until either side writes one, see `ferroslam_map::Map`).
    fn dispatch(&mut self, map: &Map, vocabulary: Option<&Arc<Vocabulary>>) {
        let job = Job {
            epoch: self.epoch,
            map: map.clone(),
            job: MappingJob {
                merged_seam: self.merged_seam.take(),
                work: std::mem::take(&mut self.queue),
                fresh: std::mem::take(&mut self.fresh),
                renamed: std::mem::take(&mut self.renamed),
                vocabulary: vocabulary.cloned(),
                hurried: self.hurried(),
            },
            #[cfg(test)]
            panics: false,
        };
        let n = job.job.work.len();
        self.interrupt.store(false, Ordering::Relaxed);
        let sent = self.jobs.as_ref().is_some_and(|j| j.send(job).is_ok());
        if sent {
            self.in_flight = true;
        } else {
            // The thread is gone (it panicked): drop the work rather than hang later.
            self.backlog.fetch_sub(n, Ordering::SeqCst);
        }
    }

    /// Stops the thread once its queue is done and takes its pipeline back, with the points
    /// of its last job renamed as replayed; a fresh pipeline if the thread failed or the map
    /// was reset meanwhile.
    pub(crate) fn stop_thread(mut self) -> MappingPipeline {
        self.jobs = None;
        let pipeline = self.thread.take().and_then(|t| t.join().ok().flatten());
        match pipeline {
            Some(mut pipeline) if !self.fresh => {
                pipeline.rename_points(&self.renamed);
                pipeline
            }
            _ => MappingPipeline::default(),
        }
    }
}

impl Drop for MappingThread {
    fn drop(&mut self) {
        self.jobs = None;
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// The mapping thread: the pipeline's state persists across jobs; each job brings the map
/// to work on. Returns the pipeline when tracking stops sending jobs (`None` after a panic).
fn mapping_loop(
    mut pipeline: MappingPipeline,
    ctx: &Context,
    inbox: Receiver<Job>,
    report: Sender<FromMapping>,
    backlog: Arc<AtomicUsize>,
    interrupt: &AtomicBool,
    keyframe_mapping_us: &AtomicU64,
) -> Option<MappingPipeline> {
    // Jobs run on a thread pool of their own: a job runs hundreds of small parallel loops
    // (each local BA iteration several), each otherwise handed to a pool and waited for; and
    // in tracking's pool they would queue ahead of tracking's own (idle threads steal work
    // before taking new jobs).
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(rayon::current_num_threads())
        .thread_name(|i| format!("ferroslam-mapping-{i}"))
        .start_handler(|_| yield_to_tracking())
        .build()
        .ok();
    // Only now: `current_num_threads` above may start rayon's global pool, whose threads
    // (tracking's) would inherit this thread's priority.
    yield_to_tracking();
    for job in inbox {
        let n = job.job.work.len();
        let run = || {
            run_job(
                &mut pipeline,
                job,
                ctx,
                &report,
                interrupt,
                keyframe_mapping_us,
            )
        };
        let done = catch_unwind(AssertUnwindSafe(|| match &pool {
            Some(pool) => pool.install(run),
            None => run(),
        }));
        backlog.fetch_sub(n, Ordering::SeqCst);
        // After a panic the pipeline's state may be inconsistent: report it and stop.
        let (message, stop) = match done {
            Ok(done) => (done, false),
            Err(panic) => (
                FromMapping::Failed(SlamError::from_panic("local mapping", &*panic)),
                true,
            ),
        };
        if stop {
            let _ = report.send(message);
            return None;
        }
        if report.send(message).is_err() {
            break;
        }
    }
    Some(pipeline)
}

/// Runs one job on its copy of the map, recording the edits; sends each keyframe's new
/// points ahead as they are made. A stale job (the epoch moved on) is still processed;
/// tracking drops its result.
fn run_job(
    pipeline: &mut MappingPipeline,
    job: Job,
    ctx: &Context,
    report: &Sender<FromMapping>,
    interrupt: &AtomicBool,
    keyframe_mapping_us: &AtomicU64,
) -> FromMapping {
    #[cfg(test)]
    assert!(!job.panics, "a job that panics (test)");
    let Job {
        epoch,
        mut map,
        job,
        ..
    } = job;
    map.begin_journal();
    // Tracking applies what was sent before its next frame; if it is gone, so is the job.
    let mut send_ahead = |map: &mut Map| {
        let journal = map.drain_journal();
        if !journal.is_empty() {
            let _ = report.send(FromMapping::Grown { epoch, journal });
        }
    };
    let mapped_in_full = |took: Duration| {
        let us = took.as_micros().try_into().unwrap_or(u64::MAX);
        keyframe_mapping_us.store(us, Ordering::Relaxed);
    };
    let progress = Progress {
        waiting: Some(interrupt),
        send_ahead: &mut send_ahead,
        mapped_in_full: &mapped_in_full,
    };
    let mapped = pipeline.process(job, &mut map, ctx, progress);
    FromMapping::Done {
        epoch,
        journal: map.take_journal(),
        mapped,
    }
}

/// Gives the calling mapping thread the lowest CPU priority (nice 19 on Linux), so that
/// tracking, the part that must keep up with the camera, and its helper threads get a core
/// as soon as they want one; mapping takes the time they leave. At equal priority a tracking
/// helper waits for the mapping thread's time slice to end (fed at full speed, frame times
/// and their tail fell). Best effort: where the OS refuses, mapping keeps the priority it has.
fn yield_to_tracking() {
    let _ = thread_priority::set_current_thread_priority(thread_priority::ThreadPriority::Min);
}

#[cfg(test)]
mod tests {
    use ferroslam_geometry::camera::{PinholeCamera, RadTan};

    use super::*;
    use crate::config::SlamConfig;

    fn spawn() -> MappingThread {
        let camera =
            PinholeCamera::new(500.0, 500.0, 320.0, 240.0, RadTan::default(), 640, 480).unwrap();
        let ctx = Context::new(camera, SlamConfig::default());
        MappingThread::spawn(ctx, MappingPipeline::default())
    }

    #[test]
    fn a_panic_in_local_mapping_is_reported_and_nothing_waits_for_the_thread() {
        let mut mapper = spawn();
        let mut map = Map::new(ferroslam_features::ScalePyramid::default());
        let job = Job {
            epoch: mapper.epoch,
            map: map.clone(),
            job: MappingJob {
                merged_seam: None,
                work: Vec::new(),
                fresh: true,
                renamed: HashMap::new(),
                vocabulary: None,
                hurried: false,
            },
            panics: true,
        };
        mapper.jobs.as_ref().unwrap().send(job).unwrap();
        mapper.in_flight = true;
        assert!(mapper.collect(&mut map, None, true).is_empty());
        assert!(matches!(
            mapper.failure(),
            Some(SlamError::StageFailed { stage: "local mapping", message })
                if message.contains("a job that panics")
        ));
        assert!(!mapper.in_flight);
        assert_eq!(mapper.backlog(), 0);
        // Later collects report at once instead of waiting for the thread.
        assert!(mapper.collect(&mut map, None, true).is_empty());
    }

    #[test]
    fn hurried_while_frames_come_faster_than_the_last_unhurried_keyframe_was_mapped() {
        let mut mapper = spawn();
        mapper.frame_started();
        assert!(mapper.frame_interval.is_none() && !mapper.hurried());
        mapper.frame_started();
        assert!(mapper.frame_interval.is_some());
        mapper.frame_interval = Some(Duration::from_millis(10));
        assert!(!mapper.hurried(), "no keyframe mapped yet");
        mapper.keyframe_mapping_us.store(20_000, Ordering::Relaxed);
        assert!(mapper.hurried());
        mapper.frame_interval = Some(Duration::from_millis(30));
        assert!(!mapper.hurried());
    }

    /// Nice value of thread `tid` of this process, and its name (`/proc`, Linux).
    #[cfg(target_os = "linux")]
    fn nice_and_name(tid: &str) -> Option<(i32, String)> {
        let stat = std::fs::read_to_string(format!("/proc/self/task/{tid}/stat")).ok()?;
        // fields after the parenthesised name: state is field 3, nice field 19
        let nice = stat
            .rsplit_once(')')?
            .1
            .split_whitespace()
            .nth(16)?
            .parse()
            .ok()?;
        let name = std::fs::read_to_string(format!("/proc/self/task/{tid}/comm")).ok()?;
        Some((nice, name.trim().to_owned()))
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn mapping_threads_run_at_the_lowest_priority_and_trackings_pool_does_not() {
        let _mapper = spawn();
        // the mapping thread and its pool's threads, once started
        let wanted = 1 + rayon::current_num_threads();
        let lowest = || {
            std::fs::read_dir("/proc/self/task")
                .unwrap()
                .filter_map(|e| nice_and_name(e.ok()?.file_name().to_str()?))
                .filter(|(nice, name)| *nice == 19 && name.starts_with("ferroslam-mapp"))
                .count()
        };
        let start = Instant::now();
        // at least: other tests of this binary may run mappers of their own meanwhile, and
        // end them, so the count is read once per round (a second read raced their exit)
        let mut seen = lowest();
        while seen < wanted && start.elapsed() < Duration::from_secs(10) {
            std::thread::sleep(Duration::from_millis(5));
            seen = lowest();
        }
        assert!(seen >= wanted, "{seen} of {wanted}");
        // rayon's global pool (tracking's parallel loops) keeps the priority of the threads
        // that use it, even when the mapping thread was the first to use rayon
        let own_nice = || {
            let tid = std::fs::read_link("/proc/thread-self").unwrap();
            nice_and_name(tid.file_name().unwrap().to_str().unwrap())
                .unwrap()
                .0
        };
        let test_thread = own_nice();
        let global: Vec<i32> = rayon::broadcast(|_| own_nice());
        assert!(
            global.iter().all(|&n| n == test_thread),
            "{global:?} vs {test_thread}"
        );
    }
}
