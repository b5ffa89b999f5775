//! Fonts for the names of strokes and characters (永, 側, 勒, ...): egui's built-in fonts
//! have no CJK glyphs, and bundling a CJK font would add 10-20 MB to the binary, so the app
//! uses one the system already has. Without one, names show as boxes, and the status says
//! which package to install.

use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Environment variable naming a CJK font file to use first.
pub const FONT_ENV: &str = "MAOBI_CJK_FONT";

/// Where systems keep a CJK font (Debian/Ubuntu, Fedora, Arch, macOS, Windows).
const CANDIDATES: &[&str] = &[
    "/usr/share/fonts/opentype/noto/NotoSansCJK-Regular.ttc",
    "/usr/share/fonts/noto-cjk/NotoSansCJK-Regular.ttc",
    "/usr/share/fonts/google-noto-cjk/NotoSansCJK-Regular.ttc",
    "/usr/share/fonts/opentype/noto/NotoSerifCJK-Regular.ttc",
    "/usr/share/fonts/truetype/wqy/wqy-microhei.ttc",
    "/usr/share/fonts/truetype/wqy/wqy-zenhei.ttc",
    "/usr/share/fonts/truetype/droid/DroidSansFallbackFull.ttf",
    "/usr/share/fonts/truetype/arphic/uming.ttc",
    "/System/Library/Fonts/PingFang.ttc",
    "/System/Library/Fonts/STHeiti Light.ttc",
    "/Library/Fonts/Arial Unicode.ttf",
    "C:\\Windows\\Fonts\\msyh.ttc",
    "C:\\Windows\\Fonts\\simsun.ttc",
];

/// The first CJK font found: `$MAOBI_CJK_FONT`, then the usual places.
pub fn find_cjk_font() -> Option<PathBuf> {
    std::env::var_os(FONT_ENV)
        .map(PathBuf::from)
        .into_iter()
        .chain(CANDIDATES.iter().map(PathBuf::from))
        .find(|p| p.is_file())
}

/// Adds `path` as a fallback for every text; returns an error message if it cannot be read.
pub fn install(ctx: &egui::Context, path: &Path) -> Result<(), String> {
    let bytes = std::fs::read(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    let name = "cjk".to_string();
    let mut fonts = egui::FontDefinitions::default();
    fonts
        .font_data
        .insert(name.clone(), Arc::new(egui::FontData::from_owned(bytes)));
    for family in [egui::FontFamily::Proportional, egui::FontFamily::Monospace] {
        fonts.families.entry(family).or_default().push(name.clone());
    }
    ctx.set_fonts(fonts);
    Ok(())
}

/// Installs a CJK font if the system has one; otherwise characters without a glyph are
/// drawn as boxes. Returns what happened, for the status line.
pub fn setup(ctx: &egui::Context) -> Result<String, String> {
    match find_cjk_font() {
        Some(p) => {
            install(ctx, &p)?;
            Ok(format!("CJK font: {}", p.display()))
        }
        None => {
            ctx.set_missing_glyph_policy(egui::MissingGlyphPolicy::Tofu);
            Err(format!(
                "no CJK font found (stroke names show as boxes): install fonts-noto-cjk, or \
                 set {FONT_ENV} to a .ttf/.ttc file"
            ))
        }
    }
}
