//! The About window: what this build is, Maobi's licence, and the licence of everything that
//! comes with it (egui's fonts, compiled into the binary; the example files that come with
//! the source) and of the CJK font found on this machine.
//!
//! The list is data ([`BUNDLED`]) so that a test keeps it honest: every entry filled in,
//! every file of the repository it names present, and the fonts it names the ones egui
//! bundles.

use super::fonts::{self, CjkReport};

/// Where something listed in the About window comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Origin {
    /// Compiled into the binary by egui (its `default_fonts` feature): the font's name among
    /// egui's default fonts, and its files (the font and its licence) in egui's
    /// `epaint_default_fonts` crate.
    EguiFont {
        key: &'static str,
        files: &'static str,
    },
    /// Files of Maobi's repository, relative to its root: they come with the source, not in
    /// the binary (the app opens them by default).
    Repository(&'static [&'static str]),
}

/// One font or data set that comes with Maobi, and its licence.
#[derive(Clone, Copy, Debug)]
pub struct Bundled {
    pub name: &'static str,
    /// What it is and what the app uses it for.
    pub what: &'static str,
    pub licence: &'static str,
    pub origin: Origin,
}

/// Maobi's licence: the workspace's `license` field, as cargo gives it to the build.
pub const LICENCE: &str = env!("CARGO_PKG_LICENSE");

/// Everything that comes with Maobi and is not Maobi's own code.
pub const BUNDLED: &[Bundled] = &[
    Bundled {
        name: "Ubuntu Light",
        what: "egui's text font: every Latin letter the app shows",
        licence: "Ubuntu Font Licence 1.0",
        origin: Origin::EguiFont {
            key: "Ubuntu-Light",
            files: "epaint_default_fonts: fonts/Ubuntu-Light.ttf, fonts/UFL.txt",
        },
    },
    Bundled {
        name: "Hack",
        what: "egui's monospace font: numbers and values",
        licence: "MIT (Hack); Bitstream Vera Licence (its Bitstream Vera glyphs); \
                  public domain (DejaVu's changes)",
        origin: Origin::EguiFont {
            key: "Hack",
            files: "epaint_default_fonts: fonts/Hack-Regular.ttf, fonts/Hack-Regular.txt",
        },
    },
    Bundled {
        name: "egui-icons",
        what: "five glyphs of John Slegers' emoji-icon-font, for egui's special symbols",
        licence: "MIT",
        origin: Origin::EguiFont {
            key: "egui-icons",
            files: "epaint_default_fonts: fonts/egui-icons.ttf, \
                    fonts/emoji-icon-font-mit-license.txt",
        },
    },
    Bundled {
        name: "Example pose tracks",
        what: "handle poses of a press-lift and three strokes, written for Maobi; the app \
               replays the hook by default",
        licence: LICENCE,
        origin: Origin::Repository(&[
            "examples/poses/press_lift.csv",
            "examples/poses/heng.csv",
            "examples/poses/shu.csv",
            "examples/poses/hook.csv",
        ]),
    },
    Bundled {
        name: "Example stroke files",
        what: "keyframed strokes written for Maobi: the eight strokes of yong (the stroke \
               editor's default) and the speed experiments",
        licence: LICENCE,
        origin: Origin::Repository(&["examples/strokes/yong.toml", "examples/strokes/speeds.toml"]),
    },
    Bundled {
        name: "Example tablet recording",
        what: "a synthetic pen stroke in evemu's format, written for Maobi's tests and demos",
        licence: LICENCE,
        origin: Origin::Repository(&["examples/tablet/press-and-tilt.evemu"]),
    },
];

/// The version, as cargo gives it to the build.
pub const VERSION: &str = env!("CARGO_PKG_VERSION");

/// What can be said of this build without a build script: the version, the profile, the
/// target, and the oldest Rust it builds with.
pub fn build_info() -> String {
    let profile = if cfg!(debug_assertions) {
        "debug"
    } else {
        "release"
    };
    format!(
        "Maobi {VERSION}, {profile} build for {}-{}; needs Rust {} or later",
        std::env::consts::ARCH,
        std::env::consts::OS,
        env!("CARGO_PKG_RUST_VERSION"),
    )
}

/// The line on the CJK font the app found on this machine (it brings none of its own).
pub fn cjk_font_line(report: Option<&CjkReport>) -> String {
    match report {
        Some(CjkReport::Found { origin, face, file }) => {
            let from = match file {
                Some(path) if std::env::var_os(fonts::FONT_ENV).is_some_and(|f| *path == f) => {
                    format!(", the file {} names: {}", fonts::FONT_ENV, path.display())
                }
                Some(path) => format!(", from this system's fonts: {}", path.display()),
                None => String::new(),
            };
            format!(
                "CJK text: {origin} (face {face}){from}. Not part of Maobi: its licence is the \
                 font's own."
            )
        }
        Some(CjkReport::NoneAsked) => "CJK text: no CJK font (a fixed font set).".to_string(),
        Some(CjkReport::Missing(why)) => format!("CJK text: no CJK font found: {why}"),
        None => "CJK text: the fonts are not set up yet.".to_string(),
    }
}

/// The About window ("About Maobi"), shown while `open` is true; its close button clears it.
pub fn about_window(ctx: &egui::Context, open: &mut bool) {
    egui::Window::new("About Maobi")
        .open(open)
        .collapsible(false)
        .resizable(true)
        .default_width(520.0)
        .show(ctx, |ui| {
            ui.heading(format!("Maobi {VERSION}"));
            ui.label(
                "A virtual Chinese-calligraphy brush: the brush model, the paper, and the \
                 devices that hold them.",
            );
            ui.label(build_info());
            ui.label(format!(
                "Maobi is licensed under {LICENCE}, at your option."
            ));
            ui.separator();
            ui.strong("Fonts");
            ui.label(cjk_font_line(fonts::installed(ctx).as_ref()));
            ui.separator();
            ui.strong("Bundled fonts and data");
            // One block an entry, not a table: the descriptions wrap to the window's width.
            egui::ScrollArea::vertical()
                .max_height(360.0)
                .show(ui, |ui| {
                    for b in BUNDLED {
                        ui.add_space(4.0);
                        ui.horizontal_wrapped(|ui| {
                            ui.strong(b.name);
                            ui.label(b.licence);
                        });
                        ui.label(b.what);
                        ui.weak(match b.origin {
                            Origin::EguiFont { files, .. } => {
                                format!("in the binary (egui's {files})")
                            }
                            Origin::Repository(files) => {
                                format!("with the source: {}", files.join(", "))
                            }
                        });
                    }
                });
        });
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    #[test]
    fn every_entry_is_filled_in_and_its_files_exist() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        assert!(!LICENCE.is_empty());
        for b in BUNDLED {
            for field in [b.name, b.what, b.licence] {
                assert!(!field.trim().is_empty(), "{b:?}");
            }
            match b.origin {
                Origin::EguiFont { key, files } => {
                    assert!(!key.is_empty() && !files.is_empty(), "{b:?}");
                }
                Origin::Repository(files) => {
                    assert!(!files.is_empty(), "{b:?}");
                    for f in files {
                        assert!(root.join(f).is_file(), "{}: {f} is missing", b.name);
                    }
                }
            }
        }
    }

    /// The fonts listed are exactly the ones egui compiles in: an egui update that adds or
    /// drops one fails here until the list says so.
    #[test]
    fn the_fonts_listed_are_the_ones_egui_bundles() {
        let listed: std::collections::BTreeSet<&str> = BUNDLED
            .iter()
            .filter_map(|b| match b.origin {
                Origin::EguiFont { key, .. } => Some(key),
                Origin::Repository(_) => None,
            })
            .collect();
        let egui = egui::FontDefinitions::default();
        let bundled: std::collections::BTreeSet<&str> =
            egui.font_data.keys().map(String::as_str).collect();
        assert_eq!(listed, bundled);
    }

    #[test]
    fn the_font_line_says_where_the_cjk_font_came_from() {
        let found = CjkReport::Found {
            origin: "Noto Sans CJK SC".into(),
            face: 2,
            file: Some("/usr/share/fonts/noto/NotoSansCJK.ttc".into()),
        };
        let line = cjk_font_line(Some(&found));
        assert!(
            line.contains("Noto Sans CJK SC") && line.contains("face 2"),
            "{line}"
        );
        assert!(line.contains("NotoSansCJK.ttc"), "{line}");
        let missing = cjk_font_line(Some(&CjkReport::Missing("none draws it".into())));
        assert!(missing.contains("none draws it"), "{missing}");
        assert!(cjk_font_line(None).contains("not set up"));
    }
}
