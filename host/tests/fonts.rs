//! The app's text does not depend on the machine's fonts: every symbol its source can put on
//! screen is drawn by egui's own fonts, and every CJK character is one the CJK font must draw
//! ([`CJK_TEXT`]); a CJK font is taken only if it draws all of those (in any face of a
//! collection), `MAOBI_CJK_FONT` first; and the app with a CJK fallback that lacks "→" opens
//! the stroke editor under kittest's panic on a missing glyph.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::str::FromStr;

use egui_kittest::kittest::Queryable;
use maobi::device::builtin::SimClock;
use maobi::gui::app::Automation;
use maobi::gui::fonts::{self, CjkFont, FontSource, CJK_TEXT};
use proc_macro2::{Delimiter, TokenStream, TokenTree};

mod common;
use common::test_font;

/// Han ideographs, their radicals and punctuation, kana, Hangul, full-width forms: what only
/// a CJK font draws.
fn is_cjk(c: char) -> bool {
    matches!(c as u32,
        0x2E80..=0x2FDF | 0x3000..=0x30FF | 0x3100..=0x9FFF | 0xAC00..=0xD7AF
            | 0xF900..=0xFAFF | 0xFE30..=0xFE4F | 0xFF00..=0xFFEF | 0x20000..=0x3FFFF)
}

/// The text of every string and char literal in `tokens`, except doc comments and items
/// under `#[cfg(test)]` (neither reaches the screen).
fn literals(tokens: TokenStream, out: &mut Vec<String>) {
    let mut tokens = tokens.into_iter().peekable();
    while let Some(token) = tokens.next() {
        match token {
            TokenTree::Punct(p) if p.as_char() == '#' => {
                if matches!(tokens.peek(), Some(TokenTree::Punct(p)) if p.as_char() == '!') {
                    tokens.next();
                }
                let Some(TokenTree::Group(attr)) = tokens.next() else {
                    continue;
                };
                let text = attr.stream().to_string();
                if text.starts_with("doc") {
                    continue;
                }
                if text.replace(' ', "") == "cfg(test)" {
                    // Skip the item: up to its body, or its `;`.
                    for t in tokens.by_ref() {
                        match t {
                            TokenTree::Group(g) if g.delimiter() == Delimiter::Brace => break,
                            TokenTree::Punct(p) if p.as_char() == ';' => break,
                            _ => {}
                        }
                    }
                    continue;
                }
                literals(attr.stream(), out);
            }
            TokenTree::Group(g) => literals(g.stream(), out),
            TokenTree::Literal(l) => match syn::Lit::new(l) {
                syn::Lit::Str(s) => out.push(s.value()),
                syn::Lit::Char(c) => out.push(c.value().to_string()),
                _ => {}
            },
            _ => {}
        }
    }
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

fn toml_strings(value: &toml::Value, out: &mut Vec<String>) {
    match value {
        toml::Value::String(s) => out.push(s.clone()),
        toml::Value::Array(a) => a.iter().for_each(|v| toml_strings(v, out)),
        toml::Value::Table(t) => t.values().for_each(|v| toml_strings(v, out)),
        _ => {}
    }
}

/// Every non-ASCII character the app can show, and the files it is in: the literals of the
/// app's crates (the GUI, and the messages and names of everything it calls, `shared/`
/// included) and the strings of the example stroke files it opens.
fn shown_chars() -> BTreeMap<char, BTreeSet<String>> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut files = Vec::new();
    rust_files(&root.join("host/src"), &mut files);
    rust_files(&root.join("shared/src"), &mut files);
    let mut chars: BTreeMap<char, BTreeSet<String>> = BTreeMap::new();
    let mut note = |text: &str, file: &Path| {
        let name = file.strip_prefix(&root).unwrap().display().to_string();
        for c in text.chars().filter(|c| !c.is_ascii()) {
            chars.entry(c).or_default().insert(name.clone());
        }
    };
    for file in &files {
        let source = std::fs::read_to_string(file).unwrap();
        let tokens =
            TokenStream::from_str(&source).unwrap_or_else(|e| panic!("{}: {e:?}", file.display()));
        let mut texts = Vec::new();
        literals(tokens, &mut texts);
        texts.iter().for_each(|t| note(t, file));
    }
    for entry in std::fs::read_dir(root.join("examples/strokes")).unwrap() {
        let file = entry.unwrap().path();
        if file.extension().is_some_and(|e| e == "toml") {
            let value: toml::Value =
                toml::from_str(&std::fs::read_to_string(&file).unwrap()).unwrap();
            let mut texts = Vec::new();
            toml_strings(&value, &mut texts);
            texts.iter().for_each(|t| note(t, &file));
        }
    }
    chars
}

/// The fonts of `family` in egui's font set (what the app installs before its CJK font), and
/// whether each face maps `c` to a glyph.
fn egui_fonts_draw(c: char) -> bool {
    let defs = egui::FontDefinitions::default();
    [egui::FontFamily::Proportional, egui::FontFamily::Monospace]
        .iter()
        .all(|family| {
            defs.families[family].iter().any(|name| {
                let data = &defs.font_data[name];
                let face = skrifa::FontRef::from_index(data.bytes(), data.index).unwrap();
                fonts::missing_chars(&face, &c.to_string()).is_empty()
            })
        })
}

#[test]
fn every_symbol_the_app_shows_is_in_eguis_fonts_and_every_cjk_character_in_cjk_text() {
    // The check has teeth: egui's fonts lack CJK and the arrow that started this, and have
    // the degree sign and the ellipsis.
    assert!(!egui_fonts_draw('永') && !egui_fonts_draw('→'));
    assert!(egui_fonts_draw('°') && egui_fonts_draw('…'));

    let shown = shown_chars();
    // The scan sees literals (the presets' names, the strokes' names), not comments alone.
    for c in ['大', '側'] {
        assert!(shown.contains_key(&c), "{c} not found in the app's text");
    }
    eprintln!(
        "non-ASCII characters the app can show: {}",
        shown.keys().collect::<String>()
    );
    let mut bad = Vec::new();
    for (c, files) in &shown {
        let ok = if is_cjk(*c) {
            CJK_TEXT.contains(*c)
        } else {
            egui_fonts_draw(*c)
        };
        if !ok {
            bad.push(format!("{c:?} (U+{:04X}) in {files:?}", *c as u32));
        }
    }
    assert!(
        bad.is_empty(),
        "characters no font the app ships draws (use words or ASCII), or CJK missing from \
         fonts::CJK_TEXT:\n{}",
        bad.join("\n")
    );
    // And CJK_TEXT asks a font for no more than the app shows.
    let unused: String = CJK_TEXT
        .chars()
        .filter(|c| !shown.contains_key(c))
        .collect();
    assert!(
        unused.is_empty(),
        "CJK_TEXT has {unused}, which the app never shows"
    );
}

#[test]
fn a_cjk_font_is_taken_only_if_it_draws_all_the_app_shows() {
    let without_hook: String = CJK_TEXT.chars().filter(|&c| c != '趯').collect();
    let e = CjkFont::from_bytes("short", test_font::font_for(&without_hook)).unwrap_err();
    assert!(e.contains("lacks 趯"), "{e}");
    assert!(CjkFont::from_bytes("text", b"not a font".to_vec()).is_err());

    // In a collection, the face that draws it all.
    let ttc = test_font::collection_for(&[&without_hook, CJK_TEXT]);
    let font = CjkFont::from_bytes("collection", ttc).unwrap();
    assert_eq!(font.face_index(), 1);

    // `MAOBI_CJK_FONT` first; skipped if it lacks a character.
    let dir = std::env::temp_dir().join(format!("maobi-fonts-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (good, short) = (dir.join("good.ttf"), dir.join("short.ttf"));
    std::fs::write(&good, test_font::font_for(CJK_TEXT)).unwrap();
    std::fs::write(&short, test_font::font_for(&without_hook)).unwrap();
    let found = fonts::find_cjk_font(Some(&good)).unwrap();
    assert_eq!(found.origin, good.display().to_string());
    match fonts::find_cjk_font(Some(&short)) {
        Ok(f) => assert_ne!(f.origin, short.display().to_string()),
        Err(e) => assert!(e.contains("lacks 趯"), "{e}"),
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// What the platform's lookup finds here (this machine's fonts): a font that draws all of
/// [`CJK_TEXT`], or an error that says what to install.
#[test]
fn the_platform_lookup_finds_a_font_that_draws_the_apps_cjk_or_says_what_to_install() {
    match fonts::find_cjk_font(None) {
        Ok(font) => {
            let data = fonts::definitions(Some(&font));
            let name = format!("cjk: {}", font.origin);
            let cjk = &data.font_data[&name];
            let face = skrifa::FontRef::from_index(cjk.bytes(), cjk.index).unwrap();
            assert!(fonts::missing_chars(&face, CJK_TEXT).is_empty());
            // After egui's fonts in both families: Latin text keeps egui's.
            for family in [egui::FontFamily::Proportional, egui::FontFamily::Monospace] {
                assert_eq!(data.families[&family].last(), Some(&name));
                assert_ne!(data.families[&family].first(), Some(&name));
            }
            eprintln!("CJK font here: {font:?}");
        }
        Err(e) => assert!(e.contains("system fonts draws all of"), "{e}"),
    }
}

#[test]
fn the_app_with_a_cjk_fallback_that_lacks_the_arrow_opens_the_stroke_editor() {
    let cjk = common::test_cjk_font();
    let data = fonts::definitions(Some(&cjk));
    let cjk_data = &data.font_data[&format!("cjk: {}", cjk.origin)];
    let face = skrifa::FontRef::from_index(cjk_data.bytes(), cjk_data.index).unwrap();
    assert_eq!(fonts::missing_chars(&face, "→A"), ['→', 'A']);

    let mut app = common::app(SimClock::Stepped(50), 150.0, 4.0, Automation::default());
    app.show_timeline(true);
    let yong = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/strokes/yong.toml");
    app.timeline_mut().open(&yong).unwrap();
    // kittest's harness panics on a glyph no font has.
    let mut h = egui_kittest::Harness::builder()
        .with_size(egui::vec2(1400.0, 1000.0))
        .build_ui_state(
            |ui, app: &mut maobi::gui::app::MaobiApp| app.frame_ui(ui),
            app.with_fonts(FontSource::Fixed(Some(cjk))),
        );
    h.run_steps(3);
    h.get_by_label_contains("kinetic curve");
    h.get_by_label_contains("8 strokes");
    // The stroke names draw (in the CJK font), and the status line has nothing to say.
    assert!(h.query_all_by_label_contains("側").next().is_some());
    assert!(h.query_by_label_contains("CJK").is_none());
}
