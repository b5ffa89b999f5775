//! What the app keeps between runs: saved through eframe's storage at exit, restored at the
//! next start; recent files per kind; a damaged store is ignored, never an error.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

mod common;
use common::example;

use egui_kittest::Harness;
use maobi::device::builtin::SimClock;
use maobi::gui::app::{Automation, MaobiApp};
use maobi::gui::files::{DeviceKind, FileKind, Recent, Settings, RECENT_PER_KIND, SETTINGS_KEY};
use maobi::gui::DeviceChoice;
use maobi::tablet::PressureCurve;

#[derive(Default)]
struct MemoryStorage(HashMap<String, String>);

impl eframe::Storage for MemoryStorage {
    fn get_string(&self, key: &str) -> Option<String> {
        self.0.get(key).cloned()
    }
    fn set_string(&mut self, key: &str, value: String) {
        self.0.insert(key.to_string(), value);
    }
    fn remove_string(&mut self, key: &str) {
        self.0.remove(key);
    }
    fn flush(&mut self) {}
}

fn harness(automation: Automation) -> Harness<'static, MaobiApp> {
    common::harness(common::app(SimClock::Stepped(10), 100.0, 2.0, automation))
}

#[test]
fn settings_survive_a_restart_and_the_command_line_wins() {
    let mut a = harness(Automation::default());
    a.run_steps(1);
    let choice: DeviceChoice = "tcp:127.0.0.1:7999".parse().unwrap();
    a.state_mut()
        .set_device_choice(&choice, "small", maobi::device::ModelKind::Liang);
    a.state_mut()
        .set_pressure_curve(PressureCurve::new(1.8, 0.1).unwrap());
    let ctx = a.ctx.clone();
    a.state_mut()
        .file_action(FileKind::Poses, &example("heng.csv"), &ctx);
    a.run_steps(2);
    let mut store = MemoryStorage::default();
    eframe::App::save(a.state_mut(), &mut store);
    let saved: Settings = eframe::get_value(&store, SETTINGS_KEY).expect("stored");
    assert_eq!(saved.device_kind, DeviceKind::Tcp);
    assert_eq!(saved.device_addr, "127.0.0.1:7999");
    assert_eq!(saved.pressure_exponent, 1.8);
    assert_eq!((saved.paper_mm, saved.px_per_mm), (100.0, 2.0), "the paper");
    assert!(saved.replay_path.ends_with("heng.csv"));
    let recent: Vec<&Path> = saved.recent.of(FileKind::Poses).collect();
    assert_eq!(recent.len(), 1);
    assert!(recent[0].ends_with("heng.csv"));

    // The next run starts from them.
    let mut b = harness(Automation::default());
    b.state_mut().restore(&saved, false);
    b.run_steps(1);
    let again = b.state().settings();
    assert_eq!(again.device_kind, saved.device_kind);
    assert_eq!(again.device_addr, saved.device_addr);
    assert_eq!(again.replay_path, saved.replay_path);
    assert_eq!(again.pressure_exponent, 1.8);
    assert_eq!(again.recent, saved.recent);

    // A curve given on the command line is kept (`keep_tablet`).
    let mut c = harness(Automation::default());
    c.state_mut()
        .set_pressure_curve(PressureCurve::new(3.0, 0.0).unwrap());
    c.state_mut().restore(&saved, true);
    assert_eq!(c.state().settings().pressure_exponent, 3.0);
}

#[test]
fn automated_runs_leave_the_settings_alone() {
    let mut a = harness(Automation {
        screenshot: Some("out/x.png".into()),
        ..Automation::default()
    });
    a.run_steps(1);
    let mut store = MemoryStorage::default();
    eframe::App::save(a.state_mut(), &mut store);
    assert!(store.0.is_empty(), "an automated run stores nothing");
}

#[test]
fn a_damaged_store_or_a_vanished_tablet_is_not_an_error() {
    let mut store = MemoryStorage::default();
    eframe::Storage::set_string(&mut store, SETTINGS_KEY, "(device_kind: Banana".into());
    assert!(eframe::get_value::<Settings>(&store, SETTINGS_KEY).is_none());
    // An older file without today's fields: the missing ones take their defaults.
    eframe::Storage::set_string(&mut store, SETTINGS_KEY, "(brush: \"small\")".into());
    let old: Settings = eframe::get_value(&store, SETTINGS_KEY).expect("parses");
    assert_eq!(old.brush, "small");
    assert_eq!(old.device_kind, DeviceKind::Sim);

    let mut h = harness(Automation::default());
    let gone = Settings {
        tablet: Some("/dev/input/event-maobi-gone".into()),
        ..Settings::default()
    };
    h.state_mut().restore(&gone, false);
    h.run_steps(1);
    assert!(
        h.state().tablet_status().is_none(),
        "the mouse has the hand"
    );
}

#[test]
fn recent_files_are_per_kind_newest_first_and_bounded() {
    let dir = std::env::temp_dir().join(format!("maobi-recent-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut r = Recent::default();
    let files: Vec<PathBuf> = (0..RECENT_PER_KIND + 3)
        .map(|i| {
            let p = dir.join(format!("s{i}.maobi.toml"));
            std::fs::write(&p, "").unwrap();
            p
        })
        .collect();
    for f in &files {
        r.add(FileKind::Session, f);
    }
    r.add(FileKind::Poses, &files[0]);
    // Opening one again moves it to the front, once.
    r.add(FileKind::Session, &files[5]);
    let sessions: Vec<&Path> = r.of(FileKind::Session).collect();
    assert_eq!(sessions.len(), RECENT_PER_KIND);
    assert!(sessions[0].ends_with("s5.maobi.toml"));
    assert!(sessions[1].ends_with(format!("s{}.maobi.toml", RECENT_PER_KIND + 2)));
    assert_eq!(
        sessions
            .iter()
            .filter(|p| p.ends_with("s5.maobi.toml"))
            .count(),
        1
    );
    assert_eq!(r.of(FileKind::Poses).count(), 1);
    // Files that are gone are forgotten.
    std::fs::remove_file(&files[5]).unwrap();
    r.prune_missing();
    assert!(r
        .of(FileKind::Session)
        .all(|p| !p.ends_with("s5.maobi.toml")));
    let _ = std::fs::remove_dir_all(&dir);
}
