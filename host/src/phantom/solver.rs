//! Baxter & Lin's brush on the Phantom: solved on a thread of its own beside the servo loop.
//!
//! A solve of their brush along the ten ticks since the last (in substeps,
//! `BaxterLinBrush::tick`) and the rebuild of its local force model take several
//! milliseconds on the desktop, several servo periods, so the servo callback cannot run
//! them: it would overrun every tenth tick. The callback runs only the 1 kHz half of the loop
//! ([`BaxterLinHand`], the same one the built-in simulator's [`BaxterLinLoop`] ends in)
//! against the last [`LocalForceModel`] this thread published; every
//! [`LocalForceParams::rebuild_every`] ticks it leaves the pose to solve at in a slot and
//! wakes the thread.
//!
//! # Neither side waits for the other
//! The callback only `try_lock`s: a slot the solver holds at that instant is tried again the
//! next tick. The request slot keeps the newest request (a solver that falls behind solves
//! the newest pose and counts the ones it skipped); the spines' friction is told the time the
//! solve really covers (the servo ticks between the poses it solved). The model the callback
//! feels is one solve old at most, plus however long the solve took: the local model is built
//! for exactly that, a force field valid around the solved pose.
//!
//! # A solver that stalls
//! A model is a force field valid about the pose it was solved at. One felt longer than
//! [`LocalForceParams::stale_after_ticks`] after that pose (the solver starved of the
//! processor, or stuck) pushes the hand by a field extrapolated from where it no longer is
//! and creates energy (the passivity audit measures it). As for a stalled loop, the
//! callback then closes the output stage's gate, so the force ramps out, until a fresh model
//! arrives; the GUI says why.
//!
//! # Brushes afresh
//! Each request carries the brush's generation. The servo loop starts a new generation
//! whenever it restarts the brush (the first pose, a calibration, a device warning, new
//! parameters); the solver then builds the brush at rest at the request's pose, and the
//! callback feels no force until a model of the new generation arrives, so no model of the
//! old brush is ever felt at the new pose.
//!
//! [`BaxterLinLoop`]: maobi_shared::baxter_lin::force_loop::BaxterLinLoop
//! [`BaxterLinHand`]: maobi_shared::baxter_lin::force_loop::BaxterLinHand

use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::thread::{JoinHandle, Thread};
use std::time::Duration;

use maobi_shared::baxter_lin::brush::BaxterLinBrush;
use maobi_shared::baxter_lin::head::HeadShape;
use maobi_shared::baxter_lin::local_force::{LocalForceBrush, LocalForceModel, LocalForceParams};
use maobi_shared::force::TICK_S;
use maobi_shared::{BrushParams, Pose};

/// What the servo loop asks the solver to do: solve the brush of generation `generation`
/// at `pose`, as of servo tick `tick`.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct SolveRequest {
    pub generation: u32,
    pub tick: u32,
    pub pose: Pose<f64>,
    /// The parameters a new generation's brush is built with.
    pub params: BrushParams,
}

/// A model the solver published: of the brush of `generation`, solved at the pose of servo
/// tick `tick`.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Published {
    pub generation: u32,
    pub tick: u32,
    pub model: LocalForceModel,
}

/// What the servo callback and the solver thread share. The callback touches only atomics
/// and `try_lock`s.
pub struct SolverLink {
    request: Mutex<Option<SolveRequest>>,
    published: Mutex<Option<Published>>,
    /// The brush as last solved and its generation, for the GUI's frames (replaced, never
    /// mutated in place).
    brush: Mutex<Option<(u32, Arc<BaxterLinBrush>)>>,
    /// Dips asked for (a counter), and the last one's load (`f32` bits).
    dips: AtomicU32,
    dip_load: AtomicU32,
    solves: AtomicU64,
    /// Requests replaced before the solver took them (it fell behind).
    skipped: AtomicU64,
    /// Requests the servo could not leave (the solver held the slot) and left a tick later.
    deferred: AtomicU64,
    /// Servo ticks without brush force because the newest model was stale, and whether the
    /// last tick was one.
    stale_ticks: AtomicU64,
    stale: AtomicBool,
    /// Why the solver could not build the brush in force (parameters the model refuses).
    refusal: Mutex<Option<String>>,
    stop: AtomicBool,
    thread: OnceLock<Thread>,
}

impl SolverLink {
    pub fn new() -> Arc<SolverLink> {
        Arc::new(SolverLink {
            request: Mutex::new(None),
            published: Mutex::new(None),
            brush: Mutex::new(None),
            dips: AtomicU32::new(0),
            dip_load: AtomicU32::new(0),
            solves: AtomicU64::new(0),
            skipped: AtomicU64::new(0),
            deferred: AtomicU64::new(0),
            stale_ticks: AtomicU64::new(0),
            stale: AtomicBool::new(false),
            refusal: Mutex::new(None),
            stop: AtomicBool::new(false),
            thread: OnceLock::new(),
        })
    }

    /// The servo side: leaves `req` for the solver (replacing one it has not taken) and
    /// wakes it (`unpark`: at most a futex wake, which never waits). Never blocks; `false`
    /// if the slot was busy this instant (try next tick).
    pub fn request(&self, req: SolveRequest) -> bool {
        match self.request.try_lock() {
            Ok(mut slot) => {
                if slot.replace(req).is_some() {
                    self.skipped.fetch_add(1, Ordering::Relaxed);
                }
                drop(slot);
                if let Some(t) = self.thread.get() {
                    t.unpark();
                }
                true
            }
            Err(_) => {
                self.deferred.fetch_add(1, Ordering::Relaxed);
                false
            }
        }
    }

    /// The servo side: the newest model published since the last call, if the slot is free
    /// this instant.
    pub fn take_published(&self) -> Option<Published> {
        self.published.try_lock().ok()?.take()
    }

    /// Dips the brush (every ring to `load` of what it holds) at the solver's next solve.
    pub fn dip(&self, load: f32) {
        self.dip_load.store(load.to_bits(), Ordering::Release);
        self.dips.fetch_add(1, Ordering::AcqRel);
    }

    /// The brush as last solved (`None` before the first solve).
    pub fn brush(&self) -> Option<Arc<BaxterLinBrush>> {
        self.brush.lock().ok()?.as_ref().map(|(_, b)| b.clone())
    }

    /// The brush as last solved if it is of `generation` (a restarted brush is not drawn
    /// as the old one).
    pub fn brush_of(&self, generation: u32) -> Option<Arc<BaxterLinBrush>> {
        match self.brush.lock().ok()?.as_ref() {
            Some((g, b)) if *g == generation => Some(b.clone()),
            _ => None,
        }
    }

    /// Solves done, requests the solver never took (it fell behind), and requests the servo
    /// left a tick late.
    pub fn counts(&self) -> (u64, u64, u64) {
        (
            self.solves.load(Ordering::Relaxed),
            self.skipped.load(Ordering::Relaxed),
            self.deferred.load(Ordering::Relaxed),
        )
    }

    /// The servo side: whether this tick's model was stale (see
    /// [`LocalForceParams::stale_after_ticks`]).
    pub fn set_stale(&self, stale: bool) {
        if stale {
            self.stale_ticks.fetch_add(1, Ordering::Relaxed);
        }
        self.stale.store(stale, Ordering::Relaxed);
    }

    /// Whether the servo loop is holding the brush's force for want of a fresh model, and
    /// the ticks it has done so in all.
    pub fn stale(&self) -> (bool, u64) {
        (
            self.stale.load(Ordering::Relaxed),
            self.stale_ticks.load(Ordering::Relaxed),
        )
    }

    /// Why the brush in force could not be built, if it could not (the next that builds
    /// clears it).
    pub fn refusal(&self) -> Option<String> {
        self.refusal.lock().ok()?.clone()
    }
}

/// The solver's side: the brush of the current generation and its local force model.
pub struct Solver {
    link: Arc<SolverLink>,
    shape: HeadShape,
    params: LocalForceParams,
    /// The brush, its generation and the servo tick it was last solved at.
    current: Option<(u32, u32, LocalForceBrush)>,
    dips_seen: u32,
}

impl Solver {
    /// A solver of heads of `shape`, its local models built with `params`.
    pub fn new(link: Arc<SolverLink>, shape: HeadShape, params: LocalForceParams) -> Solver {
        Solver {
            link,
            shape,
            params,
            current: None,
            dips_seen: 0,
        }
    }

    /// Serves the pending request, if there is one: a new generation's brush built at rest
    /// at its pose, or the current one solved there; the dips asked for since; then the model
    /// and the brush published. Returns whether there was a request.
    pub fn serve(&mut self) -> bool {
        let req = match self.link.request.lock() {
            Ok(mut slot) => slot.take(),
            Err(_) => None,
        };
        let Some(req) = req else {
            return false;
        };
        match &mut self.current {
            Some((generation, last_tick, brush)) if *generation == req.generation => {
                let ticks = req.tick.wrapping_sub(*last_tick).max(1);
                brush.set_solve_interval(f64::from(ticks) * TICK_S);
                brush.solve(&req.pose);
                *last_tick = req.tick;
            }
            _ => match BaxterLinBrush::of_shape(self.shape, &req.params, req.pose) {
                Ok(b) => {
                    if let Ok(mut r) = self.link.refusal.lock() {
                        *r = None;
                    }
                    let brush = LocalForceBrush::new(b, &req.pose, self.params);
                    self.current = Some((req.generation, req.tick, brush));
                }
                Err(e) => {
                    // The parameters were validated before they reached the servo loop; a
                    // brush the model still refuses leaves the hand feeling nothing.
                    if let Ok(mut r) = self.link.refusal.lock() {
                        *r = Some(e.to_string());
                    }
                    self.current = None;
                    return true;
                }
            },
        }
        let Some((generation, tick, brush)) = &mut self.current else {
            return true;
        };
        let dips = self.link.dips.load(Ordering::Acquire);
        if dips != self.dips_seen {
            self.dips_seen = dips;
            let load = f32::from_bits(self.link.dip_load.load(Ordering::Acquire));
            brush.dip(if load.is_finite() {
                f64::from(load)
            } else {
                0.0
            });
        }
        self.link.solves.fetch_add(1, Ordering::Relaxed);
        if let Ok(mut slot) = self.link.published.lock() {
            *slot = Some(Published {
                generation: *generation,
                tick: *tick,
                model: *brush.model(),
            });
        }
        let snapshot = (*generation, Arc::new(brush.brush().clone()));
        if let Ok(mut b) = self.link.brush.lock() {
            *b = Some(snapshot);
        }
        true
    }

    /// Serves requests until the link is stopped, sleeping between them (woken by the
    /// servo's requests; a timeout covers a wake lost to a race).
    fn run(mut self) {
        while !self.link.stop.load(Ordering::Acquire) {
            if !self.serve() {
                std::thread::park_timeout(Duration::from_millis(20));
            }
        }
    }
}

/// The solver thread, stopped and joined when dropped.
pub struct SolverThread {
    link: Arc<SolverLink>,
    handle: Option<JoinHandle<()>>,
}

impl SolverThread {
    /// Starts a thread serving `link` for heads of `shape`.
    pub fn spawn(
        link: Arc<SolverLink>,
        shape: HeadShape,
        params: LocalForceParams,
    ) -> std::io::Result<SolverThread> {
        let solver = Solver::new(link.clone(), shape, params);
        let handle = std::thread::Builder::new()
            .name("maobi-brush-solver".into())
            .spawn(move || solver.run())?;
        let _ = link.thread.set(handle.thread().clone());
        Ok(SolverThread {
            link,
            handle: Some(handle),
        })
    }

    pub fn link(&self) -> &Arc<SolverLink> {
        &self.link
    }

    /// Stops the thread (after the solve under way) and waits for it.
    pub fn stop(&mut self) {
        self.link.stop.store(true, Ordering::Release);
        if let Some(h) = self.handle.take() {
            h.thread().unpark();
            let _ = h.join();
        }
    }
}

impl Drop for SolverThread {
    fn drop(&mut self) {
        self.stop();
    }
}
