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
//!   brush nearly 90 degrees. The tie springs are chosen so the large brush pressed at a 45
//!   degree slant until its tip lies flat pushes back with a force in that range (test
//!   `large_brush_bends_flat_under_newtons` in `tests/model.rs`).
//! * Axial springs: hair barely stretches; k_s is set stiff (h^2 k_s / m = 0.05 at 25 kHz)
//!   while staying well inside the solver's range, and damped at about a fifth of critical.
//! * Surface: TF, SDF and RL_max from Liang 2009 3.2; with a wet brush (W = 1) the surface
//!   does not spread (eq. 3-17), a drier one splays up to RL_max.

use crate::params::BrushParams;

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
    axial_damping: 0.1,
    tie_stiffness: 30.0,
    tie_damping: 0.03,
    paper_drag: 0.05,
    plasticity: 0.0,
    jacobi_iterations: 4,
    substeps_per_tick: 25,
    spread_tf: 0.6,
    spread_rate: 0.0005,
    spread_max: 1.8,
    wetness: 0.6,
    footprint_eps_mm: 0.1,
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
    axial_damping: 0.01,
    tie_stiffness: 8.0,
    tie_damping: 0.004,
    paper_drag: 0.008,
    plasticity: 0.0,
    jacobi_iterations: 4,
    substeps_per_tick: 25,
    spread_tf: 0.6,
    spread_rate: 0.0005,
    spread_max: 1.8,
    wetness: 0.6,
    footprint_eps_mm: 0.05,
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_are_valid() {
        for (name, p) in PRESETS {
            p.validate().unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(by_name(name), Some(**p));
        }
        assert_eq!(by_name("huge"), None);
    }
}
