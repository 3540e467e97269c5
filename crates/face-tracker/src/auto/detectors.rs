//! The initialisation threads: the detector runs on frames handed to it, in threads of its
//! own, and sends back what it found; the tracker takes the results when ready (live) or when
//! due (a file, at a fixed delay).

use std::collections::VecDeque;
use std::sync::mpsc::{Receiver, Sender, TryRecvError, channel};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;

use crate::detect::{DetectConfig, Detection, FaceDetector};
use crate::error::FaceError;
use crate::image::GrayImage;

/// A frame handed to the detector, and what it found there.
pub(super) struct DetectionResult {
    pub(super) frame_index: usize,
    pub(super) frame: Arc<GrayImage>,
    pub(super) faces: Result<Vec<Detection>, FaceError>,
}

/// The initialisation threads: take frames, send back detections.
pub(super) struct Detectors {
    jobs: Option<Sender<(usize, Arc<GrayImage>)>>,
    results: Receiver<DetectionResult>,
    /// The frames handed over whose detections have not been used, oldest first.
    in_flight: VecDeque<usize>,
    /// Detections that came back before they were due.
    early: Vec<DetectionResult>,
    handles: Vec<JoinHandle<()>>,
}

impl Detectors {
    pub(super) fn spawn(
        detector: Arc<FaceDetector>,
        config: DetectConfig,
        threads: usize,
    ) -> Result<Self, FaceError> {
        let (jobs, job_queue) = channel::<(usize, Arc<GrayImage>)>();
        let job_queue = Arc::new(Mutex::new(job_queue));
        let (result_sender, results) = channel();
        let mut handles = Vec::with_capacity(threads);
        for k in 0..threads.max(1) {
            let (job_queue, detector, config, result_sender) = (
                Arc::clone(&job_queue),
                Arc::clone(&detector),
                config.clone(),
                result_sender.clone(),
            );
            let handle = std::thread::Builder::new()
                .name(format!("face-detector-{k}"))
                .spawn(move || {
                    loop {
                        // One thread at a time waits on the queue; the lock is let go before
                        // the detection runs.
                        let job = job_queue
                            .lock()
                            .unwrap_or_else(PoisonError::into_inner)
                            .recv();
                        let Ok((frame_index, frame)) = job else {
                            break;
                        };
                        let faces = detector.detect(&frame, &config);
                        let result = DetectionResult {
                            frame_index,
                            frame,
                            faces,
                        };
                        if result_sender.send(result).is_err() {
                            break;
                        }
                    }
                })
                .map_err(|e| FaceError::InvalidInput(format!("cannot start the detector: {e}")))?;
            handles.push(handle);
        }
        Ok(Self {
            jobs: Some(jobs),
            results,
            in_flight: VecDeque::new(),
            early: Vec::new(),
            handles,
        })
    }

    pub(super) fn idle(&self) -> bool {
        self.in_flight.is_empty()
    }

    pub(super) fn send(
        &mut self,
        frame_index: usize,
        frame: Arc<GrayImage>,
    ) -> Result<(), FaceError> {
        self.jobs
            .as_ref()
            .and_then(|jobs| jobs.send((frame_index, frame)).ok())
            .ok_or_else(|| FaceError::InvalidInput("the detector thread has stopped".into()))?;
        self.in_flight.push_back(frame_index);
        Ok(())
    }

    fn stopped() -> FaceError {
        FaceError::InvalidInput("the detector thread stopped".into())
    }

    /// A finished detection if one is ready (live: one frame in flight at most).
    pub(super) fn take_ready(&mut self) -> Result<Option<DetectionResult>, FaceError> {
        if self.idle() {
            return Ok(None);
        }
        let result = match self.results.try_recv() {
            Ok(r) => r,
            Err(TryRecvError::Empty) => return Ok(None),
            Err(TryRecvError::Disconnected) => return Err(Self::stopped()),
        };
        self.in_flight.retain(|&f| f != result.frame_index);
        Ok(Some(result))
    }

    /// The detection of `frame_index` if that frame was handed over, waiting for it.
    pub(super) fn take_frame(
        &mut self,
        frame_index: usize,
    ) -> Result<Option<DetectionResult>, FaceError> {
        if !self.in_flight.contains(&frame_index) {
            return Ok(None);
        }
        self.in_flight.retain(|&f| f != frame_index);
        if let Some(i) = self.early.iter().position(|r| r.frame_index == frame_index) {
            return Ok(Some(self.early.swap_remove(i)));
        }
        loop {
            let result = self.results.recv().map_err(|_| Self::stopped())?;
            if result.frame_index == frame_index {
                return Ok(Some(result));
            }
            self.early.push(result);
        }
    }
}

impl Drop for Detectors {
    fn drop(&mut self) {
        // Closing the job channel ends the threads' loops.
        self.jobs = None;
        for handle in self.handles.drain(..) {
            let _ = handle.join();
        }
    }
}
