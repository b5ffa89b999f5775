//! A CJK font the tests make themselves, so that what a test draws does not depend on the
//! machine's fonts: a TrueType font whose every glyph is a square, for exactly the characters
//! asked for (and nothing else: no Latin, no arrows).

/// The em square, in font units.
const UNITS_PER_EM: i16 = 1000;
/// The square each glyph draws: left, bottom, right, top (font units).
const BOX: [i16; 4] = [100, -50, 900, 750];

fn be16(out: &mut Vec<u8>, v: u16) {
    out.extend_from_slice(&v.to_be_bytes());
}

fn be32(out: &mut Vec<u8>, v: u32) {
    out.extend_from_slice(&v.to_be_bytes());
}

fn pad4(out: &mut Vec<u8>) {
    while !out.len().is_multiple_of(4) {
        out.push(0);
    }
}

/// The tables of a font drawing a square for each of `chars` (glyph 0, `.notdef`, is empty),
/// sorted by tag.
fn tables(chars: &[char]) -> Vec<([u8; 4], Vec<u8>)> {
    let glyphs = chars.len() as u16 + 1;
    let [x0, y0, x1, y1] = BOX;

    let mut head = Vec::new();
    be32(&mut head, 0x0001_0000); // version
    be32(&mut head, 0x0001_0000); // fontRevision
    be32(&mut head, 0); // checksumAdjustment
    be32(&mut head, 0x5F0F_3CF5); // magicNumber
    be16(&mut head, 0x000B); // flags: baseline at y=0, lsb at x=0, integer ppem
    be16(&mut head, UNITS_PER_EM as u16);
    head.extend_from_slice(&[0; 16]); // created, modified
    for v in BOX {
        be16(&mut head, v as u16);
    }
    be16(&mut head, 0); // macStyle
    be16(&mut head, 8); // lowestRecPPEM
    be16(&mut head, 2); // fontDirectionHint
    be16(&mut head, 1); // indexToLocFormat: long offsets
    be16(&mut head, 0); // glyphDataFormat

    let mut hhea = Vec::new();
    be32(&mut hhea, 0x0001_0000);
    be16(&mut hhea, 880); // ascender
    be16(&mut hhea, (-120i16) as u16); // descender
    be16(&mut hhea, 0); // lineGap
    be16(&mut hhea, UNITS_PER_EM as u16); // advanceWidthMax
    be16(&mut hhea, x0 as u16); // minLeftSideBearing
    be16(&mut hhea, (UNITS_PER_EM - x1) as u16); // minRightSideBearing
    be16(&mut hhea, x1 as u16); // xMaxExtent
    be16(&mut hhea, 1); // caretSlopeRise
    hhea.extend_from_slice(&[0; 12]); // caretSlopeRun, caretOffset, 4 reserved
    be16(&mut hhea, 0); // metricDataFormat
    be16(&mut hhea, glyphs); // numberOfHMetrics

    let mut maxp = Vec::new();
    be32(&mut maxp, 0x0001_0000);
    be16(&mut maxp, glyphs);
    be16(&mut maxp, 4); // maxPoints
    be16(&mut maxp, 1); // maxContours
    maxp.extend_from_slice(&[0; 4]); // maxCompositePoints, maxCompositeContours
    be16(&mut maxp, 2); // maxZones
    maxp.extend_from_slice(&[0; 16]); // twilight points .. component depth

    let mut hmtx = Vec::new();
    be16(&mut hmtx, UNITS_PER_EM as u16);
    be16(&mut hmtx, 0);
    for _ in chars {
        be16(&mut hmtx, UNITS_PER_EM as u16);
        be16(&mut hmtx, x0 as u16);
    }

    // One contour of four on-curve points, clockwise, as 16-bit deltas (flag bit 0 only).
    let mut square = Vec::new();
    be16(&mut square, 1); // numberOfContours
    for v in BOX {
        be16(&mut square, v as u16);
    }
    be16(&mut square, 3); // endPtsOfContours
    be16(&mut square, 0); // instructionLength
    square.extend_from_slice(&[1; 4]);
    for dx in [x0, 0, x1 - x0, 0] {
        be16(&mut square, dx as u16);
    }
    for dy in [y0, y1 - y0, 0, y0 - y1] {
        be16(&mut square, dy as u16);
    }
    pad4(&mut square);
    let mut glyf = Vec::new();
    let mut loca = Vec::new();
    be32(&mut loca, 0);
    be32(&mut loca, 0); // .notdef: no outline
    for _ in chars {
        glyf.extend_from_slice(&square);
        be32(&mut loca, glyf.len() as u32);
    }

    // Format 12 (segmented coverage) for Windows Unicode full repertoire: one group a char.
    let mut mapped: Vec<(u32, u32)> = chars
        .iter()
        .enumerate()
        .map(|(i, &c)| (c as u32, i as u32 + 1))
        .collect();
    mapped.sort_unstable();
    let mut cmap = Vec::new();
    be16(&mut cmap, 0); // version
    be16(&mut cmap, 1); // numTables
    be16(&mut cmap, 3); // platform: Windows
    be16(&mut cmap, 10); // encoding: Unicode full repertoire
    be32(&mut cmap, 12); // offset of the subtable
    be16(&mut cmap, 12); // format
    be16(&mut cmap, 0);
    be32(&mut cmap, 16 + 12 * mapped.len() as u32); // length
    be32(&mut cmap, 0); // language
    be32(&mut cmap, mapped.len() as u32);
    for (c, g) in mapped {
        be32(&mut cmap, c);
        be32(&mut cmap, c);
        be32(&mut cmap, g);
    }

    let mut name = Vec::new();
    let strings = [(1u16, "Maobi Test CJK"), (2, "Regular")];
    be16(&mut name, 0); // format
    be16(&mut name, strings.len() as u16);
    be16(&mut name, 6 + 12 * strings.len() as u16); // stringOffset
    let mut storage = Vec::new();
    for (id, s) in strings {
        let utf16: Vec<u8> = s.encode_utf16().flat_map(u16::to_be_bytes).collect();
        for v in [3, 1, 0x409, id, utf16.len() as u16, storage.len() as u16] {
            be16(&mut name, v);
        }
        storage.extend(utf16);
    }
    name.extend(storage);

    let mut post = Vec::new();
    be32(&mut post, 0x0003_0000); // version 3: no glyph names
    be32(&mut post, 0); // italicAngle
    be16(&mut post, (-100i16) as u16); // underlinePosition
    be16(&mut post, 50); // underlineThickness
    post.extend_from_slice(&[0; 20]); // isFixedPitch, memory hints

    vec![
        (*b"cmap", cmap),
        (*b"glyf", glyf),
        (*b"head", head),
        (*b"hhea", hhea),
        (*b"hmtx", hmtx),
        (*b"loca", loca),
        (*b"maxp", maxp),
        (*b"name", name),
        (*b"post", post),
    ]
}

fn checksum(data: &[u8]) -> u32 {
    data.chunks(4)
        .map(|c| {
            let mut w = [0; 4];
            w[..c.len()].copy_from_slice(c);
            u32::from_be_bytes(w)
        })
        .fold(0, u32::wrapping_add)
}

/// A font (its table directory and tables) that will sit at `base` in its file.
fn font_at(chars: &[char], base: u32) -> Vec<u8> {
    let tables = tables(chars);
    let n = tables.len() as u16;
    let entry_selector = 15 - n.leading_zeros() as u16;
    let search_range = 16 << entry_selector;
    let mut out = Vec::new();
    be32(&mut out, 0x0001_0000); // TrueType outlines
    for v in [n, search_range, entry_selector, n * 16 - search_range] {
        be16(&mut out, v);
    }
    let mut offset = 12 + 16 * tables.len();
    for (tag, data) in &tables {
        out.extend_from_slice(tag);
        be32(&mut out, checksum(data));
        be32(&mut out, base + offset as u32);
        be32(&mut out, data.len() as u32);
        offset += data.len().next_multiple_of(4);
    }
    for (_, data) in &tables {
        out.extend_from_slice(data);
        pad4(&mut out);
    }
    out
}

/// A TrueType font drawing a square for each character of `chars`, and nothing else.
pub fn font_for(chars: &str) -> Vec<u8> {
    font_at(&chars.chars().collect::<Vec<_>>(), 0)
}

/// A font collection (`.ttc`) of one face per entry of `faces`, each drawing its characters.
pub fn collection_for(faces: &[&str]) -> Vec<u8> {
    let faces: Vec<Vec<char>> = faces.iter().map(|f| f.chars().collect()).collect();
    let mut out = Vec::new();
    out.extend_from_slice(b"ttcf");
    be32(&mut out, 0x0001_0000);
    be32(&mut out, faces.len() as u32);
    let mut base = 12 + 4 * faces.len() as u32;
    let mut fonts = Vec::new();
    for chars in &faces {
        be32(&mut out, base);
        let font = font_at(chars, base);
        base += font.len() as u32;
        fonts.push(font);
    }
    for font in fonts {
        out.extend(font);
    }
    out
}
