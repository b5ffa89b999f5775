//! Re-rendering a session: the built-in device's model run again over the session's
//! journal, inking a fresh paper at the ticks the session inked, with its undo and clear in
//! between. Same fixed-point model, same inker: the same canvas, bit for bit, and the model
//! left where the session ended, so writing can go on.
//!
//! It sits above both halves it joins: the device ([`SimCore`], which wrote the
//! [`Journal`](crate::device::journal::Journal)) and the paper ([`PaperView`], the
//! [`Session`]'s ink log).

use crate::device::builtin::SimCore;
use crate::device::DeviceError;

use super::canvas::PaperView;
use super::session::{CanvasOp, InkLog, Session};

/// What a re-render leaves: the model where the session ended, and the paper.
pub struct Rerender {
    pub core: SimCore,
    pub paper: PaperView,
    pub ink: InkLog,
    /// The session was recorded with another brush model: what that means
    /// ([`Session::model_note`]).
    pub model_note: Option<String>,
}

/// Runs `session` again: the model from its start, the same poses and commands at the
/// same ticks, the same ticks inked and the same undo/clear between them. `progress` is
/// called now and then with the fraction done.
pub fn rerender(session: &Session, mut progress: impl FnMut(f64)) -> anyhow::Result<Rerender> {
    let j = &session.journal;
    let mut core = SimCore::of_model(j.model, &j.preset, j.start)
        .map_err(|e: DeviceError| anyhow::anyhow!("{e}"))?;
    core.set_params(j.params)
        .map_err(|e| anyhow::anyhow!("[params]: {e}"))?;
    let mut paper = PaperView::new(session.paper, session.paper_spec);
    let mut poses = j.poses.iter().peekable();
    let mut events = j.events.iter().peekable();
    let mut ops = session.ink.ops.iter().peekable();
    let mut pose = j.start;
    let mut replayed = InkLog::default();
    while let Some((_, op)) = ops.next_if(|(t, _)| *t == 0) {
        apply_op(&mut paper, *op);
    }
    for tick in 1..=j.ticks {
        while let Some((_, e)) = events.next_if(|(t, _)| *t == tick) {
            // A command that failed live was never journaled; one that fails here
            // means the file was edited by hand.
            core.replay_event(e)
                .map_err(|err| anyhow::anyhow!("tick {tick}: {e:?}: {err}"))?;
        }
        if let Some((_, p)) = poses.next_if(|(t, _)| *t == tick) {
            pose = *p;
        }
        let frame = core.step_at(pose);
        if session.ink.contains(tick) {
            paper.ink(&frame);
            replayed.inked(tick);
        }
        while let Some((_, op)) = ops.next_if(|(t, _)| *t == tick) {
            apply_op(&mut paper, *op);
            replayed.ops.push((tick, *op));
        }
        if tick % 4096 == 0 {
            progress(tick as f64 / j.ticks as f64);
        }
    }
    // Events after the last tick (commands given just before saving).
    for (_, e) in events {
        core.replay_event(e)
            .map_err(|err| anyhow::anyhow!("after the last tick: {e:?}: {err}"))?;
    }
    progress(1.0);
    core.resume_journal(j.clone());
    Ok(Rerender {
        core,
        paper,
        ink: session.ink.clone(),
        model_note: session.model_note(),
    })
}

fn apply_op(paper: &mut PaperView, op: CanvasOp) {
    match op {
        CanvasOp::Undo => {
            paper.undo();
        }
        CanvasOp::Clear => paper.clear(),
    }
}
