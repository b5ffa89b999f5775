//! Brush presets with physically plausible parameters.
//!
//! Sources for the numbers:
//! * Head sizes: a large regular-script brush (大楷) has a head about 40 mm long and 12 mm
//!   across at the ferrule; a small regular-script brush (小楷) about 18 mm by 5 mm (the sizes
//!   named in the Maobi issue tracker, matching common brush-maker catalogues).
//! * Mass: a cone of wet hair, volume pi r^2 L / 3 (1.5 cm^3 for the large brush), packed about
//!   two-thirds full with hair and ink of density about 1 g/cm^3: about 1 g; 0.08 g for the
//!   small brush.
//! * Bending stiffness: Baxter & Lin 2004 section 5 report that 1-2 N of normal force bends a
//!   brush nearly 90 degrees. Bending stiffness in this model comes from the ties between the
//!   spine and the virtual skeleton, so the tie stiffness sets it: with 1.5 N/m dry, 82% of it
//!   at the presets' starting load (wetness 0.6, the ink's law in `crate::brush::ink`), a
//!   load of 1 N across the large brush's tip bends its ferrule-to-tip chord by about 75
//!   degrees and 2 N by about 82 (test `large_brush_bends_nearly_flat_under_one_to_two_newtons`
//!   in `tests/model.rs`). Dry, the tie's damping is about half of critical.
//! * Ink in the ties: a saturated layer's tie has [`TIE_STIFFNESS_WET_PCT`] of the dry
//!   stiffness and [`TIE_DAMPING_WET_PCT`] of the dry damping, linear in the wetness between.
//! * Axial springs: hair barely stretches; k_s is set stiff (h^2 k_s / m = 0.05 at 25 kHz, 30
//!   at the presets' one substep per 1 ms tick, which the backward-Euler step takes in its
//!   stride) while staying well inside the solver's range.
//! * Neighbour damping: the thesis's damper (eq. 2.27) acts on the whole relative velocity, so
//!   it also resists bending. Its integrator added a step-dependent damping of `h k_s` between
//!   neighbours on top (0.08 N s/m at its 25 kHz); the backward-Euler step adds none, so the
//!   brush's feel is a real damper: k_d = 0.06 N s/m on the large brush brings it back from a
//!   10 mm press to within 0.1 mm in 200 ms (the spring-back between the thesis's at 25 kHz
//!   and the undamped spine's), and with this much damping one substep per tick gives the
//!   converged brush within 10% (`tests/convergence.rs`).
//! * Compression: 0.1% of the stretch stiffness. Hair buckles under compression; with this
//!   ratio (0.1%) the large brush pressed 10 mm straight down lays four layers on the paper
//!   instead of standing on its tip like a column (2% left only the tip touching).
//! * Surface: TF, SDF and RL_max from Liang 2009 3.2; with a wet brush (W = 1) the surface
//!   does not spread (eq. 3-17), a drier one splays up to RL_max.

use core::fmt;

use crate::params::{BrushParams, DEFAULT_INTEGRATOR};

/// The presets' tie stiffness of a saturated layer in percent of the dry's (see
/// `crate::brush::ink`): wet keratin's modulus is a half to a third of dry keratin's, but a
/// layer that has given its ink is still damp, so the step from a saturated to an emptied
/// layer is taken as the smaller 30%.
pub const TIE_STIFFNESS_WET_PCT: u8 = 70;

/// The presets' tie damping of a saturated layer in percent of the dry's: the ink's
/// viscosity between the hairs. Half as much again keeps the saturated large brush's tie
/// below critical damping (the dry tie is about half of critical).
pub const TIE_DAMPING_WET_PCT: u8 = 150;

/// 大楷: large regular-script brush.
pub const LARGE: BrushParams = BrushParams {
    layers: 16,
    ring_nodes: 16,
    length_mm: 40.0,
    radius_mm: 6.0,
    tip_radius_mm: 0.15,
    belly: 0.5,
    mass_g: 1.0,
    axial_stiffness: 2000.0,
    axial_damping: 0.06,
    compression_ratio: 0.001,
    tie_stiffness: 1.5,
    tie_damping: 0.01,
    paper_drag: 0.05,
    plasticity: 0.0,
    jacobi_iterations: 4,
    substeps_per_tick: 1,
    spread_tf: 0.6,
    spread_rate: 0.0005,
    spread_max: 1.8,
    wetness: 0.6,
    footprint_eps_mm: 0.1,
    integrator: DEFAULT_INTEGRATOR,
    ink_capacity: 0.4,
    tie_stiffness_wet_pct: TIE_STIFFNESS_WET_PCT,
    tie_damping_wet_pct: TIE_DAMPING_WET_PCT,
};

/// 小楷: small regular-script brush.
pub const SMALL: BrushParams = BrushParams {
    layers: 12,
    ring_nodes: 16,
    length_mm: 18.0,
    radius_mm: 2.5,
    tip_radius_mm: 0.08,
    belly: 0.4,
    mass_g: 0.08,
    axial_stiffness: 400.0,
    axial_damping: 0.003,
    compression_ratio: 0.001,
    tie_stiffness: 1.0,
    tie_damping: 0.003,
    paper_drag: 0.008,
    plasticity: 0.0,
    jacobi_iterations: 4,
    substeps_per_tick: 1,
    spread_tf: 0.6,
    spread_rate: 0.0005,
    spread_max: 1.8,
    wetness: 0.6,
    footprint_eps_mm: 0.05,
    integrator: DEFAULT_INTEGRATOR,
    ink_capacity: 0.4,
    tie_stiffness_wet_pct: TIE_STIFFNESS_WET_PCT,
    tie_damping_wet_pct: TIE_DAMPING_WET_PCT,
};

/// Presets by the names the CLI and the protocol use.
pub const PRESETS: [(&str, &BrushParams); 2] = [("large", &LARGE), ("small", &SMALL)];

/// The preset called `name` (also accepts `dakai` / `xiaokai` and the Chinese names).
pub fn by_name(name: &str) -> Option<BrushParams> {
    match name {
        "large" | "dakai" | "大楷" => Some(LARGE),
        "small" | "xiaokai" | "小楷" => Some(SMALL),
        _ => None,
    }
}

/// Names for error messages and `--help`.
pub const NAMES: &str = "large (大楷), small (小楷)";

/// The preset called `name`, or the error that says which names are valid.
pub fn find(name: &str) -> Result<BrushParams, UnknownPreset<'_>> {
    by_name(name).ok_or(UnknownPreset(name))
}

/// A brush name that is no preset (it displays the valid names).
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct UnknownPreset<'a>(pub &'a str);

impl fmt::Display for UnknownPreset<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "unknown brush `{}`; valid brushes: {NAMES}", self.0)
    }
}

impl core::error::Error for UnknownPreset<'_> {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_are_valid() {
        for (name, p) in PRESETS {
            p.validate().unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(by_name(name), Some(*p));
        }
        assert_eq!(by_name("huge"), None);
        assert_eq!(find("huge"), Err(UnknownPreset("huge")));
    }

    #[test]
    fn an_unknown_preset_names_the_valid_ones() {
        extern crate std;
        use std::string::ToString;
        assert_eq!(
            UnknownPreset("huge").to_string(),
            "unknown brush `huge`; valid brushes: large (大楷), small (小楷)"
        );
    }
}
