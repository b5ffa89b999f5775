//! The brush model the built-in simulator runs, in its 1 kHz loop: Liang's [`ForceLoop`]
//! or Baxter & Lin's [`BaxterLinLoop`] (the local force model between solves), both ending
//! in the shared guide, gate and output stage, each with the stroke its guide plays.

use maobi_shared::baxter_lin::brush::{BaxterLinBrush, RING_NODES};
use maobi_shared::baxter_lin::force_loop::BaxterLinLoop;
use maobi_shared::brush::Layer;
use maobi_shared::force::{DeviceLimits, OutputState, DEFAULT_FORCES};
use maobi_shared::force_loop::{Gate, TickIn};
use maobi_shared::guide::{GuideParams, GuidePlay};
use maobi_shared::protocol::Faults;
use maobi_shared::{BrushParams, ForceLoop, Fx, ParamId, Pose, Scalar, Vec3};

use std::time::Instant;

use super::api::{BrushFrame, DeviceError, GuideFrame};
use super::lane::HostLane;
use super::model::{BrushChoice, ModelKind};

/// The part of a tick every model reports, in the units a [`super::BrushFrame`] carries.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct ModelTick {
    /// The output stage's command (N).
    pub command: [f64; 3],
    /// The brush's force on the hand before the guide and the output stage (N), and its
    /// part along the paper's normal.
    pub force_total: [f64; 3],
    pub force_normal: [f64; 3],
    /// Liang's virtual skeleton's depth below the paper (mm); Baxter & Lin's hair never goes
    /// below it (0).
    pub depth_mm: f64,
    pub faults: Faults,
    /// Guided writing, while a stroke plays into the guide.
    pub guide: Option<GuideFrame>,
}

impl ModelTick {
    /// Baxter & Lin's tick: the output stage's `command`, the local model's `force` (its
    /// normal part along the paper's normal), no skeleton below the paper.
    pub fn of_baxter_lin(
        command: Vec3<f64>,
        force: Vec3<f64>,
        faults: Faults,
        guide: Option<GuideFrame>,
    ) -> ModelTick {
        ModelTick {
            command: command.to_f64(),
            force_total: force.to_f64(),
            force_normal: [0.0, 0.0, force.z],
            depth_mm: 0.0,
            faults,
            guide,
        }
    }
}

/// A simulated brush model in its 1 kHz loop.
// Both loops are large; the enum is boxed where it lives (one per device).
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug)]
pub enum SimModel {
    /// Liang's brush in the pen's own loop, in the pen's number type, and the stroke its
    /// guide plays.
    Liang {
        fl: ForceLoop<Fx>,
        play: Option<GuidePlay<Vec<Vec3<Fx>>>>,
        lane: Option<HostLane>,
    },
    /// Baxter & Lin's brush of `brush`'s head, its loop and the stroke its guide plays.
    BaxterLin {
        lp: BaxterLinLoop,
        brush: BrushChoice,
        params: BrushParams,
        play: Option<GuidePlay<Vec<Vec3<f64>>>>,
        lane: Option<HostLane>,
    },
}

impl SimModel {
    /// `model` with the brush `brush` (parameters `params`) at rest at `pose`, the device's
    /// `limits` and the guide `guide`.
    pub fn new(
        model: ModelKind,
        brush: &BrushChoice,
        params: BrushParams,
        pose: Pose<f64>,
        limits: DeviceLimits,
        guide: GuideParams,
    ) -> Result<SimModel, DeviceError> {
        let rejected = |e: &dyn std::fmt::Display| DeviceError::Rejected(e.to_string());
        match model {
            ModelKind::Liang => {
                if let Some(shape) = brush.shape {
                    return Err(DeviceError::Rejected(format!(
                        "the {} brush is Baxter & Lin's model's",
                        shape.name()
                    )));
                }
                ForceLoop::new(params, pose.cast(), DEFAULT_FORCES, limits, guide)
                    .map(|fl| SimModel::Liang {
                        fl,
                        play: None,
                        lane: None,
                    })
                    .map_err(|e| rejected(&e))
            }
            ModelKind::BaxterLin => {
                let b = BaxterLinBrush::of_shape(brush.head_shape(), &params, pose)
                    .map_err(|e| rejected(&e))?;
                let lp = BaxterLinLoop::new(b, pose, limits, guide).map_err(|e| rejected(&e))?;
                Ok(SimModel::BaxterLin {
                    lp,
                    brush: brush.clone(),
                    params,
                    play: None,
                    lane: None,
                })
            }
        }
    }

    pub fn kind(&self) -> ModelKind {
        match self {
            SimModel::Liang { .. } => ModelKind::Liang,
            SimModel::BaxterLin { .. } => ModelKind::BaxterLin,
        }
    }

    /// The parameters in force (Baxter & Lin's brush reads only its head's, see
    /// [`BrushChoice::baxter_lin_reads`]).
    pub fn params(&self) -> &BrushParams {
        match self {
            SimModel::Liang { fl, .. } => fl.brush().params(),
            SimModel::BaxterLin { params, .. } => params,
        }
    }

    /// Guided writing: the guide plays `points` (one per tick) from the next tick.
    pub fn guide(&mut self, points: Vec<Vec3<f64>>) {
        match self {
            SimModel::Liang { play, lane, .. } => {
                *play = Some(GuidePlay::new(points.iter().map(|p| p.cast()).collect()));
                *lane = None;
            }
            SimModel::BaxterLin { play, lane, .. } => {
                *play = Some(GuidePlay::new(points));
                *lane = None;
            }
        }
    }

    /// Stay in the lane: the guide keeps the hand near `lane`'s path from the next tick
    /// (replacing guided writing).
    pub fn lane(&mut self, new: HostLane) {
        match self {
            SimModel::Liang { play, lane, .. } => {
                *play = None;
                *lane = Some(new);
            }
            SimModel::BaxterLin { play, lane, .. } => {
                *play = None;
                *lane = Some(new);
            }
        }
    }

    /// Stops guided writing: the point reached is held while the guide fades out.
    pub fn stop_guide(&mut self) {
        match self {
            SimModel::Liang { play, lane, .. } => {
                if let Some(p) = play {
                    p.stop();
                }
                if let Some(l) = lane {
                    l.stop();
                }
            }
            SimModel::BaxterLin { play, lane, .. } => {
                if let Some(p) = play {
                    p.stop();
                }
                if let Some(l) = lane {
                    l.stop();
                }
            }
        }
    }

    /// Guided writing is on (or fading out).
    pub fn guiding(&self) -> bool {
        match self {
            SimModel::Liang { play, lane, .. } => play.is_some() || lane.is_some(),
            SimModel::BaxterLin { play, lane, .. } => play.is_some() || lane.is_some(),
        }
    }

    /// Brush parameters `params` in force, the brush at rest at its handle `pose`.
    pub fn set_params(&mut self, params: BrushParams, pose: Pose<f64>) -> Result<(), DeviceError> {
        match self {
            SimModel::Liang { fl, .. } => fl
                .set_params(params)
                .map_err(|e| DeviceError::Rejected(e.to_string())),
            SimModel::BaxterLin {
                lp,
                brush,
                params: held,
                ..
            } => {
                let b = BaxterLinBrush::of_shape(brush.head_shape(), &params, pose)
                    .map_err(|e| DeviceError::Rejected(e.to_string()))?;
                lp.reset_brush(b, pose);
                *held = params;
                Ok(())
            }
        }
    }

    /// Sets one parameter: Liang's brush takes it as it stands; Baxter & Lin's is rebuilt at
    /// rest at `pose` with it (refused if its head does not read it).
    pub fn set_param(&mut self, id: ParamId, v: f32, pose: Pose<f64>) -> Result<(), DeviceError> {
        match self {
            SimModel::Liang { fl, .. } => fl
                .brush_mut()
                .set_param(id, v)
                .map_err(|e| DeviceError::Rejected(e.to_string())),
            SimModel::BaxterLin { brush, params, .. } => {
                brush.baxter_lin_reads(id).map_err(DeviceError::Rejected)?;
                let mut p = *params;
                p.set(id, v)
                    .and_then(|()| p.validate())
                    .map_err(|e| DeviceError::Rejected(e.to_string()))?;
                self.set_params(p, pose)
            }
        }
    }

    /// Wets every layer to `w` in [0, 1].
    pub fn dip(&mut self, w: f32) {
        match self {
            SimModel::Liang { fl, .. } => fl.brush_mut().dip(Fx::from_f32(w)),
            SimModel::BaxterLin { lp, .. } => lp.dip(w as f64),
        }
    }

    /// The brush at rest at `pose`, the forces afresh; the next pose is not checked for a
    /// jump from the last.
    pub fn reset_at(&mut self, pose: Pose<f64>) {
        match self {
            SimModel::Liang { fl, .. } => {
                fl.reset_brush(pose.cast());
                fl.forget_pose();
            }
            SimModel::BaxterLin { .. } => {
                let p = *self.params();
                // The parameters were valid when set, so the rebuild cannot fail; if it
                // did, the brush would stay as it was rather than vanish.
                let _ = self.set_params(p, pose);
            }
        }
    }

    /// What the output stage is doing under the switch `enabled` with `faults` latched.
    pub fn output_state(&self, enabled: bool, faults: Faults) -> OutputState {
        match self {
            SimModel::Liang { fl, .. } => fl.output_state(enabled, faults),
            SimModel::BaxterLin { lp, .. } => lp.output_state(enabled, faults),
        }
    }

    /// One 1 kHz tick of the loop with the handle at `pose` (none: the host fell behind)
    /// under `gate`, the guide fed from its play.
    pub fn tick(&mut self, pose: Option<Pose<f64>>, gate: Gate) -> ModelTick {
        match self {
            SimModel::Liang { fl, play, lane } => {
                let guide = match lane {
                    Some(l) => l.next_sample(pose.map(|p| p.pos.to_f64()), fl.guide()),
                    None => GuidePlay::next_sample_of(play, fl.guide()),
                };
                let out = fl.tick(TickIn {
                    pose: pose.map(|p| p.cast()),
                    guide,
                    gate,
                });
                let tick = ModelTick {
                    command: out.command.to_f64(),
                    force_total: out.forces.total.to_f64(),
                    force_normal: out.forces.normal.to_f64(),
                    depth_mm: out.forces.depth_mm.to_f64(),
                    faults: out.faults,
                    guide: (play.is_some() || lane.is_some())
                        .then(|| GuideFrame::of(fl.guide(), &out.guide))
                        .flatten(),
                };
                // A lane let go is done once its guide has faded out.
                if lane.as_ref().is_some_and(|l| l.done(fl.guide())) {
                    *lane = None;
                }
                tick
            }
            SimModel::BaxterLin { lp, play, lane, .. } => {
                let guide = match lane {
                    Some(l) => l.next_sample(pose.map(|p| p.pos.to_f64()), lp.guide()),
                    None => GuidePlay::next_sample_of(play, lp.guide()),
                };
                let out = lp.tick(TickIn { pose, guide, gate });
                let guide = (play.is_some() || lane.is_some())
                    .then(|| GuideFrame::of(lp.guide(), &out.guide))
                    .flatten();
                if lane.as_ref().is_some_and(|l| l.done(lp.guide())) {
                    *lane = None;
                }
                ModelTick::of_baxter_lin(out.command, out.force, out.faults, guide)
            }
        }
    }

    /// The frame of the tick just run: `tick` with the handle at `pose`, what the loop
    /// gave (`out`), the output stage's state and whether a replay drove it; the brush's
    /// surface in the frame's number type, and Baxter & Lin's spines for the drawing.
    pub fn frame(
        &self,
        tick: u64,
        pose: Pose<f64>,
        out: ModelTick,
        output: OutputState,
        replaying: bool,
    ) -> BrushFrame {
        let mut frame = frame_of_tick(tick, pose, out, output, replaying);
        match self {
            SimModel::Liang { fl, .. } => {
                let b = fl.brush();
                frame.spine = b.spine().to_vec();
                frame.skeleton = b.skeleton().to_vec();
                frame.layers = b.layers().to_vec();
                frame.in_contact = b.in_contact().to_vec();
                frame.ring_nodes = b.ring_nodes();
                frame.eps = Fx::from_f32(b.params().footprint_eps_mm);
            }
            SimModel::BaxterLin { lp, .. } => fill_baxter_lin(&mut frame, lp.brush()),
        }
        frame
    }
}

/// A frame of tick `tick` with the handle at `pose`, what the loop gave (`out`), the output
/// stage's state and whether a replay drove it; no brush in it yet.
pub fn frame_of_tick(
    tick: u64,
    pose: Pose<f64>,
    out: ModelTick,
    output: OutputState,
    replaying: bool,
) -> BrushFrame {
    BrushFrame {
        tick,
        pose,
        spine: Vec::new(),
        skeleton: Vec::new(),
        layers: Vec::new(),
        in_contact: Vec::new(),
        ring_nodes: 0,
        eps: Fx::ZERO,
        hairs: Vec::new(),
        force_total: out.force_total,
        force_normal: out.force_normal,
        depth_mm: out.depth_mm,
        command: out.command,
        output,
        replaying,
        received: Instant::now(),
        guide: out.guide,
    }
}

/// Puts Baxter & Lin's brush `b` into `frame`: its rings as the surface's layers (in the
/// frame's number type) and its spines for the drawing.
pub fn fill_baxter_lin(frame: &mut BrushFrame, b: &BaxterLinBrush) {
    let eps = b.geometry().eps;
    frame.spine = b.centres().iter().map(|c| c.cast()).collect();
    frame.layers = b.layers().iter().map(Layer::cast).collect();
    // A ring inks where its lowest point reaches the footprint's threshold.
    frame.in_contact = b
        .centres()
        .iter()
        .zip(b.layers())
        .map(|(c, l)| c.z - l.long_radius.max(l.short_radius) <= eps)
        .collect();
    frame.ring_nodes = RING_NODES;
    frame.eps = Fx::from_f64(eps);
    frame.hairs = b.spines().iter().map(|s| s.positions().to_vec()).collect();
}
