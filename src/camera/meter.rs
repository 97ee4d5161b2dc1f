//! [`StreamMeter`]: what a camera stream delivered, counted from the driver's buffer sequence
//! numbers and timestamps.
//!
//! The V4L2 capture thread feeds it `(sequence, timestamp_s)` for every buffer it dequeues
//! after warm-up (`struct v4l2_buffer`: `sequence` is a `__u32` the driver increments once per
//! frame, whether or not the frame reached a buffer; `timestamp` is the driver's stamp,
//! `CLOCK_MONOTONIC` on every driver rig uses). From consecutive buffers it counts:
//!
//! - received: every buffer fed;
//! - dropped: the sequence numbers skipped between two buffers (frames the driver captured
//!   but had no free buffer for, or lost on the bus);
//! - timed frames and timed seconds: for each buffer that advances the sequence and whose
//!   stamp is later than the previous buffer's, one frame and the time between the two stamps.
//!   Their ratio is the rate at which frames were delivered, in driver time.
//!
//! Sequence numbers wrap at 2^32: the step from one buffer to the next is taken modulo 2^32,
//! so a wrap is an ordinary step. A step of more than 2^31 (the sequence went backwards) or a
//! stamp earlier than the previous one means the stream restarted: the buffer counts as
//! received and starts a new run of sequence numbers, with nothing dropped or timed across
//! the restart. A buffer repeating the previous sequence number (the second field of an
//! interlaced frame) counts as received, neither dropped nor timed. The first buffer is
//! received and only starts the count. Nothing here panics or overflows, whatever it is fed.

use super::{StreamOrigin, StreamStats};

/// Sequence steps above this (modulo 2^32) are the sequence going backwards: a restart.
const MAX_FORWARD_STEP: u32 = 1 << 31;

/// Counts frames, dropped frames and delivery time of one stream. See the module docs.
#[derive(Debug, Clone, Default)]
pub struct StreamMeter {
    frames_received: u64,
    frames_dropped: u64,
    timed_frames: u64,
    timed_s: f64,
    /// Sequence number and stamp of the buffer the next one is compared with.
    last: Option<(u32, f64)>,
}

impl StreamMeter {
    /// A meter that has seen nothing.
    pub fn new() -> Self {
        Self::default()
    }

    /// Counts one dequeued buffer: the driver's `sequence` and its timestamp, s.
    pub fn record(&mut self, sequence: u32, timestamp_s: f64) {
        self.frames_received = self.frames_received.saturating_add(1);
        let Some((last_sequence, last_s)) = self.last else {
            self.last = Some((sequence, timestamp_s));
            return;
        };
        let step = sequence.wrapping_sub(last_sequence);
        if step == 0 {
            // Same frame again: keep comparing with its first buffer.
            return;
        }
        let restarted = step > MAX_FORWARD_STEP || timestamp_s < last_s;
        if !restarted {
            self.frames_dropped = self.frames_dropped.saturating_add(u64::from(step - 1));
            let interval_s = timestamp_s - last_s;
            if interval_s.is_finite() && interval_s > 0.0 {
                self.timed_frames = self.timed_frames.saturating_add(1);
                self.timed_s += interval_s;
            }
        }
        self.last = Some((sequence, timestamp_s));
    }

    /// The counts so far.
    pub fn stats(&self) -> StreamStats {
        StreamStats {
            frames_received: self.frames_received,
            frames_dropped: self.frames_dropped,
            timed_frames: self.timed_frames,
            timed_s: self.timed_s,
            stale_discarded: 0,
            origin: StreamOrigin::Measured,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A meter fed `frames` as (sequence, stamp).
    fn fed(frames: &[(u32, f64)]) -> StreamStats {
        let mut meter = StreamMeter::new();
        for &(sequence, t_s) in frames {
            meter.record(sequence, t_s);
        }
        meter.stats()
    }

    /// `n` frames at `fps` from sequence `first` and time `t0_s`, skipping the sequence numbers
    /// in `lost`.
    fn stream(first: u32, n: u32, fps: f64, t0_s: f64, lost: &[u32]) -> Vec<(u32, f64)> {
        (0..n)
            .map(|k| first.wrapping_add(k))
            .filter(|s| !lost.contains(s))
            .map(|s| (s, t0_s + f64::from(s.wrapping_sub(first)) / fps))
            .collect()
    }

    fn assert_close(a: f64, b: f64) {
        assert!((a - b).abs() < 1e-9, "{a} != {b}");
    }

    #[test]
    fn a_clean_stream_counts_every_frame_and_its_rate() {
        let s = fed(&stream(100, 31, 30.0, 5000.0, &[]));
        assert_eq!((s.frames_received, s.frames_dropped, s.timed_frames), (31, 0, 30));
        assert_close(s.timed_s, 1.0);
        assert_close(s.measured_fps().expect("measured"), 30.0);
        assert_eq!(s.origin, StreamOrigin::Measured);
    }

    #[test]
    fn gaps_in_the_sequence_are_dropped_frames() {
        // 25 fps, frames 3, 4 and 10 never reached a buffer.
        let s = fed(&stream(0, 26, 25.0, 0.0, &[3, 4, 10]));
        assert_eq!((s.frames_received, s.frames_dropped, s.timed_frames), (23, 3, 22));
        // Delivered: 22 frames over the second between the first and the last stamp.
        assert_close(s.timed_s, 1.0);
        assert_close(s.measured_fps().expect("measured"), 22.0);
    }

    #[test]
    fn the_first_frame_only_starts_the_count() {
        let s = fed(&[(7, 1.0)]);
        assert_eq!((s.frames_received, s.frames_dropped, s.timed_frames), (1, 0, 0));
        assert_eq!(s.measured_fps(), None, "one frame has no rate");
        let empty = StreamMeter::new().stats();
        assert_eq!((empty.frames_received, empty.frames_dropped), (0, 0));
        assert_eq!(empty.measured_fps(), None);
    }

    #[test]
    fn the_sequence_wraps_without_a_drop() {
        let s = fed(&stream(u32::MAX - 2, 6, 30.0, 10.0, &[]));
        assert_eq!((s.frames_received, s.frames_dropped, s.timed_frames), (6, 0, 5));
        // A frame lost right at the wrap is one drop, not four billion.
        let s = fed(&stream(u32::MAX - 1, 4, 30.0, 10.0, &[0]));
        assert_eq!((s.frames_received, s.frames_dropped), (3, 1));
    }

    #[test]
    fn a_restart_neither_drops_nor_times_across_it() {
        // The stream restarted: the sequence goes back to 0 and the stamps jump ahead.
        let mut frames = stream(500, 10, 30.0, 100.0, &[]);
        frames.extend(stream(0, 10, 30.0, 200.0, &[]));
        let s = fed(&frames);
        assert_eq!((s.frames_received, s.frames_dropped, s.timed_frames), (20, 0, 18));
        assert_close(s.timed_s, 18.0 / 30.0);
        // Stamps going backwards with the sequence going on (a driver reset its clock).
        let s = fed(&[(1, 50.0), (2, 50.1), (3, 10.0), (4, 10.1)]);
        assert_eq!((s.frames_received, s.frames_dropped, s.timed_frames), (4, 0, 2));
        assert_close(s.timed_s, 0.2);
    }

    #[test]
    fn a_repeated_sequence_is_received_but_not_dropped_or_timed() {
        // Alternate fields: two buffers per sequence number, 1/60 s apart, 30 frames a second.
        let frames: Vec<(u32, f64)> = (0..10u32).flat_map(|s| [(s, f64::from(s) / 30.0), (s, f64::from(s) / 30.0 + 1.0 / 60.0)]).collect();
        let s = fed(&frames);
        assert_eq!((s.frames_received, s.frames_dropped, s.timed_frames), (20, 0, 9));
        assert_close(s.measured_fps().expect("measured"), 30.0);
    }

    #[test]
    fn unusable_stamps_are_not_timed() {
        let s = fed(&[(0, 0.0), (1, f64::NAN), (2, 0.1), (3, 0.1), (4, f64::INFINITY), (5, 0.3)]);
        assert_eq!((s.frames_received, s.frames_dropped), (6, 0));
        // NaN, zero and infinite intervals are not timed; the step back from infinity is a
        // restart.
        assert_eq!(s.timed_frames, 0);
        assert_eq!(s.measured_fps(), None);
    }

    #[test]
    fn the_figures_of_a_window_are_the_difference_of_two_snapshots() {
        let frames = stream(0, 91, 30.0, 0.0, &[40, 41]);
        let mut meter = StreamMeter::new();
        for &(sequence, t_s) in &frames[..30] {
            meter.record(sequence, t_s);
        }
        let before = meter.stats();
        for &(sequence, t_s) in &frames[30..] {
            meter.record(sequence, t_s);
        }
        let window = meter.stats().since(&before);
        assert_eq!((window.frames_received, window.frames_dropped, window.timed_frames), (59, 2, 59));
        assert_close(window.timed_s, 61.0 / 30.0);
        // An earlier snapshot of a camera reopened since (counts lower now) gives no negatives.
        let reopened = StreamMeter::new().stats().since(&before);
        assert_eq!((reopened.frames_received, reopened.frames_dropped, reopened.timed_frames), (0, 0, 0));
        assert_eq!(reopened.timed_s, 0.0);
    }

    proptest! {
        /// Whatever it is fed: no panic, every buffer received, no more timed frames than
        /// buffers, no negative or non-finite time.
        #[test]
        fn any_feed_is_counted_without_panicking(
            frames in proptest::collection::vec((any::<u32>(), prop_oneof![any::<f64>(), 0.0f64..1e6]), 0..200)
        ) {
            let s = fed(&frames);
            prop_assert_eq!(s.frames_received, frames.len() as u64);
            prop_assert!(s.timed_frames <= s.frames_received);
            prop_assert!(s.timed_s >= 0.0);
            if let Some(fps) = s.measured_fps() {
                prop_assert!(fps.is_finite() && fps > 0.0);
            }
        }
    }
}
