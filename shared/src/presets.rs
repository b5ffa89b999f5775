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
//!   spine and the virtual skeleton, so the tie stiffness sets it: with 2.05 N/m dry (12
//!   layers), 82% of it
//!   at the presets' starting load (wetness 0.6, the ink's law in `crate::brush::ink`), a
//!   load of 1 N across the large brush's tip bends its ferrule-to-tip chord by about 75
//!   degrees and 2 N by about 82 (test `large_brush_bends_nearly_flat_under_one_to_two_newtons`
//!   in `tests/model.rs`). Dry, the tie's damping is about half of critical.
//! * Ink in the ties: a saturated layer's tie has [`TIE_STIFFNESS_WET_PCT`] of the dry
//!   stiffness and [`TIE_DAMPING_WET_PCT`] of the dry damping, linear in the wetness between.
//! * Axial springs: hair barely stretches; k_s is set stiff (h^2 k_s / m = 0.03 at 25 kHz, 16
//!   at the presets' one substep per 1 ms tick, which the backward-Euler step takes in its
//!   stride) while staying well inside the solver's range.
//! * Neighbour damping: the thesis's damper (eq. 2.27) acts on the whole relative velocity, so
//!   it also resists bending. Its integrator added a step-dependent damping of `h k_s` between
//!   neighbours on top (0.08 N s/m at its 25 kHz); the backward-Euler step adds none, so the
//!   brush's feel is a real damper: k_d = 0.044 N s/m on the large brush brings it back from
//!   a 10 mm press to within 0.1 mm in 200 ms (the spring-back between the thesis's at 25 kHz
//!   and the undamped spine's), and with this much damping one substep per tick gives the
//!   converged brush within 5% (`tests/convergence.rs`).
//! * Layers: 12. The springs are those of the same continuous hair at 16 layers rescaled to
//!   the count (axial stiffness and damping x 11/15; ties, their damping and the paper's drag
//!   x 15/11): it bends as it did and springs back faster (docs/firmware-cost.md).
//! * Compression: 0.1% of the stretch stiffness. Hair buckles under compression; with this
//!   ratio (0.1%) the large brush pressed 10 mm straight down lays three layers on the paper
//!   instead of standing on its tip like a column (2% left only the tip touching).
//! * Surface: TF, SDF and RL_max from Liang 2009 3.2; with a wet brush (W = 1) the surface
//!   does not spread (eq. 3-17), a drier one splays up to RL_max.
//!
//! # The hair types: 狼毫 ([`WOLF`]), 羊毫 ([`GOAT`]), 兼毫 ([`MIXED`])
//!
//! The three hairs a calligrapher picks between, each as a head of the large brush's size
//! (大楷, 40 mm by 12 mm, 1 g wet), so that they compare with `large` and with each other at
//! the same geometry and only what the hair changes differs: the ties' stiffness and damping,
//! the neighbour damping, the ink a layer holds and the load a dip leaves. The mass stays
//! the large brush's 1 g for all three: the model's mass does not follow the ink (a goat
//! head carrying more of it would be a little heavier).
//!
//! * What the hairs are: 狼毫 is in fact the tail hair of the Siberian weasel (黄鼠狼),
//!   stiff, straight and springy; 羊毫 is goat hair, fine, soft, kinked and absorbent; 兼毫
//!   mixes the two (or rabbit and goat), commonly in proportions of 7:3, 5:5 or 3:7, for a
//!   brush between them (brush makers' and calligraphy guides, e.g. the Molecular Expressions
//!   gallery's "Chinese goat hair fibers" and China-tour notes on writing brushes; Saitzyk,
//!   *Art Hardware*, 1987, names absorbency and spring as the two properties that tell hairs
//!   apart; USDA Circular 802, Hardy & Hardy 1949, *Animal fibers used in brushes*, ties a
//!   soft-hair brush's spring to its hairs' taper).
//! * Stiffness: a hair bends with E I, I = pi d^4 / 64, and keratin's modulus is about the
//!   same across these animals (a few GPa), so the hair's diameter and taper set it: a head
//!   of given size holds about (D / d)^2 hairs, so its bending stiffness goes as d^2, and the
//!   coarse, strongly tapered weasel hair makes a stiffer head than fine goat hair. No
//!   measured stiffness per hair type was found; the ties are set to keep the calligrapher's
//!   order (goat bends most under the same push, wolf least) inside Baxter & Lin's 70 to 90
//!   degrees under 1-2 N: wolf 2.59 N/m, mixed 2.18, goat 1.5 (large: 2.05). Under 1 N the
//!   chord bends 70, 74 and 79 degrees (`tests/hair.rs`); goat hair is the one that bends
//!   more than 50 degrees under a light 0.25 N (54.5).
//! * Spring and damping: weasel hair is straight and springs back; goat hair's kink and
//!   scales rub between the hairs and hold more ink between them, which damps. Tie damping
//!   0.0109, 0.015 and 0.0191 N s/m, neighbour damping 0.0367, 0.0477 and 0.049: dry, a wolf
//!   tie is damped at about a third of critical, mixed at a half (as large), goat at four
//!   fifths, and a saturated goat tie (150%) beyond critical, so goat hair creeps back where
//!   wolf hair springs. Goat's creep comes from its ties; its neighbour damping, which
//!   resists the whole bend's return, is held just above mixed's, so that goat too is back
//!   within a tenth of a millimetre 200 ms after a 10 mm press, as every preset is
//!   (`tests/model.rs`; `tests/hair.rs` keeps wolf quickest back and goat slowest at every
//!   reading; the figures are in docs/figures.md).
//! * Substeps: the springier wolf hair has faster modes, and at one substep per tick the
//!   backward-Euler step's own damping slows its spring-back beyond the 10% that
//!   `tests/convergence.rs` holds the presets to; [`WOLF`] takes two substeps per tick. A
//!   board that sets its own substep rate (a pen: one) runs it at that, and the test holds
//!   wolf at one substep to its own, wider bound (docs/figures.md has the figures).
//! * Ink: hair holds ink by capillarity on its surface, which per volume of hair goes as
//!   1 / d, and goat hair's scales hold more (Saitzyk): [`GOAT`] holds 0.55 units per mm^3,
//!   [`MIXED`] 0.42, [`WOLF`] 0.3 (large: 0.4), and a dip leaves the absorbent goat head
//!   fuller (wetness 0.75, mixed 0.6, wolf 0.5). The same 400 mm stroke without dipping
//!   stays darker than half its start for 225 mm with wolf hair, 325 mm with mixed, 375 mm
//!   with goat (`host/tests/paper.rs`).
//! * Mixed is the half-and-half 兼毫 with its stiffer hair at the core, which carries the
//!   bend: its ties a little stiffer than the midpoint, the rest near the midpoint.

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
    layers: 12,
    ring_nodes: 16,
    length_mm: 40.0,
    radius_mm: 6.0,
    tip_radius_mm: 0.15,
    belly: 0.5,
    mass_g: 1.0,
    axial_stiffness: 1470.0,
    axial_damping: 0.044,
    compression_ratio: 0.001,
    tie_stiffness: 2.05,
    tie_damping: 0.0136,
    paper_drag: 0.068,
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

/// 狼毫 (wolf hair, in fact the tail hair of the Siberian weasel): a stiff, springy head of
/// the large brush's size (大楷, 40 mm) that holds less ink, at two substeps per tick (see the
/// module's notes on the hair types).
pub const WOLF: BrushParams = BrushParams {
    substeps_per_tick: 2,
    axial_damping: 0.0367,
    tie_stiffness: 2.59,
    tie_damping: 0.0109,
    wetness: 0.5,
    ink_capacity: 0.3,
    ..LARGE
};

/// 羊毫 (goat hair): a soft, slow head of the large brush's size (大楷, 40 mm) that holds much
/// ink (see the module's notes on the hair types).
pub const GOAT: BrushParams = BrushParams {
    axial_damping: 0.049,
    tie_stiffness: 1.5,
    tie_damping: 0.0191,
    wetness: 0.75,
    ink_capacity: 0.55,
    ..LARGE
};

/// 兼毫 (mixed hair): wolf and goat hair half and half, a head of the large brush's size (大楷,
/// 40 mm) between the two (see the module's notes on the hair types).
pub const MIXED: BrushParams = BrushParams {
    axial_damping: 0.0477,
    tie_stiffness: 2.18,
    tie_damping: 0.015,
    wetness: 0.6,
    ink_capacity: 0.42,
    ..LARGE
};

/// Presets by the names the CLI and the protocol use; the protocol's preset index is the
/// position here, so new presets go at the end.
pub const PRESETS: [(&str, &BrushParams); 5] = [
    ("large", &LARGE),
    ("small", &SMALL),
    ("wolf", &WOLF),
    ("goat", &GOAT),
    ("mixed", &MIXED),
];

/// Each preset's other names, in the order of [`PRESETS`]: its pinyin and its Chinese name.
const ALIASES: [[&str; 2]; PRESETS.len()] = [
    ["dakai", "大楷"],
    ["xiaokai", "小楷"],
    ["langhao", "狼毫"],
    ["yanghao", "羊毫"],
    ["jianhao", "兼毫"],
];

/// The preset called `name`: its name in [`PRESETS`], its pinyin or its Chinese name.
pub fn by_name(name: &str) -> Option<BrushParams> {
    PRESETS
        .iter()
        .zip(ALIASES)
        .find(|((own, _), aliases)| *own == name || aliases.contains(&name))
        .map(|((_, params), _)| **params)
}

/// Names for error messages and `--help`.
pub const NAMES: &str = "large (大楷), small (小楷), wolf (狼毫), goat (羊毫), mixed (兼毫)";

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
    fn every_preset_answers_to_its_pinyin_and_chinese_name_and_is_listed() {
        extern crate std;
        use std::format;
        for ((name, params), aliases) in PRESETS.iter().zip(ALIASES) {
            for alias in aliases {
                assert_eq!(by_name(alias), Some(**params), "{alias}");
            }
            let listed = format!("{name} ({})", aliases[1]);
            assert!(NAMES.contains(&listed), "{listed} not in {NAMES}");
        }
        assert_eq!(by_name("羊毫"), Some(GOAT));
        assert_eq!(by_name("langhao"), Some(WOLF));
        assert_eq!(by_name("兼毫"), Some(MIXED));
        assert_eq!(by_name("Wolf"), None);
    }

    #[test]
    fn an_unknown_preset_names_the_valid_ones() {
        extern crate std;
        use std::string::ToString;
        assert_eq!(
            UnknownPreset("huge").to_string(),
            "unknown brush `huge`; valid brushes: large (大楷), small (小楷), wolf (狼毫), goat (羊毫), \
             mixed (兼毫)"
        );
    }
}
