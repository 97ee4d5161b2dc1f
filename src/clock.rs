//! Time as a value passed in.
//!
//! Logic that needs "now" takes a [`Clock`]. [`MonotonicClock`] runs at real time or a chosen
//! multiple of it (the simulated rig runs faster than real time in tests); [`MockClock`] only
//! moves when told to.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// A source of time in seconds since the clock's own epoch.
pub trait Clock: Send + Sync + 'static {
    /// Seconds since this clock's epoch (simulated seconds for a scaled clock).
    fn now_s(&self) -> f64;
    /// Real time that corresponds to `sim` of this clock's time.
    fn real_duration(&self, sim: Duration) -> Duration {
        sim
    }
}

/// Real monotonic time, optionally sped up by `scale` (2.0 = twice as fast as real time).
#[derive(Debug, Clone)]
pub struct MonotonicClock {
    start: Instant,
    scale: f64,
}

impl MonotonicClock {
    pub fn new() -> Self {
        Self::scaled(1.0)
    }
    /// A clock running `scale` times faster than real time. Non-finite or non-positive scales
    /// are treated as 1.
    pub fn scaled(scale: f64) -> Self {
        let scale = if scale.is_finite() && scale > 0.0 { scale } else { 1.0 };
        Self { start: Instant::now(), scale }
    }
    pub fn scale(&self) -> f64 {
        self.scale
    }
}

impl Default for MonotonicClock {
    fn default() -> Self {
        Self::new()
    }
}

impl Clock for MonotonicClock {
    fn now_s(&self) -> f64 {
        self.start.elapsed().as_secs_f64() * self.scale
    }
    fn real_duration(&self, sim: Duration) -> Duration {
        sim.div_f64(self.scale)
    }
}

/// A clock that moves only when [`advance`](MockClock::advance) is called. Cloning shares it.
#[derive(Debug, Clone, Default)]
pub struct MockClock {
    nanos: Arc<AtomicU64>,
}

impl MockClock {
    pub fn new() -> Self {
        Self::default()
    }
    pub fn advance(&self, by: Duration) {
        self.nanos.fetch_add(by.as_nanos() as u64, Ordering::SeqCst);
    }
    pub fn set_s(&self, t_s: f64) {
        self.nanos.store((t_s.max(0.0) * 1e9) as u64, Ordering::SeqCst);
    }
}

impl Clock for MockClock {
    fn now_s(&self) -> f64 {
        self.nanos.load(Ordering::SeqCst) as f64 * 1e-9
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    #[test]
    fn mock_moves_only_when_told() {
        let c = MockClock::new();
        assert_eq!(c.now_s(), 0.0);
        c.advance(Duration::from_millis(1500));
        assert!((c.now_s() - 1.5).abs() < 1e-12);
    }
    #[test]
    fn scaled_clock_runs_faster() {
        let c = MonotonicClock::scaled(10.0);
        assert_eq!(c.real_duration(Duration::from_secs(1)), Duration::from_millis(100));
        assert_eq!(MonotonicClock::scaled(f64::NAN).scale(), 1.0);
    }
}
