//! Background mode: the SLAM system runs in a thread of its own, fed through a bounded queue,
//! with local mapping and loop closing in a third thread.
//!
//! The caller (e.g. Python, extracting ORB features) submits frames and returns at once
//! unless the queue is full; the tracking thread tracks them in submission order and hands
//! keyframes to the mapping thread ([`SlamSystem::set_concurrent_mapping`]), so tracking
//! never waits for local bundle adjustment. Everything else (trajectory, map, saving) is a
//! message executed by the tracking thread after the frames queued before it: it owns the
//! map, nobody locks it. [`BackgroundSlam::wait`] also waits for the mapping thread.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc::{channel, sync_channel, Receiver, Sender, SyncSender};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use ferroslam_features::{Descriptor, GrayImage, Keypoint, StereoView};
use ferroslam_map::Rgb;

use crate::error::SlamError;
use crate::frame::{MonoInput, RgbdInput, StereoInput};
use crate::front_end::OwnedRigFrame;
use crate::input_guard::InputGuard;
use crate::system::{SlamSystem, TrackResult};

/// Frames that may wait in the queue before `submit` blocks (bounded memory).
pub const QUEUE_CAPACITY: usize = 8;

/// An image pyramid level owned by a queued frame: `(width, height, pixels)`.
pub type OwnedLevel = (usize, usize, Vec<u8>);

/// A frame's features, owned so they can cross to the worker thread.
#[derive(Clone, Debug)]
pub enum OwnedFrame {
    /// A monocular frame.
    Mono {
        /// Seconds.
        timestamp: f64,
        /// Raw keypoints.
        keypoints: Vec<Keypoint>,
        /// Their descriptors.
        descriptors: Vec<Descriptor>,
        /// Their colours, if known.
        colors: Option<Vec<Rgb>>,
    },
    /// An RGB-D frame.
    Rgbd {
        /// Seconds.
        timestamp: f64,
        /// Raw keypoints.
        keypoints: Vec<Keypoint>,
        /// Their descriptors.
        descriptors: Vec<Descriptor>,
        /// Depth at each keypoint, metres.
        depth_m: Vec<f32>,
        /// Their colours, if known.
        colors: Option<Vec<Rgb>>,
    },
    /// A rectified stereo pair: `(keypoints, descriptors, pyramid)` per side.
    Stereo {
        /// Seconds.
        timestamp: f64,
        /// Left image features and pyramid.
        left: (Vec<Keypoint>, Vec<Descriptor>, Vec<OwnedLevel>),
        /// Right image features and pyramid.
        right: (Vec<Keypoint>, Vec<Descriptor>, Vec<OwnedLevel>),
        /// Colours of the left keypoints, if known.
        colors: Option<Vec<Rgb>>,
    },
    /// Images, measured by the tracking thread's front end ([`SlamSystem::track`]).
    Images(OwnedRigFrame),
}

impl OwnedFrame {
    /// Checks the frame against `guard` (accepting its timestamp when it passes).
    pub fn check(&self, guard: &mut InputGuard) -> Result<(), SlamError> {
        if let OwnedFrame::Images(frame) = self {
            return guard.accept_frame(frame);
        }
        self.with_input(|input| match input {
            Input::Mono(i) => guard.accept_mono(i),
            Input::Rgbd(i) => guard.accept_rgbd(i),
            Input::Stereo(i) => guard.accept_stereo(i),
        })
    }

    /// Tracks the frame with `system` (the matching `track_*` call).
    pub fn track(&self, system: &mut SlamSystem) -> Result<TrackResult, SlamError> {
        if let OwnedFrame::Images(frame) = self {
            return system.track(frame);
        }
        self.with_input(|input| match input {
            Input::Mono(i) => system.track_mono(i),
            Input::Rgbd(i) => system.track_rgbd(i),
            Input::Stereo(i) => system.track_stereo(i),
        })
    }

    /// Calls `f` with the borrowed input the `track_*` calls take.
    fn with_input<R>(
        &self,
        f: impl FnOnce(Input<'_>) -> Result<R, SlamError>,
    ) -> Result<R, SlamError> {
        match self {
            OwnedFrame::Mono {
                timestamp,
                keypoints,
                descriptors,
                colors,
            } => f(Input::Mono(&MonoInput {
                timestamp: *timestamp,
                keypoints,
                descriptors,
                colors: colors.as_deref(),
            })),
            OwnedFrame::Rgbd {
                timestamp,
                keypoints,
                descriptors,
                depth_m,
                colors,
            } => f(Input::Rgbd(&RgbdInput {
                timestamp: *timestamp,
                keypoints,
                descriptors,
                depth_m,
                colors: colors.as_deref(),
            })),
            OwnedFrame::Stereo {
                timestamp,
                left,
                right,
                colors,
            } => {
                let (lv, rv) = (views(&left.2)?, views(&right.2)?);
                f(Input::Stereo(&StereoInput {
                    timestamp: *timestamp,
                    left: StereoView {
                        keypoints: &left.0,
                        descriptors: &left.1,
                        levels: &lv,
                    },
                    right: StereoView {
                        keypoints: &right.0,
                        descriptors: &right.1,
                        levels: &rv,
                    },
                    colors: colors.as_deref(),
                }))
            }
            // `check` and `track` take images to the front end before asking for features.
            OwnedFrame::Images(_) => Err(SlamError::InvalidInput(
                "a frame of images has no features before the front end measures it".into(),
            )),
        }
    }
}

/// A borrowed frame input.
enum Input<'a> {
    Mono(&'a MonoInput<'a>),
    Rgbd(&'a RgbdInput<'a>),
    Stereo(&'a StereoInput<'a>),
}

fn views(levels: &[OwnedLevel]) -> Result<Vec<GrayImage<'_>>, SlamError> {
    levels
        .iter()
        .map(|(w, h, data)| GrayImage::new(*w, *h, data))
        .collect::<Result<_, _>>()
        .map_err(|e| SlamError::InvalidInput(e.to_string()))
}

type Job = Box<dyn FnOnce(&mut SlamSystem) + Send>;

enum Message {
    Frame(Box<OwnedFrame>),
    Run(Job),
}

/// A [`SlamSystem`] running in a background thread.
pub struct BackgroundSlam {
    sender: Option<SyncSender<Message>>,
    /// Behind a mutex only so the handle can be shared (`Sync`); one reader at a time.
    results: Mutex<Receiver<Result<TrackResult, SlamError>>>,
    pending: Arc<AtomicUsize>,
    /// Keyframes the mapping thread has queued or is processing.
    mapping_backlog: Option<Arc<AtomicUsize>>,
    /// Gives the system back when it ends ([`BackgroundSlam::stop`]).
    worker: Option<JoinHandle<SlamSystem>>,
}

impl BackgroundSlam {
    /// Moves `system` into a new tracking thread; local mapping and loop closing run in
    /// another (unless `concurrent_mapping` is false: then inline, in the tracking thread).
    pub fn spawn(mut system: SlamSystem, concurrent_mapping: bool) -> Self {
        // Switching on cannot fail: there is no queued work to finish.
        let _ = system.set_concurrent_mapping(concurrent_mapping);
        let mapping_backlog = system.mapping_backlog();
        let (sender, inbox) = sync_channel::<Message>(QUEUE_CAPACITY);
        let (report, results) = channel();
        let pending = Arc::new(AtomicUsize::new(0));
        let done = Arc::clone(&pending);
        let worker = std::thread::Builder::new()
            .name("ferroslam-slam".into())
            .spawn(move || {
                worker_loop(&mut system, inbox, report, done);
                system
            })
            .expect("the OS refused to start the SLAM thread");
        Self {
            sender: Some(sender),
            results: Mutex::new(results),
            pending,
            mapping_backlog,
            worker: Some(worker),
        }
    }

    /// Queues a frame; blocks while `QUEUE_CAPACITY` frames are waiting.
    pub fn submit(&self, frame: OwnedFrame) -> Result<(), SlamError> {
        self.pending.fetch_add(1, Ordering::SeqCst);
        let sent = self
            .sender
            .as_ref()
            .is_some_and(|s| s.send(Message::Frame(Box::new(frame))).is_ok());
        if !sent {
            self.pending.fetch_sub(1, Ordering::SeqCst);
            return Err(stopped());
        }
        Ok(())
    }

    /// Runs `job` on the system after every frame queued so far, returning its result.
    pub fn run<R: Send + 'static>(
        &self,
        job: impl FnOnce(&mut SlamSystem) -> R + Send + 'static,
    ) -> Result<R, SlamError> {
        let (reply, answer) = channel();
        let message = Message::Run(Box::new(move |system: &mut SlamSystem| {
            // The caller may have given up waiting: nothing to do then.
            let _ = reply.send(job(system));
        }));
        let sender = self.sender.as_ref().ok_or_else(stopped)?;
        sender.send(message).map_err(|_| stopped())?;
        answer.recv().map_err(|_| stopped())
    }

    /// Results of the frames processed since the last call, in submission order.
    pub fn take_results(&self) -> Vec<Result<TrackResult, SlamError>> {
        match self.results.lock() {
            Ok(results) => results.try_iter().collect(),
            Err(poisoned) => poisoned.into_inner().try_iter().collect(),
        }
    }

    /// Frames submitted but not processed yet.
    pub fn pending(&self) -> usize {
        self.pending.load(Ordering::SeqCst)
    }

    /// Whether every submitted frame is tracked and every keyframe mapped (the mapping
    /// thread's last edits reach the map with the next frame or query).
    pub fn is_idle(&self) -> bool {
        self.pending() == 0
            && self
                .mapping_backlog
                .as_ref()
                .is_none_or(|b| b.load(Ordering::SeqCst) == 0)
    }

    /// Blocks until every submitted frame is processed and mapped, and the map has every
    /// edit of the mapping thread.
    ///
    /// # Errors
    /// An error local mapping met, or a stopped thread.
    pub fn wait(&self) -> Result<(), SlamError> {
        self.run(SlamSystem::finish_mapping)?
    }

    /// Finishes the queued frames and keyframes, stops and joins the mapping thread and the
    /// tracking thread, and gives the system back (mapping inline): no thread is left.
    /// Afterwards every call of this handle reports a stopped thread.
    ///
    /// # Errors
    /// An error mapping the queued keyframes met, or a thread that had already failed
    /// (its threads are joined all the same).
    pub fn stop(&mut self) -> Result<SlamSystem, SlamError> {
        let mapping_stopped = self.run(|system| system.set_concurrent_mapping(false));
        self.sender = None;
        let system = self.worker.take().and_then(|worker| worker.join().ok());
        mapping_stopped??;
        system.ok_or_else(stopped)
    }
}

impl Drop for BackgroundSlam {
    /// Closing the queue lets the worker finish the frames already queued and stop.
    fn drop(&mut self) {
        self.sender = None;
        if let Some(worker) = self.worker.take() {
            let _ = worker.join();
        }
    }
}

fn worker_loop(
    system: &mut SlamSystem,
    inbox: Receiver<Message>,
    report: Sender<Result<TrackResult, SlamError>>,
    pending: Arc<AtomicUsize>,
) {
    for message in inbox {
        match message {
            Message::Frame(frame) => {
                let result = catch_unwind(AssertUnwindSafe(|| frame.track(system)))
                    .unwrap_or_else(|panic| Err(SlamError::from_panic("tracking", &*panic)));
                let failed = matches!(result, Err(SlamError::StageFailed { .. }));
                // Report before counting the frame done: `pending() == 0` then implies that
                // every result can be taken.
                let reported = report.send(result).is_ok();
                pending.fetch_sub(1, Ordering::SeqCst);
                // After a panic the system may be inconsistent: the thread stops, and the
                // next call says why (the caller already has this frame's error).
                if !reported || failed {
                    return;
                }
            }
            Message::Run(job) => {
                if catch_unwind(AssertUnwindSafe(|| job(system))).is_err() {
                    // The caller's reply channel is dropped: its call reports the failure.
                    return;
                }
            }
        }
    }
    // The queue is closed: let the mapping thread finish so nothing submitted is lost.
    let _ = system.finish_mapping();
}

fn stopped() -> SlamError {
    SlamError::StageFailed {
        stage: "tracking",
        message: "the SLAM background thread has stopped after an earlier error; create a \
                  new system"
            .into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{Sensor, SlamConfig};
    use crate::tracking::TrackingState;
    use ferroslam_geometry::camera::test_cameras;

    fn system() -> SlamSystem {
        let (_, camera) = test_cameras().into_iter().next().unwrap();
        let config = SlamConfig::for_sensor(Sensor::Monocular);
        SlamSystem::new(camera, config).unwrap()
    }

    fn empty(t: f64) -> OwnedFrame {
        OwnedFrame::Mono {
            timestamp: t,
            keypoints: Vec::new(),
            descriptors: Vec::new(),
            colors: None,
        }
    }

    #[test]
    fn a_panic_in_the_thread_surfaces_as_a_stage_failure_at_the_next_call() {
        let slam = BackgroundSlam::spawn(system(), true);
        let panicked = slam.run(|_| -> () { panic!("boom") });
        assert!(matches!(
            panicked,
            Err(SlamError::StageFailed {
                stage: "tracking",
                ..
            })
        ));
        // The thread is gone: later calls say so, queued work is not waited for forever.
        assert!(matches!(
            slam.run(|s| s.state()),
            Err(SlamError::StageFailed { .. })
        ));
        assert!(matches!(
            slam.submit(empty(1.0)),
            Err(SlamError::StageFailed { .. })
        ));
        assert_eq!(slam.pending(), 0);
        let message = SlamError::from_panic("local mapping", &"index out of bounds").to_string();
        assert_eq!(
            message,
            "internal error in local mapping (please report): index out of bounds"
        );
    }

    #[test]
    fn stop_joins_both_threads_and_gives_the_system_back() {
        let mut slam = BackgroundSlam::spawn(system(), true);
        for i in 0..5 {
            slam.submit(empty(i as f64)).unwrap();
        }
        let system = slam.stop().unwrap();
        assert!(!system.concurrent_mapping());
        assert_eq!(slam.take_results().len(), 5);
        assert!(slam.worker.is_none());
        assert!(matches!(slam.submit(empty(9.0)), Err(e) if e.to_string().contains("stopped")));
        assert!(slam.stop().is_err());
    }

    #[test]
    fn frames_and_queries_run_in_submission_order() {
        let slam = BackgroundSlam::spawn(system(), true);
        for i in 0..20 {
            slam.submit(empty(i as f64)).unwrap();
        }
        // A query waits for the frames queued before it.
        let state = slam.run(|s| s.state()).unwrap();
        assert_eq!(state, TrackingState::NotInitialized);
        assert_eq!(slam.pending(), 0);
        let results = slam.take_results();
        assert_eq!(results.len(), 20);
        assert!(results.iter().all(|r| r.is_ok()));
        // Errors come back as results, in order, and do not stop the worker.
        slam.submit(empty(5.0)).unwrap();
        slam.wait().unwrap();
        let late = slam.take_results();
        assert!(matches!(&late[..], [Err(SlamError::InvalidInput(m))] if m.contains("not after")));
    }

    #[test]
    fn dropping_with_queued_frames_finishes_them_and_stops() {
        let slam = BackgroundSlam::spawn(system(), true);
        for i in 0..(3 * QUEUE_CAPACITY) {
            slam.submit(empty(i as f64)).unwrap();
        }
        drop(slam); // joins the worker: must neither hang nor panic
    }
}
