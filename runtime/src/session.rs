//! A session: an estimator and a front-end stepping through a stream of events.
//!
//! Each event goes to the estimator as the paper's EKF takes it: a motion increment to
//! [`Estimator::predict`], anything else through the front-end to
//! [`Estimator::update`] (when it yields observations). Events of one time form one time
//! step; when a step ends (the next event has another time, or the stream ends) the estimator
//! ends the step ([`Estimator::end_step`]) and the [`Observer`]s see the estimate.

use slam_core::{Estimator, Pose2, UpdateReport};
use slam_sensors::{Event, TimedEvent};

use crate::error::{Result, RuntimeError};
use crate::frontend::Frontend;

/// What a session tells the code that watches it (recording, progress, post-processing).
/// Every method has a default that does nothing.
pub trait Observer {
    /// After each event is processed, with the estimator's report when the event updated it.
    fn event(
        &mut self,
        event: &TimedEvent,
        update: Option<&UpdateReport>,
        estimator: &dyn Estimator<Pose2>,
    ) -> Result<()> {
        let _ = (event, update, estimator);
        Ok(())
    }

    /// At the end of each time step, with the estimate after all of the step's events.
    fn step_end(&mut self, time: f64, estimator: &dyn Estimator<Pose2>) -> Result<()> {
        let _ = (time, estimator);
        Ok(())
    }
}

/// The observer that watches nothing.
impl Observer for () {}

/// Several observers, each told in turn.
impl Observer for Vec<&mut dyn Observer> {
    fn event(
        &mut self,
        event: &TimedEvent,
        update: Option<&UpdateReport>,
        estimator: &dyn Estimator<Pose2>,
    ) -> Result<()> {
        for observer in self.iter_mut() {
            observer.event(event, update, estimator)?;
        }
        Ok(())
    }

    fn step_end(&mut self, time: f64, estimator: &dyn Estimator<Pose2>) -> Result<()> {
        for observer in self.iter_mut() {
            observer.step_end(time, estimator)?;
        }
        Ok(())
    }
}

/// An estimator and a front-end stepping through events (see the module documentation).
///
/// ```
/// use slam_core::{Pose2, nalgebra::DMatrix};
/// use slam_runtime::{Session, frontend::{FrontendConfig, NoFrontendConfig, SensorInfo}};
/// use slam_runtime::{EstimatorConfig, Start};
/// use slam_estimators::DeadReckoningParams;
/// let start = Start { pose: Pose2::identity(), covariance: DMatrix::zeros(3, 3) };
/// let estimator = DeadReckoningParams::default().build(&start)?;
/// let frontend = NoFrontendConfig::default().build(&SensorInfo::default())?;
/// let mut session = Session::new(estimator, frontend);
/// session.finish(&mut ())?;
/// assert_eq!(session.events(), 0);
/// # Ok::<(), slam_runtime::RuntimeError>(())
/// ```
pub struct Session {
    estimator: Box<dyn Estimator<Pose2>>,
    frontend: Box<dyn Frontend>,
    /// The time of the step being filled, if any.
    open_step: Option<f64>,
    events: usize,
}

impl Session {
    /// A session of `estimator` fed by `frontend`.
    pub fn new(estimator: Box<dyn Estimator<Pose2>>, frontend: Box<dyn Frontend>) -> Self {
        Session {
            estimator,
            frontend,
            open_step: None,
            events: 0,
        }
    }

    /// Processes one event: ends the open time step first when the event starts a new one.
    pub fn step(&mut self, event: &TimedEvent, observer: &mut dyn Observer) -> Result<()> {
        if let Some(open) = self.open_step
            && open != event.time
        {
            self.end_step(open, observer)?;
        }
        self.open_step = Some(event.time);
        let update = self.process(event)?;
        self.events += 1;
        observer.event(event, update.as_ref(), self.estimator.as_ref())
    }

    /// Ends the open time step (call after the last event).
    pub fn finish(&mut self, observer: &mut dyn Observer) -> Result<()> {
        match self.open_step.take() {
            Some(open) => self.end_step(open, observer),
            None => Ok(()),
        }
    }

    /// Steps through every event of `events`, then ends the last step. The first error (a
    /// malformed line of the data, a failed step) stops the run.
    pub fn run(
        &mut self,
        events: impl IntoIterator<Item = slam_sensors::Result<TimedEvent>>,
        observer: &mut dyn Observer,
    ) -> Result<()> {
        for event in events {
            self.step(&event?, observer)?;
        }
        self.finish(observer)
    }

    /// The estimator.
    pub fn estimator(&self) -> &dyn Estimator<Pose2> {
        self.estimator.as_ref()
    }

    /// The front-end.
    pub fn frontend(&self) -> &dyn Frontend {
        self.frontend.as_ref()
    }

    /// Events processed so far.
    pub fn events(&self) -> usize {
        self.events
    }

    /// The estimator and the front-end, once the session is over.
    pub fn into_parts(self) -> (Box<dyn Estimator<Pose2>>, Box<dyn Frontend>) {
        (self.estimator, self.frontend)
    }

    fn end_step(&mut self, time: f64, observer: &mut dyn Observer) -> Result<()> {
        self.estimator.end_step();
        observer.step_end(time, self.estimator.as_ref())
    }

    /// A motion to the prediction; anything else through the front-end to the update when it
    /// yields observations.
    fn process(&mut self, event: &TimedEvent) -> Result<Option<UpdateReport>> {
        let time = event.time;
        if let Event::Motion(motion) = &event.event {
            self.estimator
                .predict(motion.as_ref())
                .map_err(|e| RuntimeError::from(e).at("prediction", time))?;
            return Ok(None);
        }
        let observations = self
            .frontend
            .observe(&event.event)
            .map_err(|e| e.at("front-end", time))?;
        if observations.is_empty() {
            return Ok(None);
        }
        let report = self
            .estimator
            .update(&observations)
            .map_err(|e| RuntimeError::from(e).at("update", time))?;
        Ok(Some(report))
    }
}
