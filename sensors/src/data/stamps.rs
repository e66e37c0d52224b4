//! Time stamps into event times that never go back, shared by the readers of logs whose
//! records are scans and odometry stamped by a logger (CARMEN, ROS 2 bags), so that the same
//! log read either way gives the same events at the same times:
//!
//! - A motion record stamped more than [`STAMP_OUTLIER_S`] before the latest stamp read is out
//!   of order (stamped 0 or with a garbage value): its motion takes the time of the record
//!   after it. (The CARMEN reader reads the Radish corrected logs' `ODOM` line of the
//!   corrected pose after each scan, stamped 0, as a reset of the odometry frame before it
//!   gets here.)
//! - Motion between two scans never takes a time after the next scan's stamp, nor before the
//!   time already written (odometry stamps jitter by up to a second in the Intel log).
//! - A scan stamped before the time already written takes that time.
//!
//! [`Times::repairs`] describes what was changed, for a warning.

use std::collections::VecDeque;

use crate::events::{Event, TimedEvent};

pub use super::carmen::STAMP_OUTLIER_S;

/// At most this many motion events wait for their times (see [`Times::release`]).
const MAX_HELD: usize = 4096;

/// A motion event waiting for its time.
struct Held {
    stamp: f64,
    /// Stamped out of order: takes the time of the record after it.
    out_of_order: bool,
    event: Event,
}

/// Logger timestamps into event times that never go back (see the [module](self) documentation): motion events wait for the next scan, which bounds their times.
#[derive(Default)]
pub(crate) struct Times {
    held: Vec<Held>,
    /// The time of the last event written.
    last: Option<f64>,
    /// The latest stamp of a record in order.
    reached: Option<f64>,
    /// Scans stamped before the time already written, and by how much at most.
    late_scans: usize,
    latest_scan: f64,
    /// Motion events stamped out of order, and those whose time is not their stamp.
    out_of_order: usize,
    moved: usize,
}

impl Times {
    /// The time of a scan stamped `stamp`; writes the motion before it to `out` first.
    pub(crate) fn scan(&mut self, stamp: f64, out: &mut VecDeque<TimedEvent>) -> f64 {
        self.flush(stamp, out);
        let time = match self.last {
            Some(last) if stamp < last => {
                self.late_scans += 1;
                self.latest_scan = self.latest_scan.max(last - stamp);
                last
            }
            _ => stamp,
        };
        self.last = Some(time);
        self.reached = Some(self.reached.map_or(stamp, |r| r.max(stamp)));
        time
    }

    /// Whether a motion record stamped `stamp` would be out of order: more than
    /// [`STAMP_OUTLIER_S`] before the latest stamp in order.
    pub(crate) fn is_out_of_order(&self, stamp: f64) -> bool {
        self.reached.is_some_and(|r| stamp < r - STAMP_OUTLIER_S)
    }

    /// An `ODOM` record stamped `stamp` and its motion event (none for the first).
    pub(crate) fn odometry(
        &mut self,
        stamp: f64,
        event: Option<Event>,
        out: &mut VecDeque<TimedEvent>,
    ) {
        let out_of_order = self.is_out_of_order(stamp);
        if !out_of_order {
            self.reached = Some(self.reached.map_or(stamp, |r| r.max(stamp)));
        }
        if let Some(event) = event {
            self.held.push(Held {
                stamp,
                out_of_order,
                event,
            });
        }
        self.release(out);
    }

    /// The times of the waiting motion events with nothing after them but `bound`: each its
    /// stamp, bounded by the times after it; one stamped out of order takes the time after it.
    fn provisional(&self, bound: f64) -> Vec<f64> {
        let mut after = bound;
        let mut times = vec![0.0; self.held.len()];
        for (time, held) in times.iter_mut().zip(&self.held).rev() {
            *time = if held.out_of_order {
                after
            } else {
                held.stamp.min(after)
            };
            after = *time;
        }
        times
    }

    /// Writes the waiting motion events whose times no later record can lower (records in
    /// order are stamped at most [`STAMP_OUTLIER_S`] before the latest stamp), or all of them
    /// when too many wait: a log of odometry alone streams too.
    fn release(&mut self, out: &mut VecDeque<TimedEvent>) {
        let Some(reached) = self.reached else { return };
        let times = self.provisional(f64::INFINITY);
        let safe = if self.held.len() >= MAX_HELD {
            times.len()
        } else {
            times.partition_point(|&t| t <= reached - STAMP_OUTLIER_S)
        };
        self.write(safe, &times, out);
    }

    /// Writes the waiting motion events to `out`, none after `bound` (the next scan's stamp,
    /// or infinity at the end).
    pub(crate) fn flush(&mut self, bound: f64, out: &mut VecDeque<TimedEvent>) {
        let times = self.provisional(bound);
        self.write(times.len(), &times, out);
    }

    /// Writes the first `n` waiting motion events with `times`, never before the time
    /// already written.
    fn write(&mut self, n: usize, times: &[f64], out: &mut VecDeque<TimedEvent>) {
        for (held, &time) in self.held.drain(..n).zip(times) {
            // Without a record after it, an event stamped out of order takes the time before.
            let time = match (self.last, time.is_finite()) {
                (Some(last), true) => time.max(last),
                (Some(last), false) => last,
                (None, true) => time,
                (None, false) => held.stamp,
            };
            if held.out_of_order {
                self.out_of_order += 1;
            } else if time != held.stamp {
                self.moved += 1;
            }
            self.last = Some(time);
            out.push_back(TimedEvent {
                time,
                event: held.event,
            });
        }
    }

    /// The time of a record that goes with the scans (a reference pose of its own): its
    /// stamp, never before the time already written.
    pub(crate) fn other(&mut self, stamp: f64) -> f64 {
        let time = self.last.map_or(stamp, |last| stamp.max(last));
        self.last = Some(time);
        time
    }

    /// What the repairs changed, for a warning; `None` when every time is its stamp.
    pub(crate) fn repairs(&self) -> Option<String> {
        let mut parts = Vec::new();
        if self.late_scans > 0 {
            parts.push(format!(
                "{} scans stamped up to {:.3} s before the time already reached took that time",
                self.late_scans, self.latest_scan
            ));
        }
        if self.out_of_order > 0 {
            parts.push(format!(
                "{} odometry records stamped more than {STAMP_OUTLIER_S} s before the latest \
                 stamp (e.g. 0) took the time of the record after them",
                self.out_of_order
            ));
        }
        if self.moved > 0 {
            parts.push(format!(
                "{} odometry records stamped out of order with their neighbours took a \
                 neighbour's time",
                self.moved
            ));
        }
        (!parts.is_empty()).then(|| format!("timestamps repaired: {}", parts.join("; ")))
    }
}
