//! The host end of the device link: handshake, pose streaming paced by the device's state
//! frames, and the bit-exact comparison with the host simulation.
//!
//! The same code runs over any byte stream ([`Transport`]): QEMU's UART0 on a loopback TCP
//! socket (backend `qemu`) or a serial port (backend `serial`).

use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use maobi::device::endpoint::nothing_to_read_yet;
use maobi::poses::PoseTrack;
use maobi_shared::force::{DEFAULT_FORCES, PHANTOM_OMNI};
use maobi_shared::force_loop::{Gate, TickIn};
use maobi_shared::guide::{GuideInput, DEFAULT_GUIDE};
use maobi_shared::protocol::{
    vec3_bits, BrushState, Buttons, Command, DeviceInfo, DeviceMsg, Event, EventKind, GuideSample,
    HostHello, HostMsg, HostRx, Message, PoseSample, ProtocolError, Telemetry, Vec3Bits, Version,
    DELIMITER,
};
use maobi_shared::{Brush, BrushParams, ForceLoop, Fx, Scalar, Vec3};

/// A byte stream to the device with a read timeout.
pub trait Transport: Read + Write {
    fn set_read_timeout(&mut self, t: Duration) -> Result<()>;
}

impl Transport for std::net::TcpStream {
    fn set_read_timeout(&mut self, t: Duration) -> Result<()> {
        std::net::TcpStream::set_read_timeout(self, Some(t))?;
        Ok(())
    }
}

/// What came from the device, with when it arrived (host clock).
#[derive(Clone, Debug)]
pub struct Received {
    pub at: Instant,
    pub msg: DeviceMsg,
    /// Bytes on the wire (COBS, delimiter included).
    pub wire_len: usize,
}

/// One link session.
pub struct Session<T: Transport> {
    io: T,
    rx: HostRx,
    buf: Vec<u8>,
    pending: std::collections::VecDeque<Received>,
    /// Frame bytes since the last delimiter (for `wire_len`).
    run: usize,
    /// Bytes received in all.
    pub bytes_in: u64,
    pub bytes_out: u64,
    /// Decode errors seen on the host side.
    pub errors: Vec<ProtocolError>,
}

impl<T: Transport> Session<T> {
    pub fn new(mut io: T) -> Result<Self> {
        io.set_read_timeout(Duration::from_millis(2))?;
        Ok(Session {
            io,
            rx: HostRx::new(),
            buf: vec![0; 8192],
            pending: Default::default(),
            run: 0,
            bytes_in: 0,
            bytes_out: 0,
            errors: vec![],
        })
    }

    pub fn into_inner(self) -> T {
        self.io
    }

    /// Writes raw bytes (whole frames, or deliberate garbage).
    pub fn write_raw(&mut self, bytes: &[u8]) -> Result<()> {
        self.io.write_all(bytes).context("writing to the device")?;
        self.bytes_out += bytes.len() as u64;
        Ok(())
    }

    pub fn send(&mut self, m: &HostMsg) -> Result<()> {
        let mut b = [0u8; HostMsg::MAX_FRAME];
        let n = m.encode(&mut b).context("encoding a host message")?;
        self.write_raw(&b[..n])
    }

    /// Reads what is there (waiting at most the read timeout) and decodes it.
    fn pump(&mut self) -> Result<()> {
        let n = match self.io.read(&mut self.buf) {
            Ok(0) => bail!("the device closed the link"),
            Ok(n) => n,
            Err(e) if nothing_to_read_yet(&e) => 0,
            Err(e) => return Err(e).context("reading from the device"),
        };
        self.bytes_in += n as u64;
        let at = Instant::now();
        for &b in &self.buf[..n] {
            self.run += 1;
            if let Some(r) = self.rx.push(b) {
                let wire_len = std::mem::take(&mut self.run);
                match r {
                    Ok(msg) => self.pending.push_back(Received { at, msg, wire_len }),
                    Err(e) => self.errors.push(e),
                }
            } else if b == DELIMITER {
                self.run = 0;
            }
        }
        Ok(())
    }

    /// The next message, waiting up to `timeout`.
    pub fn recv(&mut self, timeout: Duration) -> Result<Option<Received>> {
        let end = Instant::now() + timeout;
        loop {
            if let Some(r) = self.pending.pop_front() {
                return Ok(Some(r));
            }
            if Instant::now() >= end {
                return Ok(None);
            }
            self.pump()?;
        }
    }

    /// Messages that are already there (a short poll).
    pub fn poll(&mut self) -> Result<Vec<Received>> {
        self.pump()?;
        Ok(self.pending.drain(..).collect())
    }

    /// Waits for the first message `pick` accepts; others are returned in `skipped`.
    pub fn wait_for<R>(
        &mut self,
        timeout: Duration,
        skipped: &mut Vec<Received>,
        mut pick: impl FnMut(&DeviceMsg) -> Option<R>,
    ) -> Result<Option<(R, Received)>> {
        let end = Instant::now() + timeout;
        while Instant::now() < end {
            if let Some(r) = self.recv(Duration::from_millis(5))? {
                if let Some(x) = pick(&r.msg) {
                    return Ok(Some((x, r)));
                }
                skipped.push(r);
            }
        }
        Ok(None)
    }

    /// The handshake: a lone delimiter (flushes the device's decoder), our hello, the
    /// device's. A device of another protocol version is a clear error.
    pub fn handshake(
        &mut self,
        timeout: Duration,
        skipped: &mut Vec<Received>,
    ) -> Result<DeviceInfo> {
        self.write_raw(&[DELIMITER])?;
        let version = Version {
            major: env!("CARGO_PKG_VERSION_MAJOR").parse().unwrap_or(0),
            minor: env!("CARGO_PKG_VERSION_MINOR").parse().unwrap_or(0),
            patch: env!("CARGO_PKG_VERSION_PATCH").parse().unwrap_or(0),
        };
        self.send(&HostMsg::Hello(HostHello::new("hil", version)))?;
        let end = Instant::now() + timeout;
        while Instant::now() < end {
            if let Some(r) = self.recv(Duration::from_millis(5))? {
                if let DeviceMsg::Hello(info) = r.msg {
                    info.check()
                        .map_err(|e| anyhow::anyhow!("handshake: {e}"))?;
                    return Ok(info);
                }
                skipped.push(r);
            }
            if let Some(ProtocolError::VersionMismatch { ours, theirs }) = self
                .errors
                .iter()
                .find(|e| matches!(e, ProtocolError::VersionMismatch { .. }))
            {
                bail!(
                    "handshake: the device speaks protocol version {theirs}, this host {ours}: \
                     update the firmware or the host so both match"
                );
            }
        }
        bail!("handshake: no Hello from the device within {timeout:?}")
    }

    /// Round trip of a Ping (host clock).
    pub fn ping(
        &mut self,
        seq: u32,
        timeout: Duration,
        skipped: &mut Vec<Received>,
    ) -> Result<Duration> {
        let t0 = Instant::now();
        self.send(&HostMsg::Ping { seq })?;
        match self.wait_for(timeout, skipped, |m| match m {
            DeviceMsg::Pong { seq: s } if *s == seq => Some(()),
            _ => None,
        })? {
            Some(_) => Ok(t0.elapsed()),
            None => bail!("no Pong {seq} within {timeout:?}"),
        }
    }
}

/// Something to do while streaming, when the next pose to send has this index.
// `HostMsg::SetConfig` makes the message ~330 bytes; a schedule holds a handful of actions.
#[allow(clippy::large_enum_variant)]
pub enum Action {
    Send(HostMsg),
    /// Raw bytes (injected garbage).
    Raw(Vec<u8>),
    /// Stop streaming here (the caller cuts the link).
    Stop,
}

/// Streaming options.
pub struct StreamOptions {
    /// Pose `k` of the track is sent with `seq = base + k` (base > 0: a state with
    /// `pose_seq` 0 is one from before any pose).
    pub base: u32,
    /// At most this many poses sent ahead of the last one the device reported consumed
    /// (the protocol allows up to [`maobi_shared::protocol::POSES_IN_FLIGHT`]).
    pub window: u32,
    /// Give up after this long without progress.
    pub stall_timeout: Duration,
    /// Actions at pose indices (before that pose is sent).
    pub actions: BTreeMap<usize, Vec<Action>>,
    /// Guided writing: the guide sample for pose `k` (sent just before it, same `seq`).
    pub guide: Vec<Option<GuideInput<Fx>>>,
}

impl Default for StreamOptions {
    fn default() -> Self {
        StreamOptions {
            base: 1,
            window: 32,
            stall_timeout: Duration::from_secs(20),
            actions: BTreeMap::new(),
            guide: Vec::new(),
        }
    }
}

/// Everything a stream collected.
#[derive(Default)]
pub struct StreamLog {
    /// Every message received, in order.
    pub received: Vec<Received>,
    /// Index of the first pose not sent (the track's length unless stopped).
    pub sent: usize,
    pub started: Option<Instant>,
    pub finished: Option<Instant>,
}

impl StreamLog {
    pub fn states(&self) -> impl Iterator<Item = (&Received, &BrushState)> {
        self.received.iter().filter_map(|r| match &r.msg {
            DeviceMsg::State(s) => Some((r, s)),
            _ => None,
        })
    }
    pub fn events(&self) -> impl Iterator<Item = &Event> {
        self.received.iter().filter_map(|r| match &r.msg {
            DeviceMsg::Event(e) => Some(e),
            _ => None,
        })
    }
    pub fn telemetry(&self) -> impl Iterator<Item = &Telemetry> {
        self.received.iter().filter_map(|r| match &r.msg {
            DeviceMsg::Telemetry(t) => Some(t),
            _ => None,
        })
    }
    pub fn command_results(&self) -> impl Iterator<Item = (&Command, bool)> {
        self.received.iter().filter_map(|r| match &r.msg {
            DeviceMsg::CommandDone { command, result } => Some((command, result.is_ok())),
            _ => None,
        })
    }
}

/// The resampled poses of a track as the device's fixed point, one per tick.
pub fn track_poses(track: &PoseTrack) -> Vec<maobi_shared::Pose<Fx>> {
    track.resample().map(|p| p.cast::<Fx>()).collect()
}

/// Streams `poses` (one per device tick), paced by the `pose_seq` of the device's state
/// frames, and collects everything the device sends until the state after the last pose
/// (or until an [`Action::Stop`]).
pub fn stream<T: Transport>(
    s: &mut Session<T>,
    poses: &[maobi_shared::Pose<Fx>],
    mut opts: StreamOptions,
    log: &mut StreamLog,
) -> Result<()> {
    let n = poses.len();
    let last_seq = opts.base + n as u32 - 1;
    let mut acked: Option<u32> = None;
    let mut next = 0usize;
    let mut progress = Instant::now();
    log.started = Some(Instant::now());
    loop {
        // Send as far as the window allows.
        while next < n {
            let consumed = acked
                .map(|a| a.saturating_sub(opts.base) as i64)
                .unwrap_or(-1);
            if next as i64 - consumed > opts.window as i64 {
                break;
            }
            if let Some(actions) = opts.actions.remove(&next) {
                for a in actions {
                    match a {
                        Action::Send(m) => s.send(&m)?,
                        Action::Raw(b) => s.write_raw(&b)?,
                        Action::Stop => {
                            log.sent = next;
                            log.finished = Some(Instant::now());
                            return Ok(());
                        }
                    }
                }
            }
            let seq = opts.base + next as u32;
            if let Some(Some(g)) = opts.guide.get(next) {
                s.send(&HostMsg::Guide(GuideSample::new(seq, g.anchor, g.on)))?;
            }
            s.send(&HostMsg::Pose(PoseSample::new(
                seq,
                poses[next],
                Buttons::empty(),
            )))?;
            next += 1;
        }
        for r in s.poll()? {
            if let DeviceMsg::State(st) = &r.msg {
                if (opts.base..=last_seq).contains(&st.pose_seq)
                    && acked.is_none_or(|a| st.pose_seq > a)
                {
                    acked = Some(st.pose_seq);
                    progress = Instant::now();
                }
            }
            log.received.push(r);
        }
        if acked == Some(last_seq) {
            log.sent = n;
            log.finished = Some(Instant::now());
            return Ok(());
        }
        if progress.elapsed() > opts.stall_timeout {
            bail!(
                "the device stopped consuming poses: last consumed {:?} of {}..={} after {:?}",
                acked,
                opts.base,
                last_seq,
                opts.stall_timeout
            );
        }
    }
}

/// The host simulation's [`BrushState`] layers at every tick of `poses` (tick 0: at rest at
/// the first pose), as the device computes them.
pub fn simulate(params: BrushParams, poses: &[maobi_shared::Pose<Fx>]) -> Result<Vec<BrushState>> {
    let mut brush = Brush::<Fx>::new(params, poses[0])?;
    let mut out = Vec::with_capacity(poses.len());
    let state =
        |b: &Brush<Fx>| BrushState::from_brush(b, 0, 0, Default::default(), Default::default());
    out.push(state(&brush));
    for p in &poses[1..] {
        brush.tick(*p);
        out.push(state(&brush));
    }
    Ok(out)
}

/// A guide for `poses`: the moving point runs `lead` ticks ahead of the pose and `offset`
/// (mm) beside it, on from the first tick until `on_ticks`, then held at the last point
/// with `on = false` (fading out) for the rest of the poses.
pub fn guide_along(
    poses: &[maobi_shared::Pose<Fx>],
    lead: usize,
    offset: [f64; 3],
    on_ticks: usize,
) -> Vec<Option<GuideInput<Fx>>> {
    let off = Vec3::<Fx>::from_f64(offset);
    let mut last = None;
    (0..poses.len())
        .map(|k| {
            if k < on_ticks {
                let p = poses[(k + lead).min(poses.len() - 1)].pos + off;
                last = Some(p);
                Some(GuideInput {
                    anchor: p,
                    on: true,
                })
            } else {
                last.map(|anchor| GuideInput { anchor, on: false })
            }
        })
        .collect()
}

/// The device's force loop ticks from a stream's first pose on, as its states report them:
/// each tick and the index of the pose it consumed (`None`: a tick without a new pose, the
/// virtual pen's queue was empty). Rebuilt from states with `state_hz=1000`; where states
/// are missing and the ticks between cannot be told apart (some consumed a pose, some not),
/// the timeline ends there.
pub fn device_timeline(log: &StreamLog, base: u32, n: usize) -> Vec<(u32, Option<usize>)> {
    let mut states: Vec<(u32, usize)> = log
        .states()
        .filter_map(|(_, st)| {
            let k = st.pose_seq.checked_sub(base)? as usize;
            (k < n).then_some((st.tick, k))
        })
        .collect();
    states.sort();
    states.dedup_by_key(|(t, _)| *t);
    let mut out = Vec::new();
    let Some(&(t0, 0)) = states.first() else {
        return out;
    };
    out.push((t0, Some(0)));
    let (mut pt, mut pk) = (t0, 0usize);
    for &(t, k) in &states[1..] {
        let dt = t.wrapping_sub(pt) as usize;
        let dk = k.wrapping_sub(pk);
        if dk == dt {
            out.extend((1..=dt).map(|i| (pt + i as u32, Some(pk + i))));
        } else if dk == 0 {
            out.extend((1..=dt).map(|i| (pt + i as u32, None)));
        } else {
            break;
        }
        (pt, pk) = (t, k);
    }
    out
}

/// The device's force on the hand before the output stage (the state's `haptics.force_n`:
/// the force model's plus the guide's) at each tick of `timeline` ([`device_timeline`]), with
/// the guide samples `guide` (by pose index; empty: unguided), as the firmware's force loop
/// computes it, by the same shared [`ForceLoop`]: the first tick places the brush at rest at the first pose and restarts the
/// forces and the guide; a tick with a pose ticks the brush there and hands the guide that
/// pose's sample; a tick without one holds the brush, the hand and the guide's force (the
/// model's filters still tick).
pub fn simulate_forces(
    params: BrushParams,
    poses: &[maobi_shared::Pose<Fx>],
    guide: &[Option<GuideInput<Fx>>],
    timeline: &[(u32, Option<usize>)],
) -> Result<BTreeMap<u32, Vec3Bits>> {
    Ok(mirror_force_loop(params, poses, guide, timeline)?
        .into_iter()
        .map(|(t, m)| (t, m.force_n))
        .collect())
}

/// One tick of [`mirror_force_loop`].
#[derive(Clone, Debug)]
pub struct MirrorTick {
    /// The pose consumed at this tick, if one was.
    pub pose: Option<usize>,
    /// The force before the output stage, as the state's `haptics.force_n`.
    pub force_n: Vec3Bits,
    /// Energy the virtual environment stores after this tick (J): the force model's dragged
    /// mass and spring, the paper's penalty spring, the normal force's filter, the brush's
    /// weight, and the guide's spring (`ForceLoop::stored_energy`, as `maobi-shared`'s
    /// audits count them; the stylus's own kinetic energy is the hand simulation's).
    pub stored_j: f64,
    /// Energy the guide's moving point supplied at this tick (J).
    pub sourced_j: f64,
    /// The guide's distance from the stylus and its fade gain (0 on a tick without a pose).
    pub guide_distance_mm: f64,
    pub guide_gain: f64,
}

/// [`simulate_forces`] with the energies of the passivity audit at each tick.
pub fn mirror_force_loop(
    params: BrushParams,
    poses: &[maobi_shared::Pose<Fx>],
    guide: &[Option<GuideInput<Fx>>],
    timeline: &[(u32, Option<usize>)],
) -> Result<BTreeMap<u32, MirrorTick>> {
    let first = *poses.first().context("no poses")?;
    let mut fl = ForceLoop::<Fx>::new(params, first, DEFAULT_FORCES, PHANTOM_OMNI, DEFAULT_GUIDE)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    // The stream's first pose places the brush at rest, as the device's re-anchor does.
    fl.reanchor();
    // The firmware's gate while the forces drive; the wanted force, the guide and the
    // energies do not depend on it.
    let gate = Gate {
        allowed: true,
        faulted: false,
    };
    let mut out = BTreeMap::new();
    for &(tick, k) in timeline {
        let (pose, sample) = match k {
            Some(k) => {
                let p = poses.get(k).context("a pose index past the stroke")?;
                (Some(*p), guide.get(k).copied().flatten())
            }
            None => (None, None),
        };
        let t = fl.tick(TickIn {
            pose,
            guide: sample,
            gate,
        });
        out.insert(
            tick,
            MirrorTick {
                pose: k,
                force_n: vec3_bits(t.wanted),
                stored_j: fl.stored_energy(),
                sourced_j: t.guide.source_mj.to_f64() * 1e-3,
                guide_distance_mm: t.guide.distance_mm.to_f64(),
                guide_gain: fl.guide().guide().gain().to_f64(),
            },
        );
    }
    Ok(out)
}

/// Guided writing with a simulated hand in the loop ([`guide_hand`]): what was sent and what
/// the hand felt, pose by pose.
#[derive(Default)]
pub struct HandRun {
    /// The stylus's pose sent at each step (the virtual pen).
    pub poses: Vec<maobi_shared::Pose<Fx>>,
    /// The guide sample sent with it.
    pub guide: Vec<Option<GuideInput<Fx>>>,
    /// The device's command (N) the hand felt over the next millisecond: the motors of the
    /// first state that reports the pose consumed (the virtual pen's motors are the force's
    /// components).
    pub felt: Vec<[f64; 3]>,
    /// The energy the hand had put in through the grip, and the stylus's kinetic energy,
    /// when the pose was taken (J).
    pub energy_in: Vec<f64>,
    pub stylus_ke: Vec<f64>,
    pub log: StreamLog,
}

/// Closes the loop through the device, one pose at a time: each step the simulated `hand`
/// moves for 1 ms under the device's last command (and its own `hand_target(step, hand)`:
/// target and push), the stylus's position goes to the device as the pose sample `base +
/// step` with the guide sample `anchors[step]` (the moving point, `on`) just before it, and
/// the device's state for that pose gives the next command. The device ticks on its own
/// clock meanwhile: its ticks without a new pose hold the brush and the guide (pose time).
#[allow(clippy::too_many_arguments)]
pub fn guide_hand<T: Transport>(
    s: &mut Session<T>,
    base: u32,
    anchors: &[(Vec3<Fx>, bool)],
    rot: maobi_shared::Quat<Fx>,
    hand: &mut maobi_shared::hand::SimHand,
    mut hand_target: impl FnMut(usize, &maobi_shared::hand::SimHand) -> ([f64; 3], [f64; 3]),
    step_timeout: Duration,
) -> Result<HandRun> {
    let mut run = HandRun::default();
    let mut cmd = [0.0; 3];
    run.log.started = Some(Instant::now());
    for (k, &(anchor, on)) in anchors.iter().enumerate() {
        let (target, push) = hand_target(k, hand);
        hand.tick_with_push(target, cmd, push);
        let pose = maobi_shared::Pose::new(Vec3::<Fx>::from_f64(hand.stylus()), rot);
        let seq = base.wrapping_add(k as u32);
        s.send(&HostMsg::Guide(GuideSample::new(seq, anchor, on)))?;
        s.send(&HostMsg::Pose(PoseSample::new(seq, pose, Buttons::empty())))?;
        run.poses.push(pose);
        run.guide.push(Some(GuideInput { anchor, on }));
        run.energy_in.push(hand.energy_in());
        run.stylus_ke.push(hand.stylus_kinetic_energy());
        let got = s.wait_for(step_timeout, &mut run.log.received, |m| match m {
            DeviceMsg::State(st) if st.pose_seq.wrapping_sub(base) >= k as u32 => {
                Some(st.haptics.motors.map(|b| Fx::from_bits(b).to_f64()))
            }
            _ => None,
        })?;
        let Some((felt, r)) = got else {
            bail!("no state for pose {k} (seq {seq}) within {step_timeout:?}");
        };
        run.log.received.push(r);
        cmd = felt;
        run.felt.push(felt);
    }
    run.log.sent = anchors.len();
    // The states of the ticks after the last pose, to close the timeline.
    let end = Instant::now() + Duration::from_millis(50);
    while Instant::now() < end {
        run.log.received.extend(s.poll()?);
    }
    run.log.finished = Some(Instant::now());
    Ok(run)
}

/// The comparison of the states' forces with [`simulate_forces`].
#[derive(Debug, Default)]
pub struct ForceComparison {
    /// Device ticks compared (each state of a tick on the timeline).
    pub compared: usize,
    /// Ticks on the timeline without a new pose (simulated as the device ran them).
    pub gaps: usize,
    /// Ticks whose force differed.
    pub mismatches: Vec<u32>,
}

/// Compares the `haptics.force_n` of every received state on the timeline with `forces`,
/// bit for bit.
pub fn compare_forces(log: &StreamLog, forces: &BTreeMap<u32, Vec3Bits>) -> ForceComparison {
    let mut c = ForceComparison::default();
    let mut seen = std::collections::BTreeSet::new();
    for (_, st) in log.states() {
        let Some(want) = forces.get(&st.tick) else {
            continue;
        };
        if !seen.insert(st.tick) {
            continue;
        }
        c.compared += 1;
        if st.haptics.force_n != *want {
            c.mismatches.push(st.tick);
        }
    }
    c
}

/// The comparison of received states with the host simulation.
#[derive(Debug, Default)]
pub struct Comparison {
    /// States whose `pose_seq` fell in the stream.
    pub compared: usize,
    /// Distinct ticks compared.
    pub ticks: usize,
    /// (pose index, what differed) of every mismatch.
    pub mismatches: Vec<(usize, String)>,
}

/// Compares every received state in `[base, base + sim.len())` with the simulation at its
/// tick: handle pose, spine, skeleton, ellipses, contacts, bit for bit.
pub fn compare(log: &StreamLog, base: u32, sim: &[BrushState]) -> Comparison {
    let mut c = Comparison::default();
    let mut seen = std::collections::BTreeSet::new();
    for (_, st) in log.states() {
        let Some(k) = st.pose_seq.checked_sub(base).map(|k| k as usize) else {
            continue;
        };
        let Some(want) = sim.get(k) else { continue };
        c.compared += 1;
        seen.insert(k);
        let what = if st.handle != want.handle {
            Some("handle pose")
        } else if st.layers.len() != want.layers.len() {
            Some("layer count")
        } else if st
            .layers
            .iter()
            .zip(&want.layers)
            .any(|(a, b)| a.spine != b.spine)
        {
            Some("spine")
        } else if st.layers != want.layers {
            Some("skeleton or surface")
        } else if st.contacts != want.contacts {
            Some("contacts")
        } else {
            None
        };
        if let Some(w) = what {
            c.mismatches.push((k, w.to_string()));
        }
    }
    c.ticks = seen.len();
    c
}

/// Figures of a stream.
#[derive(Debug, Default, Clone)]
pub struct Figures {
    pub states: usize,
    pub states_per_s_wall: f64,
    /// Per second of device time (device ticks are 1 ms of model time).
    pub states_per_device_s: f64,
    pub state_bytes_mean: f64,
    pub state_bytes_max: usize,
    /// Share of a 1 MB/s USB full-speed CDC link at 120 states per second.
    pub link_share_at_120hz: f64,
}

pub fn figures(log: &StreamLog) -> Figures {
    let states: Vec<_> = log.states().collect();
    let mut f = Figures {
        states: states.len(),
        ..Default::default()
    };
    if states.is_empty() {
        return f;
    }
    let bytes: usize = states.iter().map(|(r, _)| r.wire_len).sum();
    f.state_bytes_mean = bytes as f64 / states.len() as f64;
    f.state_bytes_max = states.iter().map(|(r, _)| r.wire_len).max().unwrap_or(0);
    if let (Some(a), Some(b)) = (log.started, log.finished) {
        f.states_per_s_wall = states.len() as f64 / (b - a).as_secs_f64().max(1e-9);
    }
    let t0 = states.first().map(|(_, s)| s.tick).unwrap_or(0);
    let t1 = states.last().map(|(_, s)| s.tick).unwrap_or(0);
    if t1 > t0 {
        f.states_per_device_s = (states.len() - 1) as f64 * 1000.0 / (t1 - t0) as f64;
    }
    f.link_share_at_120hz = f.state_bytes_mean * 120.0 / 1.0e6;
    f
}

/// The event kinds received, in order (for reports).
pub fn event_kinds(log: &StreamLog) -> Vec<&EventKind> {
    log.events().map(|e| &e.kind).collect()
}
