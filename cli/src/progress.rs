//! A progress bar as a session observer.

use indicatif::{ProgressBar, ProgressStyle};
use slam_core::{Estimator, Pose2, UpdateReport};
use slam_runtime::{Observer, Result};
use slam_sensors::TimedEvent;

/// A spinner counting events, hidden when `quiet` (and by indicatif when stderr is not a
/// terminal); the data are streamed, so their length is not known ahead.
pub struct Progress(ProgressBar);

impl Progress {
    /// A spinner, or a hidden one.
    pub fn new(quiet: bool) -> Self {
        if quiet {
            return Progress(ProgressBar::hidden());
        }
        let bar = ProgressBar::new_spinner();
        if let Ok(style) =
            ProgressStyle::with_template("{spinner} [{elapsed_precise}] {pos} events {msg}")
        {
            bar.set_style(style);
        }
        Progress(bar)
    }

    /// Clears the spinner.
    pub fn finish(&self) {
        self.0.finish_and_clear();
    }
}

impl Observer for Progress {
    fn event(
        &mut self,
        _: &TimedEvent,
        _: Option<&UpdateReport>,
        _: &dyn Estimator<Pose2>,
    ) -> Result<()> {
        self.0.inc(1);
        Ok(())
    }
}
