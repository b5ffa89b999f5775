//! A simulated hand holding the stylus, for tests of the force loop (here, in the firmware
//! and in the Phantom bridge): shared test support, `no_std`, `f64`.
//!
//! Two masses per axis. The *hand* (arm and hand, `hand_mass_kg`) is pulled toward a scripted
//! target by a muscle spring-damper; it holds the *stylus* (the device's apparent mass at the
//! tip, `device_mass_kg`, with the device's physical damping to ground) through a grip
//! spring-damper. The device's commanded force acts on the stylus and is held constant over
//! each 1 ms tick (zero-order hold), while the masses are integrated at `substeps` per tick.
//!
//! The energy the hand puts into the device through the grip, `integral(F_grip . v_stylus)`,
//! is metered at every substep: the passivity audit compares it with the energy the device and
//! its virtual environment store.

/// Mechanical parameters of the hand and the device.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct HandParams {
    pub hand_mass_kg: f64,
    /// Muscle spring toward the target (N/m) and damper (N s/m).
    pub muscle_stiffness: f64,
    pub muscle_damping: f64,
    /// Grip spring-damper between the hand and the stylus.
    pub grip_stiffness: f64,
    pub grip_damping: f64,
    /// The device's apparent mass at the tip (kg; the Phantom Omni's is 45 g).
    pub device_mass_kg: f64,
    /// The device's physical damping to ground (N s/m).
    pub device_damping: f64,
    /// Integration steps per 1 ms tick.
    pub substeps: u32,
}

impl HandParams {
    /// A writer's hand: firm enough to follow a stroke, soft enough to be pushed back.
    pub const WRITER: HandParams = HandParams {
        hand_mass_kg: 0.4,
        muscle_stiffness: 200.0,
        muscle_damping: 6.0,
        grip_stiffness: 800.0,
        grip_damping: 2.0,
        device_mass_kg: 0.045,
        device_damping: 1.0,
        substeps: 10,
    };
    /// A relaxed hand that lets the device lead it (for guidance tests).
    pub const RELAXED: HandParams = HandParams {
        muscle_stiffness: 5.0,
        muscle_damping: 1.5,
        ..HandParams::WRITER
    };
}

/// The hand and stylus state (positions in mm, velocities in m/s).
#[derive(Clone, Debug)]
pub struct SimHand {
    p: HandParams,
    hand: [f64; 3],
    hand_v: [f64; 3],
    stylus: [f64; 3],
    stylus_v: [f64; 3],
    /// Energy the hand has put into the device through the grip (J).
    energy_in: f64,
}

impl SimHand {
    /// Hand and stylus together at `at` (mm), at rest.
    pub fn new(p: HandParams, at: [f64; 3]) -> Self {
        SimHand {
            p,
            hand: at,
            hand_v: [0.0; 3],
            stylus: at,
            stylus_v: [0.0; 3],
            energy_in: 0.0,
        }
    }

    pub fn params(&self) -> &HandParams {
        &self.p
    }
    pub fn stylus(&self) -> [f64; 3] {
        self.stylus
    }
    pub fn stylus_velocity(&self) -> [f64; 3] {
        self.stylus_v
    }
    pub fn hand(&self) -> [f64; 3] {
        self.hand
    }
    /// Energy the hand has put into the device so far (J); falls when the device pushes the
    /// hand around.
    pub fn energy_in(&self) -> f64 {
        self.energy_in
    }
    /// Kinetic energy of the stylus (J): energy the device stores in its own mass.
    pub fn stylus_kinetic_energy(&self) -> f64 {
        let v = self.stylus_v;
        0.5 * self.p.device_mass_kg * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    }

    /// Advances one 1 ms tick with the hand's target at `target` (mm) and the device's force
    /// `device_force` (N) held for the whole tick.
    pub fn tick(&mut self, target: [f64; 3], device_force: [f64; 3]) {
        self.tick_with_push(target, device_force, [0.0; 3]);
    }

    /// As [`SimHand::tick`], with an extra external push on the hand (N), e.g. a bump.
    pub fn tick_with_push(&mut self, target: [f64; 3], device_force: [f64; 3], push: [f64; 3]) {
        let n = self.p.substeps.max(1);
        let dt = 1e-3 / n as f64;
        for _ in 0..n {
            for a in 0..3 {
                // Positions in mm, forces from metres.
                let grip = self.p.grip_stiffness * (self.hand[a] - self.stylus[a]) * 1e-3
                    + self.p.grip_damping * (self.hand_v[a] - self.stylus_v[a]);
                let muscle = self.p.muscle_stiffness * (target[a] - self.hand[a]) * 1e-3
                    - self.p.muscle_damping * self.hand_v[a];
                let hand_f = muscle - grip + push[a];
                let stylus_f = grip + device_force[a] - self.p.device_damping * self.stylus_v[a];
                // Semi-implicit Euler.
                self.hand_v[a] += hand_f / self.p.hand_mass_kg * dt;
                let v_before = self.stylus_v[a];
                self.stylus_v[a] += stylus_f / self.p.device_mass_kg * dt;
                // Port power with the step's mean stylus velocity.
                self.energy_in += grip * 0.5 * (v_before + self.stylus_v[a]) * dt;
                self.hand[a] += self.hand_v[a] * dt * 1e3;
                self.stylus[a] += self.stylus_v[a] * dt * 1e3;
            }
        }
    }
}

/// A deterministic random script of presses, drags, lifts and pushes for a hand, written by a
/// tiny xorshift generator so that every run (and every target) gets the same motions.
#[derive(Clone, Debug)]
pub struct Script {
    state: u64,
    from: [f64; 3],
    to: [f64; 3],
    t: f64,
    leg_s: f64,
    push: [f64; 3],
    push_left: u32,
    /// Heights the target moves between (mm): above the paper, pressed, and into it.
    pub z_range: (f64, f64),
    /// Half-width of the square the target wanders in (mm).
    pub xy_range: f64,
}

impl Script {
    pub fn new(seed: u64, start: [f64; 3], z_range: (f64, f64)) -> Self {
        let mut s = Script {
            state: seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1,
            from: start,
            to: start,
            t: 0.0,
            leg_s: 0.0,
            push: [0.0; 3],
            push_left: 0,
            z_range,
            xy_range: 40.0,
        };
        s.next_leg();
        s
    }

    fn rand(&mut self) -> f64 {
        let mut x = self.state;
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        self.state = x;
        (x >> 11) as f64 / (1u64 << 53) as f64
    }

    fn next_leg(&mut self) {
        self.from = self.to;
        let (z0, z1) = self.z_range;
        let kind = self.rand();
        let r = self.xy_range;
        self.to = if kind < 0.3 {
            // Press or lift in place.
            [self.from[0], self.from[1], z0 + (z1 - z0) * self.rand()]
        } else if kind < 0.8 {
            // Drag along the paper at the current height, with a little change of depth.
            let dz = (self.rand() - 0.5) * 0.2 * (z1 - z0);
            [
                (self.rand() * 2.0 - 1.0) * r,
                (self.rand() * 2.0 - 1.0) * r,
                (self.from[2] + dz).clamp(z0, z1),
            ]
        } else {
            // Anywhere.
            [
                (self.rand() * 2.0 - 1.0) * r,
                (self.rand() * 2.0 - 1.0) * r,
                z0 + (z1 - z0) * self.rand(),
            ]
        };
        self.leg_s = 0.05 + 0.5 * self.rand();
        self.t = 0.0;
        if self.rand() < 0.2 {
            // A bump on the hand for 10-40 ms.
            self.push = [
                (self.rand() - 0.5) * 4.0,
                (self.rand() - 0.5) * 4.0,
                (self.rand() - 0.5) * 4.0,
            ];
            self.push_left = 10 + (self.rand() * 30.0) as u32;
        }
    }

    /// The target and the push for the next 1 ms tick.
    pub fn tick(&mut self) -> ([f64; 3], [f64; 3]) {
        self.t += 1e-3;
        if self.t >= self.leg_s {
            self.next_leg();
        }
        // Smoothstep between waypoints.
        let u = (self.t / self.leg_s).clamp(0.0, 1.0);
        let s = u * u * (3.0 - 2.0 * u);
        let target = [0, 1, 2].map(|a| self.from[a] + (self.to[a] - self.from[a]) * s);
        let push = if self.push_left > 0 {
            self.push_left -= 1;
            self.push
        } else {
            [0.0; 3]
        };
        (target, push)
    }
}
