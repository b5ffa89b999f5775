//! The app's fonts: egui's own for every text but the CJK names of strokes, characters, papers
//! and brushes (永, 側, 熟宣, 大楷, ...), and a CJK font as a fallback after them.
//!
//! egui's built-in fonts have no CJK glyphs, and bundling a CJK font would add 10-20 MB to the
//! binary, so the app finds one the system already has, the way the platform finds fonts
//! (`fontdb`: fontconfig's directories on Linux, the system font folders on macOS and
//! Windows), and takes it only if it draws every CJK character the app shows ([`CJK_TEXT`]).
//! Every other symbol the app prints must be one egui's fonts draw: `tests/fonts.rs` checks
//! the source. Tests fix the font set ([`FontSource::Fixed`]) so that what a test draws does
//! not depend on the machine's fonts.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use skrifa::raw::FileRef;
use skrifa::MetadataProvider as _;

/// Environment variable naming a CJK font file to use first.
pub const FONT_ENV: &str = "MAOBI_CJK_FONT";

/// Every CJK character the app puts on screen: the eight strokes of 永 (永字八法: 側 勒 努 趯
/// 策 掠 啄 磔), the papers (熟宣, 生宣), the brush presets' names (大楷, 小楷, 狼毫, 羊毫,
/// 兼毫) and the practice grids (米字格, 田字格, 九宫格). A CJK font must draw all of them to
/// be used.
pub const CJK_TEXT: &str = concat!(
    "永側勒努趯策掠啄磔熟宣生大楷小狼毫羊兼米字格田九宫描紅臨摹收筆",
    // The practice set's characters (`crate::hanzi::SHIPPED`), which the practice panel shows.
    "的一是不了在人有我他这个们中来上大为和国地到以说时要就出会可也你对生能而子那得于着下自之年过发后",
    "作里用道行所然家种事成方多经么去法学如都同现当没动面起看定天分还进好小部其些主样理心她本前开但因只从想实"
);

/// CJK font families to ask the platform for, best first: the common ones on Linux
/// distributions, macOS and Windows.
const CJK_FAMILIES: &[&str] = &[
    "Noto Sans CJK SC",
    "Noto Sans CJK TC",
    "Noto Serif CJK SC",
    "Source Han Sans SC",
    "Source Han Sans CN",
    "WenQuanYi Micro Hei",
    "WenQuanYi Zen Hei",
    "Droid Sans Fallback",
    "AR PL UMing CN",
    "AR PL UKai CN",
    "PingFang SC",
    "Hiragino Sans GB",
    "Heiti SC",
    "STHeiti",
    "Microsoft YaHei",
    "SimSun",
    "Arial Unicode MS",
];

/// A CJK font that draws [`CJK_TEXT`]: one face of a font file (a `.ttc` holds several).
#[derive(Clone)]
pub struct CjkFont {
    /// Where it came from (a path, or a name), for messages.
    pub origin: String,
    data: Arc<Vec<u8>>,
    index: u32,
    /// The file it was read from, if it came from one.
    file: Option<PathBuf>,
}

impl std::fmt::Debug for CjkFont {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "CjkFont({}, face {})", self.origin, self.index)
    }
}

impl CjkFont {
    /// The first face in `data` (a font or a collection) that draws every character of
    /// [`CJK_TEXT`]; the error says why none does.
    pub fn from_bytes(origin: impl Into<String>, data: Vec<u8>) -> Result<CjkFont, String> {
        let origin = origin.into();
        let file = FileRef::new(&data).map_err(|e| format!("{origin}: not a font ({e})"))?;
        let mut lacking = Vec::new();
        let mut found = None;
        for (index, face) in file.fonts().enumerate() {
            let Ok(face) = face else { continue };
            let missing = missing_chars(&face, CJK_TEXT);
            if missing.is_empty() {
                found = Some(index as u32);
                break;
            }
            lacking.extend(missing);
        }
        let Some(index) = found else {
            lacking.sort_unstable();
            lacking.dedup();
            return Err(format!(
                "{origin}: no face draws all of {CJK_TEXT} (lacks {})",
                lacking.into_iter().collect::<String>()
            ));
        };
        Ok(CjkFont {
            origin,
            data: Arc::new(data),
            index,
            file: None,
        })
    }

    /// [`Self::from_bytes`] on the file at `path`.
    pub fn from_file(path: &Path) -> Result<CjkFont, String> {
        let data =
            std::fs::read(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
        let font = CjkFont::from_bytes(path.display().to_string(), data)?;
        Ok(CjkFont {
            file: Some(path.to_path_buf()),
            ..font
        })
    }

    /// The file the font was read from (`None`: it was given as bytes).
    pub fn file(&self) -> Option<&Path> {
        self.file.as_deref()
    }

    /// The face's index in its file.
    pub fn face_index(&self) -> u32 {
        self.index
    }
}

/// The characters of `text` that `face` has no glyph for.
pub fn missing_chars(face: &skrifa::FontRef<'_>, text: &str) -> Vec<char> {
    let charmap = face.charmap();
    text.chars().filter(|&c| charmap.map(c).is_none()).collect()
}

/// Which fonts the app draws its text with.
#[derive(Clone, Debug, Default)]
pub enum FontSource {
    /// egui's fonts, then a CJK font: `$MAOBI_CJK_FONT`, else the first of the platform's
    /// fonts that draws [`CJK_TEXT`].
    #[default]
    System,
    /// egui's fonts, then this CJK font if any, and nothing from the machine: what a test
    /// draws is then the same everywhere.
    Fixed(Option<CjkFont>),
}

impl FontSource {
    /// The CJK font this source gives, or why there is none.
    pub fn cjk_font(&self) -> Result<Option<CjkFont>, String> {
        match self {
            FontSource::Fixed(font) => Ok(font.clone()),
            FontSource::System => {
                find_cjk_font(std::env::var_os(FONT_ENV).as_deref().map(Path::new)).map(Some)
            }
        }
    }
}

/// The CJK font to use: `first` if it draws [`CJK_TEXT`], else the platform's font that does
/// (the families of `CJK_FAMILIES` first, then any). The error names what was tried.
pub fn find_cjk_font(first: Option<&Path>) -> Result<CjkFont, String> {
    let mut refused = Vec::new();
    if let Some(path) = first {
        match CjkFont::from_file(path) {
            Ok(font) => return Ok(font),
            Err(e) => {
                log::warn!("{FONT_ENV}: {e}");
                refused.push(e);
            }
        }
    }
    let mut db = fontdb::Database::new();
    db.load_system_fonts();
    let named = CJK_FAMILIES.iter().filter_map(|&name| {
        db.query(&fontdb::Query {
            families: &[fontdb::Family::Name(name)],
            ..fontdb::Query::default()
        })
    });
    let any = db.faces().map(|face| face.id);
    for id in named.chain(any) {
        let font = db.with_face_data(id, |data, index| {
            let face = skrifa::FontRef::from_index(data, index).ok()?;
            missing_chars(&face, CJK_TEXT)
                .is_empty()
                .then(|| (data.to_vec(), index))
        });
        if let Some(Some((data, index))) = font {
            let face = db.face(id);
            let origin = face
                .and_then(|f| f.families.first())
                .map_or_else(|| "a system font".to_string(), |(name, _)| name.clone());
            let file = face.and_then(|f| match &f.source {
                fontdb::Source::File(path) | fontdb::Source::SharedFile(path, _) => {
                    Some(path.clone())
                }
                fontdb::Source::Binary(_) => None,
            });
            return Ok(CjkFont {
                origin,
                data: Arc::new(data),
                index,
                file,
            });
        }
    }
    refused.push(format!(
        "none of the {} system fonts draws all of {CJK_TEXT}",
        db.len()
    ));
    Err(refused.join("; "))
}

/// egui's fonts with `cjk` after them in both families, so that Latin text keeps egui's.
pub fn definitions(cjk: Option<&CjkFont>) -> egui::FontDefinitions {
    let mut fonts = egui::FontDefinitions::default();
    if let Some(cjk) = cjk {
        let name = format!("cjk: {}", cjk.origin);
        fonts.font_data.insert(
            name.clone(),
            Arc::new(egui::FontData::from_blob(cjk.data.clone(), cjk.index)),
        );
        for family in [egui::FontFamily::Proportional, egui::FontFamily::Monospace] {
            fonts.families.entry(family).or_default().push(name.clone());
        }
    }
    fonts
}

/// The CJK font [`setup`] installed, as the About window tells it.
#[derive(Clone, Debug, PartialEq)]
pub enum CjkReport {
    /// This font: its name (or path), its face in the file, and the file it came from.
    Found {
        origin: String,
        face: u32,
        file: Option<PathBuf>,
    },
    /// A fixed font set without one was asked for (tests).
    NoneAsked,
    /// None was found: why.
    Missing(String),
}

/// Where [`setup`] keeps its [`CjkReport`] in the context's memory.
fn report_id() -> egui::Id {
    egui::Id::unique("maobi::gui::fonts::CjkReport")
}

/// What the last [`setup`] on `ctx` installed for CJK text (`None`: it has not run).
pub fn installed(ctx: &egui::Context) -> Option<CjkReport> {
    ctx.data(|d| d.get_temp(report_id()))
}

/// Installs the fonts of `source` in `ctx`. `Err` says why CJK names will show as boxes (for
/// the status line); the missing-glyph policy stays as it is (a test's panics on tofu).
pub fn setup(ctx: &egui::Context, source: &FontSource) -> Result<(), String> {
    let cjk = source.cjk_font();
    ctx.set_fonts(definitions(cjk.as_ref().ok().and_then(Option::as_ref)));
    let report = match &cjk {
        Ok(Some(font)) => CjkReport::Found {
            origin: font.origin.clone(),
            face: font.index,
            file: font.file.clone(),
        },
        Ok(None) => CjkReport::NoneAsked,
        Err(e) => CjkReport::Missing(e.clone()),
    };
    ctx.data_mut(|d| d.insert_temp(report_id(), report));
    match cjk {
        // A fixed set without one was asked for: nothing to report.
        Ok(_) => Ok(()),
        Err(e) => Err(format!(
            "no CJK font found (stroke names show as boxes): install fonts-noto-cjk, or set \
             {FONT_ENV} to a .ttf/.ttc file ({e})"
        )),
    }
}
