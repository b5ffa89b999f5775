//! The journal of a built-in device: every handle pose and every brush command since its
//! model started, stamped with the tick it took effect before.
//!
//! The device writes it ([`super::builtin::SimCore`]), because only the device knows at which
//! tick a command took effect; the GUI's session file stores it, and re-rendering runs the
//! device over it again.

use maobi_shared::{BrushParams, ParamId, Pose};

use super::model::ModelKind;

/// Pose changes a journal keeps (64 bytes each): 1,000,000 is about 17 minutes of
/// continuous motion; a hand at rest costs nothing. Past it the journal stops, and saving
/// says so.
pub const MAX_JOURNAL_POSES: usize = 1_000_000;

/// A change to the model between ticks.
#[derive(Clone, Debug, PartialEq)]
pub enum JournalEvent {
    Dip(f32),
    Param(ParamId, f32),
    /// A preset's parameters, and the brush reset at rest where the hand is.
    Preset(String),
    /// The brush (and force model) reset at rest at this pose (a replay's start).
    Reset(Pose<f64>),
    /// Another brush model from here on, the brush as it stands, at rest where the hand is.
    Model(ModelKind),
}

/// What the simulator did, tick by tick, since it started.
#[derive(Clone, Debug)]
pub struct Journal {
    /// The brush model the device started with.
    pub model: ModelKind,
    pub preset: String,
    pub params: BrushParams,
    /// The brush was created at rest at this pose, before tick 1.
    pub start: Pose<f64>,
    /// The last tick run.
    pub ticks: u64,
    /// `(tick, pose)` for each tick whose handle pose differs from the previous tick's.
    pub poses: Vec<(u64, Pose<f64>)>,
    /// `(tick, event)`: the event took effect before `tick` ran.
    pub events: Vec<(u64, JournalEvent)>,
    /// The tick at which [`MAX_JOURNAL_POSES`] ran out, if it did.
    pub full_at: Option<u64>,
    last_pose: Pose<f64>,
}

impl Journal {
    pub fn new(preset: &str, params: BrushParams, start: Pose<f64>) -> Journal {
        Journal {
            model: ModelKind::Liang,
            preset: preset.to_string(),
            params,
            start,
            ticks: 0,
            poses: Vec::new(),
            events: Vec::new(),
            full_at: None,
            last_pose: start,
        }
    }

    /// A journal read back (a session file's): `ticks` run from `start`, with the pose
    /// changes and events [`Journal::tick`] and [`Journal::event`] kept.
    pub fn restored(
        preset: &str,
        params: BrushParams,
        start: Pose<f64>,
        ticks: u64,
        poses: Vec<(u64, Pose<f64>)>,
        events: Vec<(u64, JournalEvent)>,
    ) -> Journal {
        Journal {
            last_pose: poses.last().map_or(start, |p| p.1),
            ticks,
            poses,
            events,
            ..Journal::new(preset, params, start)
        }
    }

    /// This journal with its device started on `model`.
    pub fn with_model(mut self, model: ModelKind) -> Journal {
        self.model = model;
        self
    }

    /// Notes that tick `tick` ran with the handle at `pose`.
    pub fn tick(&mut self, tick: u64, pose: Pose<f64>) {
        self.ticks = tick;
        if self.full_at.is_some() || pose == self.last_pose {
            return;
        }
        if self.poses.len() >= MAX_JOURNAL_POSES {
            self.full_at = Some(tick);
            return;
        }
        self.poses.push((tick, pose));
        self.last_pose = pose;
    }

    /// Notes an event that takes effect before the next tick.
    pub fn event(&mut self, e: JournalEvent) {
        if self.full_at.is_none() {
            self.events.push((self.ticks + 1, e));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use maobi_shared::{presets, Quat, Vec3};

    #[test]
    fn journal_keeps_only_pose_changes_and_stamps_events_on_the_next_tick() {
        let p0 = Pose::new(Vec3::new(0.0, 0.0, 40.0), Quat::IDENTITY);
        let p1 = Pose::new(Vec3::new(1.0, 0.0, 40.0), Quat::IDENTITY);
        let mut j = Journal::new("large", presets::LARGE, p0);
        j.tick(1, p0);
        j.tick(2, p1);
        j.event(JournalEvent::Dip(0.5));
        j.tick(3, p1);
        assert_eq!(j.poses, vec![(2, p1)]);
        assert_eq!(j.events, vec![(3, JournalEvent::Dip(0.5))]);
        assert_eq!(j.ticks, 3);
    }
}
