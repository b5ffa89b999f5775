//! The brush models a host-side simulator runs, and a brush chosen by name for one.
//!
//! * [`ModelKind`], the model: `liang` (Liang's mass-spring brush, the pen's, in the pen's
//!   fixed point) or `baxter-lin` (Baxter & Lin's energy-minimising spines, `f64`, desktop
//!   only).
//! * [`BrushChoice`], a brush by name: one of Liang's presets, or one of Baxter & Lin's
//!   other heads (`flat`, `filbert`, `fan`), which only their model has.
//!
//! The chosen model in its 1 kHz loop is [`super::sim_model::SimModel`].

use maobi_shared::baxter_lin::brush::BaxterLinBrush;
use maobi_shared::baxter_lin::head::HeadShape;
use maobi_shared::{presets, BrushParams, ParamId, Pose, Quat, Vec3};

/// The brush model a command or a device runs.
#[derive(
    Copy,
    Clone,
    Debug,
    Default,
    PartialEq,
    Eq,
    clap::ValueEnum,
    serde::Serialize,
    serde::Deserialize,
)]
#[serde(rename_all = "kebab-case")]
pub enum ModelKind {
    /// Liang's mass-spring spine, skeleton and surface: the pen's model.
    #[default]
    Liang,
    /// Baxter & Lin's energy-minimising spines (desktop only, `f64`).
    BaxterLin,
}

impl ModelKind {
    pub const ALL: [ModelKind; 2] = [ModelKind::Liang, ModelKind::BaxterLin];

    /// The name the command line and the session file spell.
    pub fn name(self) -> &'static str {
        match self {
            ModelKind::Liang => "liang",
            ModelKind::BaxterLin => "baxter-lin",
        }
    }

    /// The model called `name`, or an error listing the names.
    pub fn from_name(name: &str) -> Result<ModelKind, String> {
        ModelKind::ALL
            .into_iter()
            .find(|m| m.name() == name)
            .ok_or_else(|| format!("unknown brush model `{name}`; the models: liang, baxter-lin"))
    }

    /// What a device that runs only Liang's model (a pen, `maobi bridge`) says to a
    /// choice of this model: nothing to do, or why not.
    pub fn on_liang_only_device(self, device: &str) -> Result<(), String> {
        match self {
            ModelKind::Liang => Ok(()),
            ModelKind::BaxterLin => Err(format!(
                "{device} runs Liang's model; Baxter & Lin's runs in the built-in simulator \
                 and on the Phantom (and `maobi render`/`trace --model baxter-lin`)"
            )),
        }
    }

    /// How the app's model choice shows it.
    pub fn label(self) -> &'static str {
        match self {
            ModelKind::Liang => "Liang (mass-spring)",
            ModelKind::BaxterLin => "Baxter & Lin (spines)",
        }
    }
}

impl std::fmt::Display for ModelKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A brush chosen by name: a preset, or one of Baxter & Lin's head shapes.
#[derive(Clone, Debug, PartialEq)]
pub struct BrushChoice {
    pub name: String,
    /// The preset's parameters; for a Baxter & Lin shape, the `large` preset's (its ink and
    /// footprint threshold).
    pub params: BrushParams,
    /// A Baxter & Lin head shape other than round (`flat`, `filbert`, `fan`): only
    /// `baxter-lin` has them.
    pub shape: Option<HeadShape>,
}

/// Baxter & Lin's heads that are no preset, for error messages and menus.
pub const HEAD_NAMES: [&str; 3] = ["flat", "filbert", "fan"];

impl BrushChoice {
    /// The brush called `name`, for either model; an unknown name is an error listing the
    /// presets and the heads.
    pub fn parse(name: &str) -> Result<BrushChoice, String> {
        if let Some(params) = presets::by_name(name) {
            return Ok(BrushChoice {
                name: name.to_string(),
                params,
                shape: None,
            });
        }
        match HeadShape::from_name(name) {
            Ok(shape) if shape != HeadShape::Round => Ok(BrushChoice {
                name: name.to_string(),
                params: presets::LARGE,
                shape: Some(shape),
            }),
            _ => Err(format!(
                "{}; with Baxter & Lin's model also {}",
                presets::UnknownPreset(name),
                HEAD_NAMES.join(", ")
            )),
        }
    }

    /// The brush called `name` for `model`: a Baxter & Lin head under Liang's model is an
    /// error that says which model has it.
    pub fn for_model(name: &str, model: ModelKind) -> Result<BrushChoice, String> {
        let choice = BrushChoice::parse(name)?;
        if let (Some(shape), ModelKind::Liang) = (choice.shape, model) {
            return Err(format!(
                "the {} brush is Baxter & Lin's: their model (baxter-lin) draws it",
                shape.name()
            ));
        }
        Ok(choice)
    }

    /// The parameters of Liang's brush called `name` (a preset): what a device that runs
    /// only Liang's model (a pen, `maobi bridge` over TCP) takes; a Baxter & Lin head or an
    /// unknown name is refused with the names.
    pub fn liang_params(name: &str) -> Result<BrushParams, String> {
        BrushChoice::for_model(name, ModelKind::Liang).map(|b| b.params)
    }

    /// Baxter & Lin's head for this brush (a preset is a round head of its profile).
    pub fn head_shape(&self) -> HeadShape {
        self.shape.unwrap_or(HeadShape::Round)
    }

    /// How long this brush's hair is (mm) under `model` with `params`: Liang's brush its
    /// length; Baxter & Lin's head its longest spine, or the preset's length if it does not
    /// build.
    pub fn hair_length_mm(&self, model: ModelKind, params: &BrushParams) -> f64 {
        let length = params.length_mm as f64;
        match model {
            ModelKind::Liang => length,
            ModelKind::BaxterLin => {
                let above = Pose::new(Vec3::new(0.0, 0.0, 2.0 * length + 10.0), Quat::IDENTITY);
                BaxterLinBrush::of_shape(self.head_shape(), params, above)
                    .map_or(length, |b| b.head().length_mm())
            }
        }
    }

    /// Checks that Baxter & Lin's brush of this head builds with `params` (its spines'
    /// springs, scaled by the hair's stiffness, must stay in their range): what the built-in
    /// simulator and the Phantom's solver would refuse is refused before it is sent.
    pub fn baxter_lin_builds(&self, params: &BrushParams) -> Result<(), String> {
        let above = Pose::new(
            Vec3::new(0.0, 0.0, 2.0 * params.length_mm as f64 + 10.0),
            Quat::IDENTITY,
        );
        BaxterLinBrush::of_shape(self.head_shape(), params, above)
            .map(|_| ())
            .map_err(|e| format!("Baxter & Lin's {} brush: {e}", self.head_shape().name()))
    }

    /// Checks that Baxter & Lin's brush of this head reads parameter `id`
    /// ([`BaxterLinBrush::preset_params`]): one it does not is refused, not ignored.
    pub fn baxter_lin_reads(&self, id: ParamId) -> Result<(), String> {
        let shape = self.head_shape();
        let reads = BaxterLinBrush::preset_params(shape);
        if reads.contains(&id) {
            return Ok(());
        }
        let names: Vec<&str> = reads.iter().map(|id| id.name()).collect();
        Err(format!(
            "Baxter & Lin's {} brush does not have {} (of the parameters it reads only {})",
            shape.name(),
            id.name(),
            names.join(", ")
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_unknown_names_list_the_valid_ones() {
        for m in ModelKind::ALL {
            assert_eq!(ModelKind::from_name(m.name()), Ok(m));
        }
        let e = ModelKind::from_name("nonsense").unwrap_err();
        assert!(e.contains("liang, baxter-lin"), "{e}");
        let e = BrushChoice::parse("nonsense").unwrap_err();
        for name in ["large", "wolf", "flat", "filbert", "fan"] {
            assert!(e.contains(name), "{e}");
        }
        assert!(BrushChoice::for_model("flat", ModelKind::Liang)
            .unwrap_err()
            .contains("baxter-lin"));
        assert_eq!(
            BrushChoice::for_model("flat", ModelKind::BaxterLin)
                .unwrap()
                .shape,
            Some(HeadShape::Flat)
        );
    }
}
