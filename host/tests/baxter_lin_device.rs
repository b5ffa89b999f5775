//! Baxter & Lin's brush on the built-in simulator (the app's model choice): the model
//! switch and what each model takes, a press felt through the local force model and the
//! shared output stage, ink on the paper, and a saved session that re-renders the same.

use maobi::device::builtin::SimCore;
use maobi::device::journal::Journal;
use maobi::device::{BrushFrame, DeviceCommand, HandInput, ModelKind};
use maobi::gui::canvas::PaperView;
use maobi::gui::rerender::rerender;
use maobi::gui::session::{InkLog, Session, MODEL_VERSION};
use maobi::gui::start_hand;
use maobi::paper::PaperSpec;
use maobi::raster::Frame;
use maobi_shared::baxter_lin::head::HeadShape;
use maobi_shared::force::{OutputState, PHANTOM_OMNI};
use maobi_shared::ParamId;
use maobi_shared::Scalar;

mod common;

const LENGTH_MM: f64 = 44.0;

/// The hand `depth_mm` below where the tip of a hanging brush of `LENGTH_MM` touches,
/// moved `x` mm along the paper.
fn hand(x: f64, depth_mm: f64) -> HandInput {
    hand_of(LENGTH_MM, x, depth_mm)
}

/// [`hand`] for a brush `length_mm` long.
fn hand_of(length_mm: f64, x: f64, depth_mm: f64) -> HandInput {
    HandInput {
        x,
        z: length_mm - depth_mm,
        ..start_hand(LENGTH_MM)
    }
}

fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

#[test]
fn the_model_choice_takes_each_models_brushes_and_parameters() {
    let mut core = SimCore::new("large", start_hand(LENGTH_MM)).unwrap();
    assert_eq!(core.model(), ModelKind::Liang);
    // Liang's model has no flat brush: the error says whose it is.
    let e = core
        .apply(DeviceCommand::Preset("flat".into()))
        .unwrap_err()
        .to_string();
    assert!(e.contains("Baxter & Lin"), "{e}");
    let e = core
        .apply(DeviceCommand::Preset("nonsense".into()))
        .unwrap_err()
        .to_string();
    for name in ["large", "goat", "flat", "filbert", "fan"] {
        assert!(e.contains(name), "{e}");
    }

    core.apply(DeviceCommand::Model(ModelKind::BaxterLin))
        .unwrap();
    assert_eq!(core.model(), ModelKind::BaxterLin);
    core.apply(DeviceCommand::Preset("flat".into())).unwrap();
    // The flat head reads only the ink: a profile or a Liang parameter is refused, naming
    // those it reads; nothing changes.
    let before = *core.params();
    for id in [ParamId::SubstepsPerTick, ParamId::LengthMm] {
        let e = core
            .apply(DeviceCommand::SetParam(id, before.get(id)))
            .unwrap_err()
            .to_string();
        assert!(e.contains("wetness"), "{id:?}: {e}");
    }
    core.apply(DeviceCommand::SetParam(ParamId::Wetness, 0.5))
        .unwrap();
    assert_eq!(core.params().wetness, 0.5);
    // Back to Liang's model with a flat head is refused until a preset is chosen.
    let e = core
        .apply(DeviceCommand::Model(ModelKind::Liang))
        .unwrap_err()
        .to_string();
    assert!(e.contains("flat"), "{e}");
    assert_eq!(core.model(), ModelKind::BaxterLin);
    core.apply(DeviceCommand::Preset("goat".into())).unwrap();
    // A round head reads its profile.
    core.apply(DeviceCommand::SetParam(ParamId::LengthMm, 40.0))
        .unwrap();
    core.apply(DeviceCommand::Model(ModelKind::Liang)).unwrap();
    assert_eq!(core.model(), ModelKind::Liang);
    assert_eq!(core.params().length_mm, 40.0);
}

/// Runs `ticks` ticks, the last frame.
fn run(core: &mut SimCore, ticks: usize) -> BrushFrame {
    let mut last = core.step();
    for _ in 1..ticks {
        last = core.step();
    }
    last
}

#[test]
fn a_press_is_felt_through_the_output_stage_and_inks_the_paper() {
    let mut core =
        SimCore::with_model(ModelKind::BaxterLin, "large", start_hand(LENGTH_MM)).unwrap();
    // Hanging in free air: no force, every spine along the handle's axis, the rings above
    // the paper.
    let f = run(&mut core, 50);
    assert!(norm(f.force_total) < 1e-6, "{:?}", f.force_total);
    assert_eq!(f.hairs.len(), 7, "the round head's seven spines");
    assert!(f.in_contact.iter().all(|c| !c));
    assert!(f.skeleton.is_empty());

    core.apply(DeviceCommand::EnableForces(true)).unwrap();
    core.apply(DeviceCommand::Hand(hand(0.0, 6.0))).unwrap();
    let frame = Frame::covering([-30.0, -20.0], [30.0, 20.0], 0.0, 5.0);
    let mut paper = PaperView::new(frame, PaperSpec::default());
    let mut peak: f64 = 0.0;
    let mut last = None;
    for _ in 0..600 {
        let f = core.step();
        paper.ink(&f);
        peak = peak.max(f.force_total[2]);
        // The command never exceeds the device's peak, and only the output stage drives.
        assert!(norm(f.command) <= PHANTOM_OMNI.peak_n as f64 + 1e-9);
        last = Some(f);
    }
    let pressed = last.unwrap();
    // Pressed 6 mm into the paper the hair pushes the hand up (the side-by-side table has
    // 0.19 N for this press at a 15 degree lean; straight down the spines splay more).
    assert!(pressed.force_total[2] > 0.05, "{:?}", pressed.force_total);
    assert!(peak < 5.0, "{peak} N");
    assert_eq!(pressed.output, OutputState::Active);
    // The output stage has ramped in: the command follows the wanted force.
    assert!(
        (pressed.command[2] - pressed.force_total[2]).abs() < 0.05,
        "command {:?} for {:?}",
        pressed.command,
        pressed.force_total
    );
    assert!(pressed.in_contact.iter().any(|c| *c));
    // A drag along x inks a stroke.
    core.apply(DeviceCommand::Hand(hand(15.0, 6.0))).unwrap();
    let mut front = f64::MIN;
    for k in 0..400 {
        let f = core.step();
        paper.ink(&f);
        // How far the footprint reaches at the end of the drag.
        if k == 399 {
            f.geometry().for_each_polygon(|_, poly| {
                for p in poly {
                    front = front.max(p.x.to_f64());
                }
            });
        }
        // Dragging the tip pulls back on the hand (friction opposes the motion), once the
        // spines the straight press buckled (backward, the solver's one way to break the
        // tie) have straightened: over the first 10 mm their stuck tips still push back.
        if f.pose.pos.x > 10.0 {
            assert!(
                f.force_total[0] < 0.0,
                "x {}: {:?}",
                f.pose.pos.x,
                f.force_total
            );
        }
    }
    // The stroke runs the drag's length: ink in every column from the press to where the
    // footprint reaches.
    let c = paper.canvas();
    let inked = |x_mm: f64| {
        let px = frame.to_px(x_mm, 0.0)[0].round() as usize;
        (0..c.height()).any(|y| c.at(px, y) > 0.0)
    };
    // The spines' tips trail the handle (the footprint reached 10.7 mm of the handle's 15
    // when this was written): one reaching less than 9 mm would be a stroke cut short.
    assert!(
        front > 9.0,
        "the footprint reaches x = {front} mm of the 15 mm drag"
    );
    let missing: Vec<f64> = (0..=front.floor() as i32)
        .map(f64::from)
        .filter(|x| !inked(*x))
        .collect();
    assert!(
        missing.is_empty(),
        "no ink at x = {missing:?} mm, the footprint reaching {front:.1} mm ({:.3}% of the paper)",
        c.ink_fraction() * 100.0
    );

    // Forces off: the output stage ramps out.
    core.apply(DeviceCommand::EnableForces(false)).unwrap();
    let f = run(&mut core, 300);
    assert_eq!(f.output, OutputState::Disabled);
    assert!(norm(f.command) < 1e-9, "{:?}", f.command);
}

fn session_of(journal: Journal, paper: Frame, paper_spec: PaperSpec, ink: InkLog) -> Session {
    Session {
        device: "built-in simulator".into(),
        journal,
        paper,
        paper_spec,
        ink,
        model: Some(MODEL_VERSION),
    }
}

#[test]
fn a_baxter_lin_session_saves_and_re_renders_as_it_was_drawn() {
    let mut core = SimCore::new("large", start_hand(LENGTH_MM)).unwrap();
    core.apply(DeviceCommand::Model(ModelKind::BaxterLin))
        .unwrap();
    core.apply(DeviceCommand::Preset("filbert".into())).unwrap();
    let frame = Frame::covering([-30.0, -20.0], [30.0, 20.0], 0.0, 5.0);
    let spec = PaperSpec::default();
    let mut paper = PaperView::new(frame, spec);
    let mut log = InkLog::default();
    let length = HeadShape::Filbert.head().length_mm();
    core.apply(DeviceCommand::Hand(hand_of(length, 0.0, 4.0)))
        .unwrap();
    for _ in 0..300 {
        let f = core.step();
        paper.ink(&f);
        log.inked(f.tick);
    }
    core.apply(DeviceCommand::Hand(hand_of(length, -12.0, 4.0)))
        .unwrap();
    for _ in 0..300 {
        let f = core.step();
        paper.ink(&f);
        log.inked(f.tick);
    }
    let live = paper.canvas().ink().to_vec();
    assert!(paper.canvas().ink_fraction() > 0.001);

    let journal = core.journal().lock().unwrap().clone();
    let session = session_of(journal, frame, spec, log);
    let text = session.to_toml().unwrap();
    assert!(text.contains("brush_model = \"baxter-lin\""), "{text}");
    assert!(text.contains("preset = \"filbert\""));
    let back = Session::from_toml(&text).unwrap();
    let r = rerender(&back, |_| {}).unwrap();
    assert_eq!(r.paper.canvas().ink(), &live[..], "the re-render differs");

    // A session that starts on Baxter & Lin's model keeps it.
    let start = SimCore::with_model(ModelKind::BaxterLin, "fan", start_hand(LENGTH_MM)).unwrap();
    let journal = start.journal().lock().unwrap().clone();
    let text = session_of(journal, frame, spec, InkLog::default())
        .to_toml()
        .unwrap();
    let back = Session::from_toml(&text).unwrap();
    assert_eq!(back.journal.model, ModelKind::BaxterLin);
    assert_eq!(back.journal.preset, "fan");
    // Bad input: an unknown model names the models.
    let e = Session::from_toml(&text.replace("baxter-lin", "spline"))
        .unwrap_err()
        .to_string();
    assert!(format!("{e:#}").contains("liang, baxter-lin") || e.contains("brush_model"));
}

#[test]
fn guided_writing_leads_the_hand_with_baxter_and_lins_brush_as_with_liangs() {
    // The guide line 50 mm up: the brush hangs in free air, so what the hand feels is the
    // guide's pull alone (Baxter & Lin's hair has no weight).
    let mut core =
        SimCore::with_model(ModelKind::BaxterLin, "large", start_hand(LENGTH_MM)).unwrap();
    let pulled = common::guide_along_a_line(&mut core, |k, f, g| {
        if g.distance_mm > 1.0 && g.gain > 0.0 {
            // The pull is the output stage's whole input here.
            assert!((f.command[0] - g.force[0]).abs() < 0.05, "tick {k}");
        }
    });
    assert!(pulled > 300, "pulled on {pulled} ticks");
}
